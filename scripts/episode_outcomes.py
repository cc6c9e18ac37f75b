"""How a trained policy's evaluation episodes end, one line per env: a success, or how it
failed. Every env plays one deterministic episode from home (as ``trainer eval``); each
failure is put in one class by the target's centre rise over the episode:

- ``never lifted``: it never rose by ``--lifted`` (1 cm);
- ``dropped``: it rose, then ended at least ``--drop`` (3 cm) below its highest point;
- ``stalled``: it rose and stayed up, but not to the lift height or not held.

For each episode the line gives its length, the highest rise and the action it came at, how many
fingertip pads were within 2 cm of the target then and ``--after`` actions later, and the hand's
five servo targets at those two moments (rad): a drop whose pads leave while the targets stay
closed is a slip; one whose targets open first is the policy letting go
(results/cpu-state-std-2026-11-27/: the toy airplane's drops are slips mid-lift).

    python scripts/episode_outcomes.py RUN_DIR [--envs 50] [--seed 11] [--h-bar M]
                                       [--lifted 0.01] [--drop 0.03] [--after 6]
"""

from __future__ import annotations

import argparse
import dataclasses
from collections import Counter
from pathlib import Path

import torch
from tensordict import TensorDictBase

from trainer.evaluation import ENDINGS, classify_endings
from trainer.grasps import keypoint_distances
from trainer.grasps.outcomes import HELD_DISTANCE
from trainer.session import EvalSession
from trainer.tasks import GraspTask

CLASSES = ("success", "never lifted", "dropped", "stalled")
"""The classes of ``ENDINGS`` that ``classify`` gives (by the heights alone: no never reached,
no knocked off)."""


@dataclasses.dataclass
class Episode:
    """One env's episode: its class, length, highest centre rise (m) and the action (0-based)
    of it, pads within 2 cm and servo targets (rad) at that action and ``after`` actions on."""

    outcome: str
    length: int
    peak_rise: float
    peak_action: int
    end_rise: float
    pads_at_peak: int
    pads_after: int
    hand_at_peak: list[float]
    hand_after: list[float]


def classify(rise: torch.Tensor, success: bool, lifted: float, drop: float) -> str:
    """The class of one episode from its (T,) centre rise (m) up to its end (``trainer
    eval``'s ``classify_endings``, without its knocked-off class)."""
    index = classify_endings(torch.zeros(1), rise.max()[None], rise[-1:],
                             torch.tensor([success]), lifted, drop, knocked_off=None)
    return ENDINGS[int(index[0])]


def outcomes(run_dir: Path, envs: int = 50, seed: int = 11, h_bar: float | None = None,
             lifted: float = 0.01, drop: float = 0.03, after: int = 6) -> list[Episode]:
    """One deterministic episode in each of ``envs`` envs of the run's last checkpoint (the
    run's env config, uncompiled, seeded ``seed``; ``h_bar``: the lift target (m) instead of
    the run's)."""
    session = EvalSession.load(run_dir, h_bar=h_bar)
    env = session.env(envs, seed, compile=False, quiet=True)
    rise: list[torch.Tensor] = []  # per action, (E,) each
    pads: list[torch.Tensor] = []
    hand: list[torch.Tensor] = []

    def on_step(env: GraspTask, step: int, td: TensorDictBase) -> None:
        pos, _ = env.target_pose()
        rise.append((pos[:, 2] - env.state["start_height"]).cpu())
        if env.objects.sdf is not None:
            pads.append((keypoint_distances(env)[:, 1:] < HELD_DISTANCE).sum(-1).cpu())
        else:  # a run without SDF grids (the com reward): no pad is counted near
            pads.append(torch.zeros(env.num_envs, dtype=torch.long))
        hand.append(env.state["ctrl"][:, env.robot.hand.actuators].cpu())

    success, length, _ = session.run(env, on_step=on_step)
    env.close()
    rises, near, targets = torch.stack(rise), torch.stack(pads), torch.stack(hand)  # (T, E, ...)
    episodes = []
    for e in range(envs):
        n = int(length[e])
        r = rises[:n, e]
        peak = int(r.argmax())
        later = min(peak + after, n - 1)
        episodes.append(Episode(
            classify(r, bool(success[e]), lifted, drop), n, float(r[peak]), peak,
            float(r[-1]), int(near[peak, e]), int(near[later, e]),
            targets[peak, e].tolist(), targets[later, e].tolist()))
    return episodes


def main(argv: list[str] | None = None) -> list[str]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("run_dir", type=Path)
    parser.add_argument("--envs", type=int, default=50)
    parser.add_argument("--seed", type=int, default=11)
    parser.add_argument("--h-bar", type=float, default=None)
    parser.add_argument("--lifted", type=float, default=0.01)
    parser.add_argument("--drop", type=float, default=0.03)
    parser.add_argument("--after", type=int, default=6)
    args = parser.parse_args(argv)
    episodes = outcomes(args.run_dir, args.envs, args.seed, args.h_bar, args.lifted, args.drop,
                        args.after)
    counts = Counter(ep.outcome for ep in episodes)
    lines = [" | ".join(f"{c} {counts.get(c, 0)}" for c in CLASSES) + f" (of {len(episodes)})",
             f"env outcome length peak_rise at end_rise pads_at_peak pads_{args.after}_later "
             f"hand_at_peak hand_{args.after}_later"]

    def fmt(values: list[float]) -> str:
        return "[" + " ".join(f"{v:.2f}" for v in values) + "]"

    for e, ep in enumerate(episodes):
        lines.append(f"{e} {ep.outcome.replace(' ', '_')} {ep.length} {ep.peak_rise:.3f} "
                     f"{ep.peak_action} {ep.end_rise:.3f} {ep.pads_at_peak} {ep.pads_after} "
                     f"{fmt(ep.hand_at_peak)} {fmt(ep.hand_after)}")
    print("\n".join(lines))
    return lines


if __name__ == "__main__":
    main()
