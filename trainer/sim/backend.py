"""The interface between the task and a physics engine that steps many environments at once.

The tasks (``trainer/tasks/``) only talk to a ``SimBackend``: they write controls and mocap
targets, step, and read ``qpos``/``qvel`` as torch tensors; ``trainer.sim.make_backend`` builds
the backend that ``EnvConfig.backend`` names from a scene and the envs' assignments:
``cpu.py`` (MuJoCo C) and ``warp.py`` (MuJoCo Warp, for a GPU) implement the same few methods,
and no task knows which one it runs on.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable, Sequence

import mujoco
import numpy as np
import torch

MAX_SPEED = 1e3
"""A joint speed above this (m/s or rad/s) means the simulation has blown up."""


class SimBackend(ABC):
    """E environments, each a compiled model (envs may use different models of the same robot
    and sizes of state). Tensors are float32 on ``device`` unless stated otherwise."""

    num_envs: int
    device: torch.device
    nq: int
    nv: int
    nu: int
    nmocap: int
    models: list[mujoco.MjModel]
    """The layouts' compiled stepping models (``_set_models``)."""
    env_layout: np.ndarray
    """(E,) int: the layout (index into ``models``) env i simulates."""

    @abstractmethod
    def step(
        self,
        ctrl: torch.Tensor,
        mocap_pos: torch.Tensor | None = None,
        mocap_quat: torch.Tensor | None = None,
    ) -> None:
        """Hold ``ctrl`` (E, nu) (and the mocap targets (E, nmocap, 3|4)) for one control period
        (``substeps`` physics steps) in every environment."""

    @abstractmethod
    def set_state(
        self,
        env_ids: torch.Tensor,
        qpos: torch.Tensor,
        qvel: torch.Tensor,
        ctrl: torch.Tensor,
        mocap_pos: torch.Tensor | None = None,
        mocap_quat: torch.Tensor | None = None,
    ) -> None:
        """Overwrite the state of the environments ``env_ids`` (R,): qpos (R, nq), qvel (R, nv),
        ctrl (R, nu); time restarts at 0."""

    @property
    @abstractmethod
    def qpos(self) -> torch.Tensor:
        """(E, nq) current joint positions."""

    @property
    @abstractmethod
    def qvel(self) -> torch.Tensor:
        """(E, nv) current joint velocities."""

    @abstractmethod
    def unstable(self) -> torch.Tensor:
        """(E,) bool: environments whose state is not finite or has blown up; the task resets
        them."""

    def _set_models(
        self,
        models: Sequence[mujoco.MjModel],
        env_layout: np.ndarray,
        render_model: Callable[[int], mujoco.MjModel] | None,
    ) -> None:
        """Keep the layouts' compiled stepping ``models``, which layout each env simulates
        (``env_layout`` (E,)) and how to build a layout's full (rendering) model (default: the
        stepping model itself), for ``model`` and ``model_for_env``."""
        self.models = list(models)
        self.env_layout = np.asarray(env_layout, dtype=np.int64)
        self._render_model = render_model
        self._render_models: dict[int, mujoco.MjModel] = {}

    @property
    def model(self) -> mujoco.MjModel:
        """A compiled model of the scene (any assignment): the robot's and the slots' indices,
        names and kinematic tree are the same in every env's model."""
        return self.models[0]

    def model_for_env(self, env_id: int) -> mujoco.MjModel:
        """The MuJoCo model env ``env_id`` simulates (its objects in their slots): for
        rendering and inspection, not for stepping. Built once per layout, on first use."""
        layout = int(self.env_layout[env_id])
        if self._render_model is None:
            return self.models[layout]
        if layout not in self._render_models:
            self._render_models[layout] = self._render_model(layout)
        return self._render_models[layout]

    def snapshot(self, env_id: int) -> tuple[mujoco.MjModel, mujoco.MjData]:
        """Env ``env_id``'s stepping model and a new ``MjData`` holding its current state and
        held controls (forward-computed): for probes that step one env on its own
        (``trainer.grasps.hold``). Backends that cannot copy a state out raise."""
        raise NotImplementedError(f"{type(self).__name__} cannot copy an env's state out")

    @abstractmethod
    def step_held(self) -> None:
        """One control period with the controls already held and nothing else (no writes, no
        reads): the physics-only baseline of ``bench/env_throughput.py``."""

    def drain_warnings(self) -> list[str]:
        """Problems seen since the last call that the user can fix (e.g. buffers to enlarge),
        one line each; the trainer prints them once per iteration. Empty by default."""
        return []

    def memory(self) -> dict[str, int]:
        """Bytes the backend holds, by kind (e.g. ``models``, ``data``, ``state``), for
        benchmarks; empty if the backend does not say."""
        return {}

    def contact_load(self, sample: int = 32) -> dict[str, float]:
        """Mean active contacts and constraint rows per env in the current state (the
        physics' cost grows with both), over all envs or the first ``sample``, for benchmarks;
        empty if the backend cannot say. This default forward-computes ``snapshot``s."""
        try:
            snaps = [self.snapshot(i) for i in range(min(sample, self.num_envs))]
        except NotImplementedError:
            return {}
        return {"contacts": sum(d.ncon for _, d in snaps) / len(snaps),
                "constraint rows": sum(d.nefc for _, d in snaps) / len(snaps)}

    @abstractmethod
    def state_dict(self) -> dict:
        """Everything needed to continue the simulation exactly (for checkpoints)."""

    @abstractmethod
    def load_state_dict(self, state: dict) -> None:
        """Restore a ``state_dict`` taken from a backend over the same models."""

    def close(self) -> None:  # noqa: B027 (optional hook: most backends hold nothing)
        """Release threads and engine memory."""
