"""Lift: one object per env on the table; lift it by h_bar (the paper's main task).

Every object of the set gets an equal share of the envs (in blocks, one compiled model per
object on the CPU backend); its settled poses are turned by a uniform random yaw at each reset.
"""

from __future__ import annotations

import numpy as np
import torch

from trainer.assets.scene import Scene
from trainer.tasks.base import GraspTask


class LiftTask(GraspTask):
    """Lift the one object of the env (slot 0, always the target)."""

    name = "lift"

    def _layouts(
        self, num_objects: int, rng: np.random.Generator
    ) -> tuple[Scene, np.ndarray, np.ndarray]:
        E = self.run_envs
        if num_objects <= E:
            env_object = np.arange(E) % num_objects
        else:
            env_object = rng.choice(num_objects, size=E, replace=False)
        used, env_layout = np.unique(np.sort(env_object), return_inverse=True)
        return Scene(fixtures=("table",), num_slots=1), used[:, None], env_layout

    def _bank_size(self) -> int:
        return self.cfg.init.bank_size

    def _choose_targets(self, n: int) -> torch.Tensor:
        return torch.zeros(n, dtype=torch.long, device=self.device)

    def _reset_yaw(self, n: int) -> torch.Tensor:
        return (torch.rand(n, generator=self._rng, device=self.device) * 2 - 1) * torch.pi
