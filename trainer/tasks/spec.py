"""The specs of a task's inputs and outputs, from its config alone: the env declares them and
the networks are built from them (``trainer.models.Agent``), without building any physics."""

from __future__ import annotations

import torch
from torchrl.data import Bounded, Categorical, Composite, Unbounded

from trainer.config import ACTION_DIM, EnvConfig
from trainer.representations import representation_shape

PROPRIO_DIM = 20
"""Palm keypoint position (3), palm orientation (6-d), hand joints (11)."""
CONTEXT_DIM = 10
"""One other object's box: centre (3), quaternion (4), full extents (3)."""


def context_size(cfg: EnvConfig) -> int:
    """Other objects in the context (0 without context)."""
    return cfg.bin.num_objects - 1 if cfg.context == "bbox" else 0


def observation_spec(
    cfg: EnvConfig, num_envs: int, device: str | torch.device = "cpu"
) -> dict[str, Composite | Bounded | Unbounded]:
    """``{"observation", "action", "reward", "done"}`` specs of ``num_envs`` envs of ``cfg``."""
    E = num_envs
    flag = lambda: Categorical(2, shape=(E, 1), dtype=torch.bool, device=device)  # noqa: E731
    scalar = lambda: Unbounded(shape=(E, 1), device=device)  # noqa: E731
    keys = {
        "proprio": Unbounded(shape=(E, PROPRIO_DIM), device=device),
        "object": Unbounded(shape=(E, *representation_shape(cfg.representation)), device=device),
    }
    if (n := context_size(cfg)) > 0:
        keys["context"] = Unbounded(shape=(E, n, CONTEXT_DIM), device=device)
        keys["context_mask"] = Categorical(2, shape=(E, n), dtype=torch.bool, device=device)
    observation = Composite(
        **keys,
        success=flag(),
        unstable=flag(),
        lift_height=scalar(),
        reward_lift=scalar(),
        reward_success=scalar(),
        reward_contact=scalar(),
        object_id=Unbounded(shape=(E, 1), dtype=torch.long, device=device),
        shape=(E,),
        device=device,
    )
    return {
        "observation": observation,
        "action": Bounded(-1.0, 1.0, shape=(E, ACTION_DIM), device=device),
        "reward": Unbounded(shape=(E, 1), device=device),
        "done": Composite(
            done=flag(), terminated=flag(), truncated=flag(), shape=(E,), device=device
        ),
    }
