"""How close a trained policy brings its hand to each object, in ``trainer eval``'s episodes:
per object, the successes, the episodes whose pads never reached the target (``trainer eval``'s
``never reached``), and the median of each episode's closest approach of the palm keypoint to
the target's surface (m) over the failed episodes and over the successful ones, with the palm's
height above the target's centre at that moment. A second table says where the fingertip pads
were when their summed distance to the surface (what the paper's contact term pays for) was
smallest in the episode: that sum (median over the failed / the successful episodes), and how
many pads lay within 1 cm of the surface on its top (the surface's outward normal there points
up, world z > 0.7) and how many on its sides or below (means).

A policy that finds an object and does not lift it shows here whether its hand closed from
too far: results/cpu-comparison-2026-11-29/ (2026-11-30) measured the arms that fail the dice
closing on it with the palm 5.3-7.0 cm from its surface, where the arms that lift it come to
3.8-4.7 cm, and no arm resting its pads on the dice's top (at most 0.2 pads per failed
episode at the pads' closest; chunk 12).

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


PAD_NEAR = 0.01
"""m: a pad this close to the target's surface counts as touching it in ``PadPlacement``."""
TOP_NORMAL_Z = 0.7
"""A touching pad is on the target's top where the surface's outward normal's world z exceeds
this (the normal within ~45 degrees of up)."""
NORMAL_STEP = 0.002
"""m: the central-difference step of the SDF's gradient (the grids' voxel is ~0.5-1.5 mm)."""


class PadPlacement:
    """Per episode, where the 5 fingertip pads were at the step their summed distance to the
    target's surface (>= 0, the contact term's sum) was smallest: the number within ``PAD_NEAR``
    of it on its top and the number on its sides or below (``on_reset`` / ``on_step`` hooks)."""

    def __init__(self) -> None:
        self.parts: list[tuple[torch.Tensor, torch.Tensor, torch.Tensor]] = []
        """Per run, ((E,) smallest pad sum, (E,) pads on top then, (E,) pads on the sides)."""

    def hooks(self) -> dict[str, object]:
        return {"on_reset": self.on_reset, "on_step": self.on_step}

    def on_reset(self, env: GraspTask, td: TensorDictBase) -> None:
        n = env.num_envs
        self.parts.append((torch.full((n,), float("inf")), torch.zeros(n), torch.zeros(n)))

    def on_step(self, env: GraspTask, step: int, td: TensorDictBase) -> None:
        qpos = env.backend.qpos
        pads = env.kinematics.forward(qpos).site_pos[:, 1:6]  # keypoint_distances' pads
        obj_pos, obj_quat = env.target_pose(qpos)
        ids = env.target_objects()

        def sdf(points: torch.Tensor) -> torch.Tensor:
            return env.objects.sdf.query(points, obj_pos, obj_quat, ids)

        offsets = NORMAL_STEP * torch.eye(3, dtype=pads.dtype, device=pads.device)
        gradient = torch.stack([sdf(pads + o) - sdf(pads - o) for o in offsets], -1)
        normal_z = gradient[..., 2] / gradient.norm(dim=-1).clamp_min(1e-9)
        self.update(sdf(pads).cpu(), normal_z.cpu())

    def update(self, distance: torch.Tensor, normal_z: torch.Tensor) -> None:
        """Keep, per env, the pads' placement (counts from ``distance`` (E, 5) m and the
        surface normal's world z ``normal_z`` (E, 5)) at the smallest summed distance so far."""
        best, top, side = self.parts[-1]
        total = distance.clamp_min(0).sum(-1)
        near = distance < PAD_NEAR
        on_top = near & (normal_z > TOP_NORMAL_Z)
        closer = total < best
        best[closer] = total[closer]
        top[closer] = on_top.sum(-1)[closer].float()
        side[closer] = (near & ~on_top).sum(-1)[closer].float()

    def results(self) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(N,) smallest summed pad distance (m), (N,) pads on top and (N,) pads on the sides
        then, in the runs' order."""
        return tuple(torch.cat([part[i] for part in self.parts]) for i in range(3))


def _median_cm(values: torch.Tensor) -> str:
    return "—" if values.numel() == 0 else f"{100 * float(values.median()):.1f}"


def _mean(values: torch.Tensor) -> str:
    return "—" if values.numel() == 0 else f"{float(values.mean()):.1f}"


def table(run_dir: Path, objects: str | None = None, episodes_per_object: int = 50) -> list[str]:
    """The markdown tables (lines; the palm's approach, a blank line, the pads' placement) of
    the run's last checkpoint's deterministic episodes, as ``trainer eval`` plays them (its
    seed; the same episodes where ``objects`` is the run's)."""
    session = EvalSession.load(run_dir)
    names = session.names(objects)
    approach, placement, endings = ClosestApproach(), PadPlacement(), EpisodeEndings()
    hooks = chain_hooks(approach.hooks(), placement.hooks(), endings.hooks())
    episodes = session.lift_episodes(names, episodes_per_object, EVAL_SEED, **hooks)
    distance, above = approach.results()
    pad_sum, on_top, on_side = placement.results()
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
    lines += ["", "| object | pads' sum, failed (cm) | on top | on the sides | "
              "pads' sum, successes (cm) | on top | on the sides |",
              "|---|---:|---:|---:|---:|---:|---:|"]
    for k, name in enumerate(names):
        mine = episodes.target == k
        failed, won = mine & ~episodes.success, mine & episodes.success
        lines.append(f"| {name} | {_median_cm(pad_sum[failed])} | {_mean(on_top[failed])} | "
                     f"{_mean(on_side[failed])} | {_median_cm(pad_sum[won])} | "
                     f"{_mean(on_top[won])} | {_mean(on_side[won])} |")
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
