"""Physics backends: the ``SimBackend`` interface (``backend.py``), MuJoCo C on CPU threads
(``cpu.py``), MuJoCo Warp (``warp.py``: one batched model for all envs, on a GPU or Warp's CPU),
and ``make_backend``, the one place that turns a scene and the envs' object assignments into
the backend ``EnvConfig.backend`` names."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import mujoco
import numpy as np
import torch

from trainer.assets.scene import Scene, build_scene
from trainer.config import EnvConfig, check_backend
from trainer.errors import TrainerError
from trainer.sim.backend import SimBackend


def make_backend(
    cfg: EnvConfig,
    scene: Scene,
    layouts: Sequence[Sequence[Path]],
    env_layout: np.ndarray,
    device: str | torch.device,
) -> SimBackend:
    """The backend of ``cfg.backend`` for E envs.

    layouts: L assignments, each the MJCF files filling the scene's K slots in order;
    env_layout: (E,) int in [0, L), non-decreasing: the layout env i simulates."""
    check_backend(cfg.backend)  # before compiling anything: a missing extra is one line
    if cfg.physics.sleep and cfg.backend != "cpu":
        raise TrainerError(
            f"[physics] sleep = true is an option of the cpu backend, not of {cfg.backend!r}: "
            "set sleep = false"
        )
    env_layout = np.asarray(env_layout, dtype=np.int64)
    # The stepping models leave out what only renders; videos get full models on demand.
    models = [build_scene(cfg, scene, xmls, visual=False).compile() for xmls in layouts]

    def render_model(layout: int) -> mujoco.MjModel:
        return build_scene(cfg, scene, layouts[layout]).compile()

    if cfg.backend == "cpu":
        from trainer.sim.cpu import MujocoCPUBackend

        return MujocoCPUBackend(
            models, env_layout, cfg.physics.substeps, cfg.nthread, device, render_model,
            sleep=cfg.physics.sleep,
        )

    if cfg.backend == "warp":
        from trainer.sim.warp import MujocoWarpBackend, build_batched_model, derived_buffers

        merged, per_layout = build_batched_model(cfg, scene, layouts, models)
        contacts, constraints = derived_buffers(cfg, merged, scene.num_slots)
        return MujocoWarpBackend(
            merged, per_layout, models, env_layout, cfg.physics.substeps, contacts, constraints,
            device, render_model,
        )
    raise TrainerError(f"backend {cfg.backend!r} is not available: use backend = \"cpu\"")


__all__ = ["SimBackend", "make_backend"]
