"""A run's evaluation split by how each episode's target starts: its mesh's up axis up or down.

A plate that settles upside down is a dome no fingertip gets under (no scripted grasp lifted
one: results/graspability-plate-rim-2026-11-26/), so a policy's held rate on the plate is capped
by the share of resets that start face up (~0.78 there). This runs exactly the episodes of
``trainer eval RUN --episodes-per-object N`` (same seed, envs, deterministic policy; the totals
match its per_object.csv) and prints, per object, the successes among the episodes whose target
started upright and among those that started upside down.

    python scripts/eval_upright.py RUN_DIR [--episodes-per-object 50] [--iteration N]
                                   [--objects 029_plate]
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path
from typing import TYPE_CHECKING

import torch

if TYPE_CHECKING:
    from trainer.models import Agent
    from trainer.tasks import GraspTask


def eval_env(
    run_dir: Path, episodes_per_object: int, iteration: int | None, objects: str | None,
    seed: int,
) -> tuple[list[str], GraspTask, Agent]:
    """(object names, env, agent) of ``trainer eval RUN --episodes-per-object N``'s episodes:
    the run's env on those objects, one batch of N envs per object, the eval's seed."""
    from trainer.objects import resolve_names
    from trainer.randomness import RandomStreams
    from trainer.tasks import make_env
    from trainer.training.checkpoint import load_agent

    cfg, agent = load_agent(run_dir, "cpu", iteration)
    names = resolve_names(objects or cfg.env.objects, cfg.env.data_dir)
    n = episodes_per_object
    # trainer eval runs up to 1024 envs in one batch: the same episodes only within one.
    if n * len(names) > 1024:
        raise SystemExit("error: more than 1024 episodes in all: name fewer --objects")
    env_cfg = dataclasses.replace(cfg.env, objects=",".join(names), num_envs=n * len(names))
    env = make_env(env_cfg, seed=RandomStreams(seed, legacy=not cfg.run.random_streams))
    return names, env, agent


def split_by_start_up(
    run_dir: Path, episodes_per_object: int = 50, iteration: int | None = None,
    objects: str | None = None, seed: int = 12345,
) -> list[tuple[str, int, int, int, int]]:
    """Per object: (name, upright episodes, upright held, upside-down episodes, upside-down
    held) over the episodes ``trainer eval`` runs with these arguments (one batch of envs)."""
    from geomgrasp.rotations import quat_to_matrix
    from trainer.evaluation import run_episodes

    names, env, agent = eval_env(run_dir, episodes_per_object, iteration, objects, seed)
    start_up: list[torch.Tensor] = []

    def first_step() -> None:  # the target has not moved yet one action after the reset
        if not start_up:
            start_up.append(quat_to_matrix(env.target_pose()[1])[:, 2, 2].cpu())

    success, _, ids = run_episodes(env, agent.actor, True, on_step=first_step)
    env.close()
    upright = start_up[0] >= 0
    rows = []
    for k, name in enumerate(names):
        up, down = (ids == k) & upright, (ids == k) & ~upright
        rows.append((name, int(up.sum()), int(success[up].sum()), int(down.sum()),
                     int(success[down].sum())))
    return rows


def eval_arguments(description: str) -> argparse.Namespace:
    """The command line of a script that replays ``trainer eval``'s episodes (``eval_env``):
    run_dir, episodes_per_object, iteration, objects, seed."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("run_dir", type=Path)
    parser.add_argument("--episodes-per-object", type=int, default=50)
    parser.add_argument("--iteration", type=int, default=None)
    parser.add_argument("--objects", default=None)
    parser.add_argument("--seed", type=int, default=12345, help="trainer eval's default")
    return parser.parse_args()


def main() -> None:
    args = eval_arguments(__doc__.splitlines()[0])
    rows = split_by_start_up(args.run_dir, args.episodes_per_object, args.iteration,
                             args.objects, args.seed)
    print("| object | upright: held / episodes | upside down: held / episodes | all |")
    print("|---|---:|---:|---:|")
    for name, up, up_held, down, down_held in rows:
        print(f"| {name} | {up_held}/{up} | {down_held}/{down} | "
              f"{up_held + down_held}/{up + down} |")


if __name__ == "__main__":
    main()
