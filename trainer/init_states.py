"""Banks of settled initial object states: a scene's objects (one per slot) dropped from random
poses, simulated together until they rest, and cached on disk
(``data/interim/trainer/init_states``); and the robot's homes above them (``robot_homes``).

Lift drops its one object onto the table; bin picking drops all of its objects into the bin one
above the other, so the clutter settles together. A state is kept only if every object came to
rest where it belongs (on the table; inside the bin) and no two bodies interpenetrate deeper
than ``[bin] max_penetration``.

The cache key covers every slot's model (geomprep's mjcf cache keys, in slot order), the scene's
fixtures, the drop parameters and the physics, so changing any of them recomputes the bank;
files are written atomically.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np
import torch
from mujoco import rollout

from geomgrasp.files import atomic_path
from geomgrasp.rotations import axis_angle_to_matrix, matrix_to_quat, quat_to_matrix, random_quats
from trainer.assets.collision import BIT_HAND
from trainer.assets.scene import Scene, build_scene, slot_geoms, slot_name, slot_qpos_addresses
from trainer.config import EnvConfig, RobotConfig, config_dict
from trainer.errors import TrainerError, TrainerWarning
from trainer.robots import Robot

BANK_VERSION = 4
MAX_REST_SPEED = 0.02
"""An object moving faster than this (m/s) after settling is not at rest: drop it again."""
MAX_ATTEMPTS = 20
HOME_RAISE = 0.01
"""``[robot] home_above_objects``: the home height rises in steps of this (m) ..."""
HOME_RAISE_STEPS = 30
"""... at most this many (0.3 m); a state still touched there starts touched, with a warning."""
HOME_CHECK_YAWS = 16
"""The home-contact check turns each settled state to this many yaws (every 22.5 degrees)."""


def bank_key(cfg: EnvConfig, scene: Scene, mjcf_keys: Sequence[str]) -> str:
    payload = {
        "version": BANK_VERSION,
        "mjcf": list(mjcf_keys),
        "fixtures": list(scene.fixtures),
        "init": config_dict(cfg.init),
        "physics": config_dict(cfg.physics),
        "bin": config_dict(cfg.bin) if "bin" in scene.fixtures else None,
    }
    return hashlib.sha256(json.dumps(payload, sort_keys=True).encode()).hexdigest()[:16]


def slot_radii(model: mujoco.MjModel, num_slots: int) -> np.ndarray:
    """(K,) radius (m) of each slot's object around its body origin (the centre of mass): the
    farthest vertex of its collision hulls (a geom's bounding sphere would overestimate it, and
    the objects are stacked by these radii before they drop)."""
    radii = np.zeros(num_slots)
    for k in range(num_slots):
        reach = [0.0]
        for g in np.flatnonzero(model.geom_bodyid == model.body(slot_name(k)).id):
            mesh = model.geom_dataid[g]
            if model.geom_type[g] != mujoco.mjtGeom.mjGEOM_MESH or mesh < 0:
                reach.append(np.linalg.norm(model.geom_pos[g]) + model.geom_rbound[g])
                continue
            start, count = model.mesh_vertadr[mesh], model.mesh_vertnum[mesh]
            rot = quat_to_matrix(torch.as_tensor(model.geom_quat[g], dtype=torch.float64)).numpy()
            verts = model.mesh_vert[start : start + count] @ rot.T + model.geom_pos[g]
            reach.append(float(np.linalg.norm(verts, axis=1).max()))
        radii[k] = max(reach)
    return radii


def _drop_poses(
    cfg: EnvConfig, scene: Scene, radii: np.ndarray, n: int, rng: np.random.Generator
) -> np.ndarray:
    """(n, K, 7) release poses: position (m) and quaternion (w, x, y, z) of every slot."""
    K = scene.num_slots
    pose = np.zeros((n, K, 7))
    generator = torch.Generator().manual_seed(int(rng.integers(2**62)))
    quats = random_quats(n * K, generator=generator, dtype=torch.float64)
    pose[..., 3:] = quats.numpy().reshape(n, K, 4)
    low, high = cfg.init.drop_height
    if "bin" not in scene.fixtures:
        pose[..., :2] = rng.uniform(-cfg.init.xy_range, cfg.init.xy_range, size=(n, K, 2))
        pose[..., 2] = radii + rng.uniform(low, high, size=(n, K))
        return pose
    # Into the bin: each object above the previous one, its centre far enough from the walls.
    inner = np.array(cfg.bin.inner_half_size)
    reach = np.clip(inner[None, :] - radii[:, None], 0.0, None)  # (K, 2)
    pose[..., :2] = rng.uniform(-1.0, 1.0, size=(n, K, 2)) * reach
    base = cfg.bin.wall_height + rng.uniform(low, high, size=(n, 1))
    stack = np.cumsum(2 * radii + cfg.bin.drop_spacing) - radii  # centre of each in the stack
    pose[..., 2] = base + stack[None, :]
    return pose


def _accepted(
    cfg: EnvConfig, scene: Scene, model: mujoco.MjModel, final: np.ndarray, address: np.ndarray
) -> np.ndarray:
    """(n,) bool: which settled full-physics states (n, nstate) are good initial states."""
    nq = model.nq
    qpos = final[:, 1 : 1 + nq]
    qvel = final[:, 1 + nq : 1 + nq + model.nv]
    pos = qpos[:, address[:, None] + np.arange(3)]  # (n, K, 3)
    # The free joints' linear velocities start at the same index as their dof addresses.
    dof = np.array([model.jnt_dofadr[model.body_jntadr[model.body(slot_name(k)).id]]
                    for k in range(scene.num_slots)])
    speed = np.linalg.norm(qvel[:, dof[:, None] + np.arange(3)], axis=-1)
    good = np.isfinite(final).all(axis=1) & (speed < MAX_REST_SPEED).all(axis=1)
    if "bin" in scene.fixtures:
        inner = np.array(cfg.bin.inner_half_size)
        inside = (np.abs(pos[..., :2]) < inner).all(axis=-1) & (pos[..., 2] > -0.01)
        good &= inside.all(axis=1)
    else:
        half_table = np.array(cfg.physics.table_size[:2])
        on_table = (pos[..., 2] > 0.0) & (np.abs(pos[..., :2]) < half_table).all(axis=-1)
        good &= on_table.all(axis=1)
    if scene.num_slots > 1 or "bin" in scene.fixtures:
        data = mujoco.MjData(model)
        for i in np.flatnonzero(good):
            data.qpos[:] = qpos[i]
            mujoco.mj_forward(model, data)
            depth = -min((data.contact[c].dist for c in range(data.ncon)), default=0.0)
            good[i] = depth <= cfg.bin.max_penetration
    return good


CHUTE_HEIGHT = 0.5
"""Bin walls (m) while the objects fall: a chute that keeps them from bouncing over the real
walls; then the chute is removed and the clutter settles again in the real bin."""


def drop_and_settle(
    cfg: EnvConfig, scene: Scene, xmls: Sequence[Path], size: int, seed: int
) -> np.ndarray:
    """Settled states (size, K, 7) of the scene's objects: position (m, world) and quaternion
    (w, x, y, z) of every slot."""
    model = build_scene(cfg, scene, xmls, robot=False, visual=False).compile()
    phases = [(model, 1.0)]
    in_bin = "bin" in scene.fixtures
    if in_bin:
        # Most of the settling inside the chute, the last third in the real bin.
        walls = max(CHUTE_HEIGHT, cfg.bin.wall_height)
        chute = dataclasses.replace(cfg, bin=dataclasses.replace(cfg.bin, wall_height=walls))
        phases = [
            (build_scene(chute, scene, xmls, robot=False, visual=False).compile(), 2 / 3),
            (model, 1 / 3),
        ]
    data = mujoco.MjData(model)
    address = slot_qpos_addresses(model, scene.num_slots)
    radii = slot_radii(model, scene.num_slots)
    seconds = cfg.bin.settle_seconds if in_bin else cfg.init.settle_seconds
    full = mujoco.mjtState.mjSTATE_FULLPHYSICS
    nstate = mujoco.mj_stateSize(model, full)
    rng = np.random.default_rng(seed)
    kept: list[np.ndarray] = []
    for _attempt in range(MAX_ATTEMPTS):
        n = 2 * size
        state = np.zeros((n, nstate))
        mujoco.mj_getState(model, data, state[0], full)
        state[:] = state[0]
        pose = _drop_poses(cfg, scene, radii, n, rng)
        columns = 1 + address[:, None] + np.arange(7)  # qpos starts after the time
        state[:, columns] = pose
        for phase_model, share in phases:
            nstep = max(1, int(round(share * seconds / model.opt.timestep)))
            phase_data = mujoco.MjData(phase_model)
            with rollout.Rollout(nthread=0) as runner:
                out, _ = runner.rollout(phase_model, [phase_data], state, nstep=nstep)
            state = out[:, -1].copy()
        good = _accepted(cfg, scene, model, state, address)
        kept.extend(state[good][:, columns])
        if len(kept) >= size:
            return np.stack(kept[:size])
    where = "inside the bin" if in_bin else "on the table"
    names = ", ".join(Path(x).stem for x in xmls)
    raise TrainerError(
        f"{names}: fewer than {size} drops came to rest {where} in {MAX_ATTEMPTS} attempts; check "
        "the models (`geomprep show`), or lower [init] drop_height / enlarge the bin"
    )


def load_or_build_bank(
    cfg: EnvConfig, scene: Scene, names: Sequence[str], xmls: Sequence[Path],
    mjcf_keys: Sequence[str], size: int,
) -> np.ndarray:
    """The cached bank of one assignment (slot k holds ``names[k]``), built on first use:
    (size, K, 7) float64."""
    cache_dir = Path(cfg.data_dir) / "interim" / "trainer" / "init_states"
    label = names[0] if len(names) == 1 else f"{len(names)}obj"
    path = cache_dir / f"{label}-{bank_key(cfg, scene, mjcf_keys)}-{size}.npy"
    if path.is_file():
        try:
            bank = np.load(path)
            if bank.shape == (size, scene.num_slots, 7):
                return bank
        except (OSError, ValueError):
            pass  # a damaged cache file is rebuilt, never trusted
    digest = hashlib.sha256("\0".join(names).encode()).hexdigest()[:8]
    seed = cfg.init.seed + int(digest, 16)
    bank = drop_and_settle(cfg, scene, xmls, size, seed)
    cache_dir.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp, open(tmp, "wb") as handle:
        np.save(handle, bank)
    return bank


def layout_banks(
    cfg: EnvConfig, scene: Scene, layouts: np.ndarray, names: Sequence[str],
    xmls: Sequence[Sequence[Path]], mjcf_keys: Sequence[str], size: int, device: torch.device,
) -> torch.Tensor:
    """(L, size, K, 7) float32 on ``device``: the cached bank (``load_or_build_bank``) of each
    layout l, whose slot k holds object ``layouts[l, k]`` (``names``, ``mjcf_keys`` by object
    id; ``xmls[l]`` the layout's slot models)."""
    banks = np.stack([
        load_or_build_bank(cfg, scene, [names[k] for k in row], xmls[i],
                           [mjcf_keys[k] for k in row], size)
        for i, row in enumerate(layouts)
    ])
    return torch.as_tensor(banks, dtype=torch.float32, device=device)


def hand_touches(model: mujoco.MjModel, home_qpos: np.ndarray, states: np.ndarray,
                 slot_qpos: np.ndarray, hand_bit: int) -> np.ndarray:
    """(B, K) bool: in which of the settled ``states`` (B, K, 7) (slot poses: position,
    quaternion) the robot in its ``home_qpos`` (nq,) touches the object of slot k, by MuJoCo's
    collision detection on ``model`` (that layout's): a hand geom (``contype`` with
    ``hand_bit``) in contact with one of the slot's geoms. ``slot_qpos`` (K, 7): each slot's
    qpos addresses."""
    data = mujoco.MjData(model)
    hand = (model.geom_contype & hand_bit) != 0
    geom_slot = np.full(model.ngeom, -1)
    for k in range(slot_qpos.shape[0]):
        geom_slot[slot_geoms(model, k)] = k
    out = np.zeros(states.shape[:2], dtype=bool)
    # Only states with an object reaching up to the hand's lowest point can touch it: the
    # others (the lying objects under a high hand: most states) need no collision detection.
    data.qpos[:] = home_qpos
    mujoco.mj_kinematics(model, data)
    bottom = (data.geom_xpos[hand, 2] - model.geom_rbound[hand] - model.geom_margin[hand]).min()
    reach = states[..., 2] + slot_radii(model, slot_qpos.shape[0]) + model.geom_margin.max()
    for b in np.flatnonzero((reach >= bottom).any(1)):
        state = states[b]
        data.qpos[:] = home_qpos
        data.qpos[slot_qpos.reshape(-1)] = state.reshape(-1)
        mujoco.mj_kinematics(model, data)  # geom poses: all that collision detection needs
        mujoco.mj_collision(model, data)
        g1, g2 = data.contact.geom1[: data.ncon], data.contact.geom2[: data.ncon]
        for slot in (geom_slot[g2][hand[g1]], geom_slot[g1][hand[g2]]):
            out[b, slot[slot >= 0]] = True
    return out


def turned(pose: torch.Tensor, yaw: torch.Tensor) -> torch.Tensor:
    """Slot poses ``pose`` (n, K, 7) (position, quaternion) turned by ``yaw`` (n,) rad about the
    vertical axis through the origin."""
    spin = axis_angle_to_matrix(torch.stack([torch.zeros_like(yaw)] * 2 + [yaw], -1))
    pos = (spin[:, None] @ pose[..., :3, None])[..., 0]
    quat = matrix_to_quat(spin[:, None] @ quat_to_matrix(pose[..., 3:]))
    return torch.cat([pos, quat], dim=-1)


@dataclass(frozen=True)
class Homes:
    """The robot's reset states at H home heights (the first ``home_hand_height``, each next
    ``HOME_RAISE`` higher) and which one each settled state starts from."""

    qpos: torch.Tensor
    """(H, nq) the robot's joint positions (the slots' entries are overwritten at a reset)."""
    ctrl: torch.Tensor
    """(H, nu) its actuator targets."""
    keypoint: torch.Tensor
    """(H, 3) m, the palm keypoint."""
    rot: torch.Tensor
    """(3, 3) the palm's orientation, the same in every home."""
    index: torch.Tensor
    """(L, B) long: the home of settled state b of layout l."""
    touched: np.ndarray
    """(L, B, K) bool: the hand at that home still touches slot k's object (at some yaw)."""


def robot_homes(
    robot: Robot, model: mujoco.MjModel, models: Sequence[mujoco.MjModel], banks: torch.Tensor,
    slot_qpos: torch.Tensor, cfg: RobotConfig,
) -> Homes:
    """The homes of ``robot`` (posed on ``model``) over the settled ``banks`` (L, B, K, 7) of the
    layouts whose models are ``models`` (slot k's qpos addresses ``slot_qpos`` (K, 7)). Without
    ``home_above_objects`` one home at ``home_hand_height`` (H = 1); with it, each state starts
    from the lowest at which the hand touches none of its objects at any of
    ``HOME_CHECK_YAWS`` turns (a reset turns it by a random one), at most
    ``HOME_RAISE_STEPS`` raises up."""
    steps = HOME_RAISE_STEPS if cfg.home_above_objects else 0
    L, B, K = banks.shape[:3]
    index = np.zeros((L, B), dtype=np.int64)
    touched = np.zeros((L, B, K), dtype=bool)
    pending = np.ones((L, B), dtype=bool)  # states the hand still touches at this height
    homes = []
    yaws = torch.arange(HOME_CHECK_YAWS, device=banks.device) * (2 * torch.pi / HOME_CHECK_YAWS)
    for step in range(steps + 1):
        homes.append(robot.home(model, cfg.home_hand_height + HOME_RAISE * step))
        for layout in np.flatnonzero(pending.any(1)):
            states = np.flatnonzero(pending[layout])
            poses = banks[layout, torch.as_tensor(states, device=banks.device)]  # (S, K, 7)
            poses = turned(poses.repeat_interleave(HOME_CHECK_YAWS, 0), yaws.repeat(len(states)))
            hit = hand_touches(
                models[layout], homes[-1].qpos.cpu().numpy(), poses.cpu().numpy(),
                slot_qpos.cpu().numpy(), BIT_HAND,
            ).reshape(len(states), HOME_CHECK_YAWS, -1).any(1)
            index[layout, states] = step
            touched[layout, states] = hit
            pending[layout, states] = hit.any(1)
        if not pending.any():
            break
    return Homes(
        qpos=torch.stack([h.qpos for h in homes]),
        ctrl=torch.stack([h.ctrl for h in homes]),
        keypoint=torch.stack([h.keypoint for h in homes]),
        rot=homes[0].rot,
        index=torch.as_tensor(index, device=banks.device),
        touched=touched,
    )


def warn_home_contact(homes: Homes, layouts: np.ndarray, names: Sequence[str],
                      cfg: RobotConfig) -> None:
    """One warning if the hand at its home touches some object in its settled states
    (``homes.touched``; ``layouts`` (L, K) the object id in each slot): those episodes start
    with the hand already on (or in) the object, whose first steps then push it around (a lift
    may even count) without any action."""
    touched = homes.touched
    ids = layouts[:, None, :].repeat(touched.shape[1], 1)
    clash = [(int(touched[ids == k].sum()), int((ids == k).sum()), name)
             for k, name in enumerate(names) if touched[ids == k].any()]
    if not clash:
        return
    clash.sort(key=lambda c: -c[0] / c[1])
    listed = ", ".join(f"{n} ({a} of {b})" for a, b, n in clash[:10])
    more = f" and {len(clash) - 10} more" if len(clash) > 10 else ""
    height = float(homes.keypoint[-1, 2])
    fix = ("raise [robot] home_hand_height" if cfg.home_above_objects else
           "set [robot] home_above_objects = true, raise home_hand_height")
    warnings.warn(
        f"the hand at its home pose touches settled states of {listed}{more}: those "
        f"episodes start with the hand on the object; {fix} (now {height:.2f} m) or "
        "leave them out",
        TrainerWarning,
        stacklevel=4,
    )
