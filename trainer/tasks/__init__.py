"""Tasks: one module each (``lift.py``, ``bin.py``) over the shared robot base (``base.py``),
and ``make_env``, which builds the task ``EnvConfig.task`` names. The tasks' names and default
representations are listed in ``trainer.config.TASKS`` (importable without torch)."""

from __future__ import annotations

from trainer.config import TASKS, EnvConfig
from trainer.randomness import RandomStreams
from trainer.tasks.base import GraspTask
from trainer.tasks.bin import BinTask
from trainer.tasks.lift import LiftTask
from trainer.tasks.spec import observation_spec

REGISTRY: dict[str, type[GraspTask]] = {"lift": LiftTask, "bin": BinTask}
assert set(REGISTRY) == set(TASKS), "trainer.config.TASKS must list every task"


def make_env(
    cfg: EnvConfig, seed: int | RandomStreams = 0, shard: tuple[int, int] = (0, 1)
) -> GraspTask:
    """The environment of ``cfg.task`` with ``cfg.num_envs`` envs, its randomness from ``seed``
    (a seed's derived streams, or the streams of a run: ``trainer.randomness``); with ``shard``
    (rank, world) only the rank-th of ``world`` equal slices of them, each env with the objects
    it has in the whole (a process of a distributed run: ``trainer.training.distributed``)."""
    return REGISTRY[cfg.task](cfg, seed=seed, shard=shard)


__all__ = ["REGISTRY", "GraspTask", "make_env", "observation_spec"]
