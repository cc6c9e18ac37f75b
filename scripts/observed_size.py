"""What a trained policy reads from the size it is told an object has. Per object, how often a
run's last checkpoint succeeds at a low lift target (``--h-bar``, default 0.03 m: the lift
curriculum's first rung) from home when its representation shows every object scaled by a
factor about its box centre (``--scales``, 1: as trained), the object itself, its physics, the
lift and the success test unchanged. Actions are sampled from the policy's Gaussian as in
training; every scale plays the same resets and the same action noise (``--seed``), so the
scales differ only in what the policy is told.

bbox: the box's extents scaled (its centre and axes kept); sq: the three semi-axes (the
exponents and the pose kept); pcN: the points about the box centre. com and sdf tell the policy
no size (the pose; the fingertips' measured distances), so they have nothing to scale.

A policy whose success on an object falls as the object is shown larger than it is grasps by
the size it is told; one whose failure on an object does not lift when the object is shown
smaller is not failing it for a misread size (results/cpu-comparison-2026-11-29/, chunk 14:
the knife shown twice its size falls from 0.50 to 0.19 in the runs that lift it; the runs that
fail the dice and the knife fail them as much when shown them at a third or half their size).

    python scripts/observed_size.py RUN... --objects A,B [--scales 0.5,1,2,4]
                                    [--h-bar 0.03] [--envs 120] [--rounds 1] [--seed 7]
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import torch

from trainer.evaluation import counts_by_object
from trainer.objects import ObjectSet
from trainer.session import EvalSession

SIZED = ("bbox", "sq", "pc")
"""The representations that tell the policy an object's size (pcN by its prefix)."""


def scaled_shapes(objects: ObjectSet, factor: float) -> ObjectSet:
    """``objects`` with every object's told shape scaled by ``factor`` about its box centre:
    box extents, superquadric semi-axes, surface points; the rest shared, unchanged."""
    center = objects.bbox_center[:, None, :]  # (N, 1, 3), object frame
    sq = objects.sq_params.clone()
    sq[:, 2:5] *= factor
    return dataclasses.replace(
        objects,
        bbox_extents=objects.bbox_extents * factor,
        sq_params=sq,
        points=center + factor * (objects.points - center),
    )


def observed_size(run_dir: Path, objects: list[str], scales: list[float], h_bar: float = 0.03,
                  envs: int = 120, rounds: int = 1, seed: int = 7,
                  ) -> dict[str, dict[float, tuple[int, int]]]:
    """Object name -> {scale: (successes, episodes)}: ``rounds`` episodes in each of ``envs``
    envs shared among ``objects`` from home, per scale of the told shapes (seeds ``seed``,
    ``seed + 1``, ... the same for every scale), the success the run's at lift target
    ``h_bar``."""
    session = EvalSession.load(run_dir, h_bar=h_bar)
    representation = session.cfg.env.representation
    if not representation.startswith(SIZED):
        raise SystemExit(f"{run_dir}: its representation {representation!r} tells the policy "
                         f"no size; pass a run of {', '.join(SIZED)}")
    totals = torch.zeros(len(scales), 2, len(objects), dtype=torch.long)  # episodes, successes
    for r in range(rounds):
        env = session.env(envs, seed + r, objects, compile=False, quiet=True)
        for k, scale in enumerate(scales):
            env.outputs.observed = scaled_shapes(env.objects, scale)
            env.set_seed(seed + r)  # every scale the same resets
            with session.sampling(seed + r):
                episodes = session.run(env, deterministic=False)
            totals[k] += torch.tensor(counts_by_object(episodes, len(objects)))
        env.close()
    return {name: {scale: (int(totals[k, 1, i]), int(totals[k, 0, i]))
                   for k, scale in enumerate(scales)}
            for i, name in enumerate(env.objects.names)}


def main(argv: list[str] | None = None) -> list[str]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", type=Path, nargs="+")
    parser.add_argument("--objects", required=True)
    parser.add_argument("--scales", default="0.5,1,2,4")
    parser.add_argument("--h-bar", type=float, default=0.03)
    parser.add_argument("--envs", type=int, default=120)
    parser.add_argument("--rounds", type=int, default=1)
    parser.add_argument("--seed", type=int, default=7)
    args = parser.parse_args(argv)
    try:
        scales = [float(s) for s in args.scales.split(",")]
    except ValueError:
        parser.error(f"--scales {args.scales}: give numbers, e.g. 0.5,1,2,4")
    if any(s <= 0 for s in scales) or len(set(scales)) < len(scales):
        parser.error(f"--scales {args.scales}: give distinct positive factors")
    objects = args.objects.split(",")
    lines = [f"success at {args.h_bar:g} m from home, sampled actions, the told shapes scaled; "
             f"{args.rounds} round(s) of {args.envs} envs", "",
             "| run | object | " + " | ".join(f"x{s:g}" for s in scales) + " |",
             "|---|---|" + "---:|" * len(scales)]
    print("\n".join(lines), flush=True)
    for run in args.runs:  # each run's rows as it is done: a run of many takes minutes
        table = observed_size(run, objects, scales, args.h_bar, args.envs, args.rounds,
                              args.seed)
        for name, row in table.items():
            cells = [f"{s}/{n} ({s / n:.2f})" if n else "-" for s, n in row.values()]
            lines.append(f"| {run.name} | {name} | " + " | ".join(cells) + " |")
            print(lines[-1], flush=True)
    return lines


if __name__ == "__main__":
    main()
