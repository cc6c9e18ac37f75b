"""Banks of settled initial object poses: each object dropped from random poses onto the table,
simulated until it rests, and cached on disk (``data/interim/trainer/init_states``).

The cache key covers the object's model (geomprep's mjcf cache key), the drop parameters and
the physics, so changing any of them recomputes the bank; files are written atomically.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import mujoco
import numpy as np
from mujoco import rollout

from geomprep.store import atomic_path
from trainer.assets.scene import build_object_scene
from trainer.config import EnvConfig, config_dict

BANK_VERSION = 1
MAX_REST_SPEED = 0.02
"""An object moving faster than this (m/s) after settling is not at rest: drop it again."""


def _random_quats(rng: np.random.Generator, n: int) -> np.ndarray:
    """(n, 4) uniformly distributed unit quaternions (w, x, y, z)."""
    quat = rng.normal(size=(n, 4))
    return quat / np.linalg.norm(quat, axis=1, keepdims=True)


def bank_key(cfg: EnvConfig, mjcf_key: str) -> str:
    payload = {
        "version": BANK_VERSION,
        "mjcf": mjcf_key,
        "init": config_dict(cfg.init),
        "physics": config_dict(cfg.physics),
    }
    return hashlib.sha256(json.dumps(payload, sort_keys=True).encode()).hexdigest()[:16]


def drop_and_settle(cfg: EnvConfig, xml_path: Path, size: int, seed: int) -> np.ndarray:
    """Settled object poses (size, 7): position (m, world) and quaternion (w, x, y, z)."""
    model = build_object_scene(cfg, xml_path).compile()
    data = mujoco.MjData(model)
    radius = float(np.max(np.linalg.norm(model.mesh_vert, axis=1))) if model.nmeshvert else 0.1
    nstep = int(round(cfg.init.settle_seconds / model.opt.timestep))
    nstate = mujoco.mj_stateSize(model, mujoco.mjtState.mjSTATE_FULLPHYSICS)
    rng = np.random.default_rng(seed)
    half_table = np.array(cfg.physics.table_size[:2])
    kept: list[np.ndarray] = []
    for _attempt in range(20):
        n = 2 * size
        state = np.zeros((n, nstate))
        mujoco.mj_getState(model, data, state[0], mujoco.mjtState.mjSTATE_FULLPHYSICS)
        state[:] = state[0]
        qpos = state[:, 1 : 1 + model.nq]
        qpos[:, :2] = rng.uniform(-cfg.init.xy_range, cfg.init.xy_range, size=(n, 2))
        qpos[:, 2] = radius + rng.uniform(*cfg.init.drop_height, size=n)
        qpos[:, 3:7] = _random_quats(rng, n)
        state[:, 1 : 1 + model.nq] = qpos
        with rollout.Rollout(nthread=0) as runner:
            out, _ = runner.rollout(model, [data], state, nstep=nstep)
        final = out[:, -1]
        pos = final[:, 1:4]
        speed = np.linalg.norm(final[:, 1 + model.nq : 4 + model.nq], axis=1)
        on_table = (pos[:, 2] > 0.0) & np.all(np.abs(pos[:, :2]) < half_table, axis=1)
        good = on_table & (speed < MAX_REST_SPEED) & np.isfinite(final).all(axis=1)
        kept.extend(final[good, 1:8])
        if len(kept) >= size:
            return np.stack(kept[:size])
    raise RuntimeError(
        f"{xml_path.stem}: fewer than {size} drops came to rest on the table; check the model "
        "(`geomprep show`) or lower [init] drop_height"
    )


def load_or_build_bank(cfg: EnvConfig, name: str, xml_path: Path, mjcf_key: str) -> np.ndarray:
    """The cached bank for one object, built on first use: (bank_size, 7) float64."""
    cache_dir = Path(cfg.data_dir) / "interim" / "trainer" / "init_states"
    path = cache_dir / f"{name}-{bank_key(cfg, mjcf_key)}.npy"
    if path.is_file():
        return np.load(path)
    seed = cfg.init.seed + int(hashlib.sha256(name.encode()).hexdigest()[:8], 16)
    bank = drop_and_settle(cfg, xml_path, cfg.init.bank_size, seed)
    cache_dir.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp, open(tmp, "wb") as handle:
        np.save(handle, bank)
    return bank
