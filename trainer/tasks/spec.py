"""The specs of a task's inputs and outputs, from its config alone: the env declares them and
the networks are built from them (``trainer.models.Agent``), without building any physics. The
observation keys and the logged reward terms come from their tables in ``trainer.tasks.terms``."""

from __future__ import annotations

import torch
from torchrl.data import Bounded, Categorical, Composite, Unbounded

from trainer.config import ACTION_DIM, EnvConfig
from trainer.tasks.terms import (  # noqa: F401 (spec.PROPRIO_DIM etc., their former home)
    CONTEXT_DIM,
    PROPRIO_DIM,
    context_size,
    observation_terms,
    reward_output_key,
    reward_terms,
)


def observation_spec(
    cfg: EnvConfig, num_envs: int, device: str | torch.device = "cpu"
) -> dict[str, Composite | Bounded | Unbounded]:
    """``{"observation", "action", "reward", "done"}`` specs of ``num_envs`` envs of ``cfg``."""
    E = num_envs
    flag = lambda: Categorical(2, shape=(E, 1), dtype=torch.bool, device=device)  # noqa: E731
    scalar = lambda: Unbounded(shape=(E, 1), device=device)  # noqa: E731
    keys = {
        term.name: (
            Categorical(2, shape=(E, *term.shape(cfg)), dtype=torch.bool, device=device)
            if term.dtype == torch.bool
            else Unbounded(shape=(E, *term.shape(cfg)), dtype=term.dtype, device=device)
        )
        for term in observation_terms(cfg)
    }
    observation = Composite(
        **keys,
        success=flag(),
        unstable=flag(),
        grasp_start=flag(),  # the episode started from a scripted grasp ([run] grasp_starts)
        lift_height=scalar(),
        **{reward_output_key(name): scalar() for name in reward_terms(cfg.reward)},
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
