"""Bin picking (the paper's Sec. V-C): ``[bin] num_objects`` objects drawn from the object set
are dropped into a bin and settle together; each episode one of them, drawn at random, is the
target. The policy sees the target through its representation (the paper: ``bbox``), the reward
and success are the paper's applied to the target (its lift, the fingertip distances to it).

Beyond the paper (its named future work), ``context = "bbox"`` adds every other object's
bounding box, ``context`` (E, N-1, 10) with ``context_mask`` (E, N-1) (False: that object has
fallen off the table), for a permutation-invariant encoder (``trainer.models``).

Layouts: ``[bin] layouts`` distinct draws of N objects, shared round-robin by the envs (one
compiled model each on the CPU backend), each with a bank of settled clutter states; a reset
takes one and turns the whole bin by a random quarter turn (half turn for an oblong bin), which
maps the bin onto itself.
"""

from __future__ import annotations

import numpy as np
import torch

from trainer.assets.scene import Scene
from trainer.errors import TrainerError
from trainer.representations import object_representation
from trainer.tasks.base import GraspTask


class BinTask(GraspTask):
    """Lift the episode's target out of a bin of N objects."""

    name = "bin"

    def _layouts(
        self, num_objects: int, rng: np.random.Generator
    ) -> tuple[Scene, np.ndarray, np.ndarray]:
        b, E = self.cfg.bin, self.run_envs
        if b.num_objects > num_objects:
            raise TrainerError(
                f"bin of {b.num_objects} objects: the object set {self.cfg.objects!r} has only "
                f"{num_objects}; lower --bin-objects or pass a larger --objects"
            )
        count = min(b.layouts, E)
        layouts = np.stack(
            [rng.choice(num_objects, size=b.num_objects, replace=False) for _ in range(count)]
        )
        env_layout = np.sort(np.arange(E) % count)
        return Scene(fixtures=("table", "bin"), num_slots=b.num_objects), layouts, env_layout

    def _bank_size(self) -> int:
        return self.cfg.bin.bank_size

    def _choose_targets(self, n: int) -> torch.Tensor:
        N = self.cfg.bin.num_objects
        return torch.randint(N, (n,), generator=self._rng, device=self.device)

    def _reset_yaw(self, n: int) -> torch.Tensor:
        hx, hy = self.cfg.bin.inner_half_size
        turns = 4 if hx == hy else 2
        k = torch.randint(turns, (n,), generator=self._rng, device=self.device)
        return k.float() * (2 * torch.pi / turns)

    def _extra_obs(
        self, slots: torch.Tensor, target_slot: torch.Tensor
    ) -> dict[str, torch.Tensor]:
        if self.cfg.context != "bbox":
            return {}
        context, mask = self._context(slots, target_slot)
        return {"context": context, "context_mask": mask}

    def _context(
        self, slots: torch.Tensor, target_slot: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """The boxes of the non-target objects (E, K-1, 10), and which of them are still on the
        table (E, K-1) bool."""
        E, K = slots.shape[:2]
        boxes = object_representation(
            "bbox", self.objects, self.assignment.reshape(-1), slots[..., :3].reshape(-1, 3),
            slots[..., 3:].reshape(-1, 4), None,
        ).reshape(E, K, -1)
        # The slots other than the target, in slot order: 0..K-2, skipping the target's.
        rank = torch.arange(K - 1, device=slots.device)[None, :]
        others = rank + (rank >= target_slot[:, None]).long()
        context = boxes.gather(1, others[..., None].expand(-1, -1, boxes.shape[-1]))
        height = slots[..., 2].gather(1, others)
        return context, height > self.cfg.fall_height
