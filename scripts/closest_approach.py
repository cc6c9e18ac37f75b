"""How close a trained policy brings its hand to each object, in ``trainer eval``'s episodes:
per object, the successes, the episodes whose pads never reached the target (``trainer eval``'s
``never reached``), and the median of each episode's closest approach of the palm keypoint to
the target's surface (m) over the failed episodes and over the successful ones, with the palm's
height above the target's centre at that moment.

A policy that finds an object and does not lift it shows here whether its hand closed from
too far: results/cpu-comparison-2026-11-29/ (2026-11-30) measured the arms that fail the dice
closing on it with the palm 5.3-7.0 cm from its surface, where the arms that lift it come to
3.8-4.7 cm.

    python scripts/closest_approach.py RUN_DIR [--objects A,B] [--episodes-per-object 50]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch
from tensordict import TensorDictBase

from trainer.evaluation import ENDINGS, EpisodeEndings, chain_hooks
from trainer.grasps import keypoint_distances
from trainer.session import EVAL_SEED, EvalSession
from trainer.tasks import GraspTask


class ClosestApproach:
    """Per episode, the palm keypoint's closest distance (m) to the target's surface and the
    palm's height (m) above the target's centre when it came closest: the ``on_reset`` and
    ``on_step`` hooks of ``run_episodes`` / ``EvalSession.lift_episodes`` (``hooks()``)."""

    def __init__(self) -> None:
        self.parts: list[tuple[torch.Tensor, torch.Tensor]] = []
        """Per run, ((E,) closest distance, (E,) palm height above the centre then)."""

    def hooks(self) -> dict[str, object]:
        return {"on_reset": self.on_reset, "on_step": self.on_step}

    def on_reset(self, env: GraspTask, td: TensorDictBase) -> None:
        self.parts.append((torch.full((env.num_envs,), float("inf")),
                           torch.zeros(env.num_envs)))

    def on_step(self, env: GraspTask, step: int, td: TensorDictBase) -> None:
        qpos = env.backend.qpos
        palm = env.kinematics.forward(qpos).site_pos[:, 0].cpu()  # keypoint_distances' first
        centre = env.target_pose(qpos)[0].cpu()
        self.update(keypoint_distances(env)[:, 0].cpu(), palm[:, 2] - centre[:, 2])

    def update(self, distance: torch.Tensor, above: torch.Tensor) -> None:
        """Keep, per env, the nearest ``distance`` (E,) so far and ``above`` (E,) with it."""
        best, height = self.parts[-1]
        closer = distance < best
        best[closer], height[closer] = distance[closer], above[closer]

    def results(self) -> tuple[torch.Tensor, torch.Tensor]:
        """(N,) closest distances and (N,) palm heights above the centre, in the runs' order."""
        return (torch.cat([d for d, _ in self.parts]), torch.cat([h for _, h in self.parts]))


def _median_cm(values: torch.Tensor) -> str:
    return "—" if values.numel() == 0 else f"{100 * float(values.median()):.1f}"


def table(run_dir: Path, objects: str | None = None, episodes_per_object: int = 50) -> list[str]:
    """The markdown table (lines) of the run's last checkpoint's deterministic episodes, as
    ``trainer eval`` plays them (its seed; the same episodes where ``objects`` is the run's)."""
    session = EvalSession.load(run_dir)
    names = session.names(objects)
    approach, endings = ClosestApproach(), EpisodeEndings()
    episodes = session.lift_episodes(names, episodes_per_object, EVAL_SEED,
                                     **chain_hooks(approach.hooks(), endings.hooks()))
    distance, above = approach.results()
    ended = endings.endings()
    lines = ["| object | episodes | successes | never reached | palm to surface, failed (cm) | "
             "above centre (cm) | palm to surface, successes (cm) | above centre (cm) |",
             "|---|---:|---:|---:|---:|---:|---:|---:|"]
    for k, name in enumerate(names):
        mine = episodes.target == k
        failed, won = mine & ~episodes.success, mine & episodes.success
        unreached = int((mine & (ended == ENDINGS.index("never reached"))).sum())
        lines.append(f"| {name} | {int(mine.sum())} | {int(won.sum())} | {unreached} | "
                     f"{_median_cm(distance[failed])} | {_median_cm(above[failed])} | "
                     f"{_median_cm(distance[won])} | {_median_cm(above[won])} |")
    return lines


def main(argv: list[str] | None = None) -> list[str]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("run_dir", type=Path)
    parser.add_argument("--objects", default=None, help="comma-separated [the run's]")
    parser.add_argument("--episodes-per-object", type=int, default=50)
    args = parser.parse_args(argv)
    if args.episodes_per_object < 1:
        parser.error(f"--episodes-per-object must be >= 1, got {args.episodes_per_object}")
    lines = table(args.run_dir, args.objects, args.episodes_per_object)
    print("\n".join(lines))
    return lines


if __name__ == "__main__":
    main()
