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

from pathlib import Path

import torch
from tensordict import TensorDictBase

from geomgrasp.rotations import quat_to_matrix
from trainer.session import EVAL_SEED, EvalSession, eval_parser
from trainer.tasks import GraspTask


def split_by_start_up(
    run_dir: Path, episodes_per_object: int = 50, iteration: int | None = None,
    objects: str | None = None, seed: int = EVAL_SEED,
) -> list[tuple[str, int, int, int, int]]:
    """Per object: (name, upright episodes, upright held, upside-down episodes, upside-down
    held) over the episodes ``trainer eval`` runs with these arguments."""
    session = EvalSession.load(run_dir, "cpu", iteration)
    names = session.names(objects)
    start_up: list[torch.Tensor] = []  # per batch of envs, (E,) the target's up axis' z

    def first_step(env: GraspTask, step: int, td: TensorDictBase) -> None:
        if step == 0:  # the target has not moved yet one action after the reset
            start_up.append(quat_to_matrix(env.target_pose()[1])[:, 2, 2].cpu())

    success, _, ids = session.lift_episodes(names, episodes_per_object, seed,
                                            on_step=first_step)
    upright = torch.cat(start_up) >= 0
    rows = []
    for k, name in enumerate(names):
        up, down = (ids == k) & upright, (ids == k) & ~upright
        rows.append((name, int(up.sum()), int(success[up].sum()), int(down.sum()),
                     int(success[down].sum())))
    return rows


def main(argv: list[str] | None = None) -> list[str]:
    args = eval_parser(__doc__.splitlines()[0]).parse_args(argv)
    rows = split_by_start_up(args.run_dir, args.episodes_per_object, args.iteration,
                             args.objects, args.seed)
    lines = ["| object | upright: held / episodes | upside down: held / episodes | all |",
             "|---|---:|---:|---:|"]
    for name, up, up_held, down, down_held in rows:
        lines.append(f"| {name} | {up_held}/{up} | {down_held}/{down} | "
                     f"{up_held + down_held}/{up + down} |")
    print("\n".join(lines))
    return lines


if __name__ == "__main__":
    main()
