"""Why bin picking fails before any learning: each target's best scripted grasp run in clutter.

    python scripts/bin_diagnosis.py --objects NAMES --bin-objects 5 --trials 64 \\
        [--config FILE] [--set KEY=VALUE ...] [--data-dir data] [--seed 0] [--out DIR] [--video]

The bin task of the config (``--objects`` and ``--bin-objects`` for its object set and bins;
the hand and physics as ``trainer run`` would have them), ``--trials`` envs per grasp family.
Each target runs the grasp that lifts it alone on the table: its ``BEST`` family, else its
searched grasp (``trainer.training.grasp_starts.object_grasps``: found, or searched now and
stored). A family runs on every env of its batch, each env's target drawn by the task as in
training; only the envs whose target it serves count. Per trial, from the bin after the
script's first action (as ``trainer.grasps.outcomes`` measures) and at its end:

- ``outcome``: lifted (the task's success: raised by h_bar, held) / dropped / no_grip /
  pushed (``outcomes.classify``);
- ``covered``: another object lies over the target (a surface sample of it within the
  target's horizontal footprint, shrunk by ``FOOTPRINT_MARGIN``, and higher than the target's
  top less ``COVER_TOLERANCE``);
- ``wall_gap`` (m): the target's nearest surface sample to a bin wall (horizontally);
  ``at_wall`` when below ``WALL_GAP``;
- ``neighbour_rose`` (m): the most any other object rose by the end; ``with_neighbour`` when
  above ``NEIGHBOUR_RISE`` (it came up with the target, or was knocked up).

Each failure is then named by its first mechanism in this order: ``covered`` (the hand meets
another object first), ``at wall`` (the approach or the fingers meet the wall), then its
outcome (``pushed``, ``no_grip``, ``dropped``). Prints a table per target object and overall,
and the lift rate by where the target lay (free, at the wall, covered, both); with ``--out DIR``
writes ``trials.csv`` (one row per trial) and ``table.md``, and with ``--video`` a video of
each family's first ``FILMED`` envs (``trials.csv``'s ``filmed``: which tile).
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import sys
from collections import Counter
from pathlib import Path

import torch

from geomgrasp.files import atomic_path
from geomgrasp.rotations import quat_to_matrix
from trainer.config import load_env_config
from trainer.config_keys import parse_sets
from trainer.errors import TrainerError
from trainer.grasps.families import best_variants
from trainer.grasps.keyframes import KeyframeGrasp
from trainer.grasps.outcomes import OUTCOMES, classify
from trainer.grasps.runner import TrajectoryRecorder, episode_config, run_scripted_grasp
from trainer.objects import task_names
from trainer.tasks import GraspTask, make_env
from trainer.training.grasp_starts import object_grasps

FOOTPRINT_MARGIN = 0.005
"""m: the target's horizontal footprint (its surface samples' bounding box) shrunk by this on
each side before another object's sample counts as over it (samples of a neighbour that only
touches its side stay out)."""
COVER_TOLERANCE = 0.01
"""m: a neighbour's sample over the footprint and above the target's top less this covers it."""
WALL_GAP = 0.02
"""m: a target whose nearest surface sample is closer than this to a wall is at the wall (the
fingertip pads are ~2 cm wide: a finger cannot pass between them)."""
NEIGHBOUR_RISE = 0.05
"""m: another object risen more than this by the script's end came up with the target."""
FIELDS = ("family", "target", "outcome", "covered", "wall_gap", "at_wall", "neighbour_rose",
          "with_neighbour", "mechanism", "filmed")
FILMED = 4
"""Envs filmed per family with ``--video`` (tiles left to right: env 0, 1, ...)."""
CONDITIONS = ("free", "at wall only", "covered only", "covered and at wall")


def world_points(env: GraspTask, qpos: torch.Tensor) -> torch.Tensor:
    """(E, K, P, 3): every slot's object surface samples in the world for the state ``qpos``."""
    poses = env.slot_poses(qpos)  # (E, K, 7)
    local = env.objects.points[env.assignment]  # (E, K, P, 3)
    rot = quat_to_matrix(poses[..., 3:])  # (E, K, 3, 3)
    return torch.einsum("ekij,ekpj->ekpi", rot, local) + poses[..., None, :3]


def clutter(env: GraspTask, qpos: torch.Tensor) -> dict[str, torch.Tensor]:
    """The target's place in its bin for the state ``qpos``: ``covered`` (E,) bool and
    ``wall_gap`` (E,) m (see the module's docstring)."""
    points = world_points(env, qpos)
    E, K = points.shape[:2]
    slot = env.state["target_slot"]
    target = points[torch.arange(E), slot]  # (E, P, 3)
    lo = target[..., :2].amin(1) + FOOTPRINT_MARGIN  # (E, 2)
    hi = target[..., :2].amax(1) - FOOTPRINT_MARGIN
    top = target[..., 2].amax(1)  # (E,)
    others = torch.ones(E, K, dtype=torch.bool, device=points.device)
    others[torch.arange(E), slot] = False
    xy = points[..., :2]
    inside = ((xy >= lo[:, None, None]) & (xy <= hi[:, None, None])).all(-1)  # (E, K, P)
    above = points[..., 2] > (top - COVER_TOLERANCE)[:, None, None]
    covered = (inside & above & others[..., None]).flatten(1).any(1)
    hx, hy = env.cfg.bin.inner_half_size
    gap = torch.minimum(hx - target[..., 0].abs(), hy - target[..., 1].abs()).amin(1)
    return {"covered": covered, "wall_gap": gap}


def mechanism(outcome: str, covered: bool, at_wall: bool) -> str:
    """A failed trial's mechanism: the first of covered, at wall, then its outcome."""
    if outcome == "lifted":
        return "lifted"
    if covered:
        return "covered"
    if at_wall:
        return "at wall"
    return outcome


def run_family(env: GraspTask, script: object, serves: torch.Tensor,
               video: Path | None = None) -> list[dict]:
    """One batch: ``script`` on every env of ``env``; the rows of the envs whose target is one of
    the object ids ``serves``. ``video``: film the batch's first ``FILMED`` envs side by side
    (their rows carry ``filmed``: the tile, from the left)."""
    film = None
    if video is not None:
        from trainer.video import EnvRecorder

        film = EnvRecorder(env, range(min(FILMED, env.num_envs)), width=320, height=240)
    recorder = TrajectoryRecorder(env)
    first: dict[str, torch.Tensor] = {}
    start_z: list[torch.Tensor] = []

    def capture(step: int) -> None:
        if film is not None:
            film.capture()
        if step == 0:  # after the first action: the bin as the hand meets it
            qpos = env.backend.qpos.clone()
            first.update(clutter(env, qpos))
            start_z.append(env.slot_poses(qpos)[..., 2].clone())

    run_scripted_grasp(env, script, on_step=capture, recorder=recorder)  # type: ignore[arg-type]
    if film is not None and video is not None:
        film.save(video, fps=env.cfg.physics.control_hz)
        film.close()
    trajectory = recorder.trajectory()
    codes = classify(trajectory, script.pushed_at)  # type: ignore[attr-defined]
    rose = env.slot_poses(env.backend.qpos)[..., 2] - start_z[0]  # (E, K)
    E = env.num_envs
    slot = env.state["target_slot"]
    rose[torch.arange(E), slot] = float("-inf")
    neighbour = rose.amax(1)
    targets = env.target_objects()
    rows = []
    for e in range(E):
        if not bool(torch.isin(targets[e], serves)):
            continue
        outcome = OUTCOMES[int(codes[e])]
        covered, gap = bool(first["covered"][e]), float(first["wall_gap"][e])
        rows.append({
            "target": env.objects.names[int(targets[e])], "outcome": outcome,
            "covered": covered, "wall_gap": round(gap, 4), "at_wall": gap < WALL_GAP,
            "neighbour_rose": round(float(neighbour[e]), 4),
            "with_neighbour": float(neighbour[e]) > NEIGHBOUR_RISE,
            "mechanism": mechanism(outcome, covered, gap < WALL_GAP),
            "filmed": e if film is not None and e < FILMED else "",
        })
    return rows


def table(rows: list[dict]) -> list[str]:
    """Markdown: per target object and overall, trials, lifted, lifted with a neighbour, the
    start conditions (covered, at the wall) and the failures by mechanism."""
    mechanisms = ("covered", "at wall", "pushed", "no_grip", "dropped")
    lines = ["| target | trials | lifted | with neighbour | covered | at wall | "
             + " | ".join(f"fail: {m}" for m in mechanisms) + " |",
             "|---|" + "---:|" * (5 + len(mechanisms))]
    groups = sorted({r["target"] for r in rows}) + ["overall"]
    for name in groups:
        mine = [r for r in rows if name in ("overall", r["target"])]
        count = Counter(r["mechanism"] for r in mine)
        lifted = count["lifted"]
        lines.append(
            f"| {name} | {len(mine)} | {lifted} ({lifted / len(mine):.2f}) | "
            f"{sum(r['with_neighbour'] and r['outcome'] == 'lifted' for r in mine)} | "
            f"{sum(r['covered'] for r in mine)} | {sum(r['at_wall'] for r in mine)} | "
            + " | ".join(str(count[m]) for m in mechanisms) + " |")
    # The lift rate by where the target lay: what the bin's conditions cost, measured.
    lines += ["", "| where the target lay | trials | lifted |", "|---|---:|---:|"]
    for name in CONDITIONS:
        mine = [r for r in rows if condition(r) == name]
        lifted = sum(r["outcome"] == "lifted" for r in mine)
        rate = f" ({lifted / len(mine):.2f})" if mine else ""
        lines.append(f"| {name} | {len(mine)} | {lifted}{rate} |")
    return lines


def condition(row: dict) -> str:
    """One of ``CONDITIONS`` for a trial's row."""
    return CONDITIONS[int(bool(row["at_wall"])) + 2 * int(bool(row["covered"]))]


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--objects", required=True, help="object set or names (the bins' pool)")
    parser.add_argument("--bin-objects", type=int, default=5)
    parser.add_argument("--trials", type=int, default=64, help="envs per grasp family")
    parser.add_argument("--config", type=Path, default=None)
    parser.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument("--data-dir", type=Path, default=None)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=None)
    parser.add_argument("--video", action="store_true",
                        help=f"film the first {FILMED} envs of each family into --out")
    args = parser.parse_args(argv)
    try:
        rows = diagnose(args)
    except TrainerError as exc:
        sys.exit(f"error: {exc}")
    print("\n".join(table(rows)))
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        with atomic_path(args.out / "trials.csv") as tmp, tmp.open("w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=FIELDS)
            writer.writeheader()
            writer.writerows(rows)
        with atomic_path(args.out / "table.md") as tmp:
            tmp.write_text("\n".join(table(rows)) + "\n")
        print(f"written: {args.out / 'trials.csv'}, {args.out / 'table.md'}")


def diagnose(args: argparse.Namespace) -> list[dict]:
    """Every family's batch of trials in the bins of ``args``: one row per counted trial."""
    if args.trials < 1:
        raise TrainerError(f"--trials {args.trials}: must be >= 1")
    if args.video and args.out is None:
        raise TrainerError("--video needs --out DIR (the videos are written there)")
    overrides = {"data_dir": args.data_dir} if args.data_dir else {}
    cfg = load_env_config(args.config, parse_sets(args.sets), task="bin", objects=args.objects,
                          num_envs=args.trials, representation="bbox", **overrides)
    cfg = dataclasses.replace(cfg, bin=dataclasses.replace(cfg.bin, num_objects=args.bin_objects))
    names = task_names(cfg)
    grasps = object_grasps(cfg, "best")
    batches = best_variants(names, searched=[n for n in names if "theta" in grasps[n]])
    rows: list[dict] = []
    for spec, (variant, mine) in batches.items():
        script = variant.script
        if isinstance(script, KeyframeGrasp):
            script = script.covering(names)  # (the other objects' envs run it too, uncounted)
        env = make_env(episode_config(cfg, script), seed=args.seed)
        try:
            serves = torch.tensor([names.index(n) for n in mine], device=env.device)
            video = None
            if args.video:
                args.out.mkdir(parents=True, exist_ok=True)
                video = args.out / f"{spec.replace(':', '-').replace('+', '-')}.mp4"
            batch = run_family(env, script, serves, video)
        finally:
            env.close()
        print(f"{spec}: {len(batch)} trials on {', '.join(mine)}", flush=True)
        rows += [{"family": spec, **r} for r in batch]
    return rows


if __name__ == "__main__":
    main()
