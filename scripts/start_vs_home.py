"""Where a trained policy fails an object: from home, or after the grasp is already in hand.
Per object, how often a run's last checkpoint succeeds at a low lift target (``--h-bar``,
default 0.03 m: the lift curriculum's first rung) in three kinds of episode, its actions sampled
from its Gaussian as in training:

- ``home``: from a settled state with the robot at home, as every evaluation and the training
  episodes the lift curriculum counts;
- ``starts``: from one of the run's own recorded scripted-grasp states (its ``grasp_starts.pt``,
  ``[run] grasp_starts``; drawn as in training among those below the target), the training
  episodes the curriculum does not count; only envs with a start take part;
- ``closed``: from each env's last recorded state below the target, the script's hand closed
  around the object and not yet lifting it: all that is left to do is hold on and rise.

A policy that lifts an object from the closed grasp and fails it from the open-hand states and
from home has the lift and lacks the closing; one that fails from the closed grasp too loses a
grasp already made (results/cpu-comparison-2026-11-29/, chunk 13: the runs whose knife and dice
stayed on the curriculum's first rung lift them from the closed grasp as well as the others).

    python scripts/start_vs_home.py RUN... [--objects A,B] [--h-bar 0.03] [--rounds 2]
                                    [--seed 7] [--deterministic] [--kinds home,starts,closed]
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import torch

from trainer.session import EvalSession
from trainer.tasks.starts import GraspStarts
from trainer.training.run_dir import RunDir

KINDS = ("home", "starts", "closed")
"""The kinds of episode, as the module's docstring says."""


def usable(starts: GraspStarts, below: torch.Tensor) -> torch.Tensor:
    """(E, S) bool: the captures a reset may start from, valid and lifted less than ``below``
    (E,) m, the env's target (as ``GraspStart`` draws them)."""
    return starts.valid & (starts.lift < below[:, None])


def closed_starts(starts: GraspStarts, below: torch.Tensor) -> GraspStarts:
    """``starts`` with one valid state per env: its last valid capture whose lift is under
    ``below`` (E,) m, the furthest along the script before the target is reached (none where
    the env has none)."""
    usable_now = usable(starts, below)
    S = usable_now.shape[1]
    last = torch.where(usable_now, torch.arange(S), -1).amax(1)  # (E,), -1: none
    valid = torch.zeros_like(usable_now)
    has = last >= 0
    valid[has, last[has]] = True
    return dataclasses.replace(starts, valid=valid)


def _episodes(session: EvalSession, seed: int, starts: GraspStarts | None,
              deterministic: bool) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """One episode in each of the run's envs (its ``num_envs``, so that its recorded starts fit
    env by env): (E,) success, (E,) target object id, (E,) whether the env took part (from
    home: all; from starts: those with a valid recorded state)."""
    env = session.env(session.cfg.env.num_envs, seed, compile=False, quiet=True)
    part = torch.ones(env.num_envs, dtype=torch.bool)
    if starts is not None:
        env.set_grasp_starts(starts, 1.0, torch.Generator().manual_seed(seed))
        part = usable(starts, env.h_bar[env.target_objects()].cpu()).any(1)
    with session.sampling(seed):
        success, _, target = session.run(env, deterministic=deterministic)
    env.close()
    return success, target, part


def start_vs_home(run_dir: Path, objects: list[str] | None = None, h_bar: float = 0.03,
                  rounds: int = 2, seed: int = 7, deterministic: bool = False,
                  kinds: tuple[str, ...] = KINDS) -> dict[str, dict[str, tuple[int, int]]]:
    """Object name -> {kind: (successes, episodes)} for each of ``kinds`` (``KINDS``) over
    ``rounds`` episodes per env of each kind (seeds ``seed``, ``seed + 1``, ...), the success
    test the run's at lift target ``h_bar``; ``objects`` (default: all of the run's)."""
    run = RunDir(run_dir)
    if not run.grasp_starts.exists():
        raise SystemExit(f"{run_dir} has no grasp_starts.pt: pass a run trained with "
                         "[run] grasp_starts > 0 (it records them when it starts)")
    session = EvalSession.load(run_dir, h_bar=h_bar)
    starts = GraspStarts.load(run.grasp_starts)
    if starts.lift is None:
        raise SystemExit(f"{run_dir}: its grasp_starts.pt predates the recorded lifts; record "
                         "it again (a run of this code does)")
    names = session.names()
    given_by_kind = {
        "home": None, "starts": starts,
        "closed": closed_starts(starts, torch.full((starts.valid.shape[0],), h_bar))}
    counts = {n: {k: [0, 0] for k in kinds} for n in names}
    for r in range(rounds):
        for kind in kinds:
            given = given_by_kind[kind]
            success, target, part = _episodes(session, seed + r, given, deterministic)
            for i, name in enumerate(names):
                mine = part & (target == i)
                counts[name][kind][0] += int(success[mine].sum())
                counts[name][kind][1] += int(mine.sum())
    chosen = objects or names
    return {n: {k: (v[0], v[1]) for k, v in counts[n].items()} for n in chosen}


def main(argv: list[str] | None = None) -> list[str]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", type=Path, nargs="+")
    parser.add_argument("--objects", default=None)
    parser.add_argument("--h-bar", type=float, default=0.03)
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--seed", type=int, default=7)
    parser.add_argument("--deterministic", action="store_true")
    parser.add_argument("--kinds", default=",".join(KINDS))
    args = parser.parse_args(argv)
    kinds = tuple(args.kinds.split(","))
    if not set(kinds) <= set(KINDS):
        parser.error(f"--kinds {args.kinds}: choose from {','.join(KINDS)}")
    objects = args.objects.split(",") if args.objects else None
    header = {"home": "from home", "starts": "from grasp starts",
              "closed": "from the closed grasp"}
    lines = [f"success at {args.h_bar:g} m, "
             f"{'deterministic' if args.deterministic else 'sampled'} actions, "
             f"{args.rounds} episode(s) per env of each kind",
             "", "| run | object | " + " | ".join(header[k] for k in kinds) + " |",
             "|---|---|" + "---:|" * len(kinds)]
    for run in args.runs:
        table = start_vs_home(run, objects, args.h_bar, args.rounds, args.seed,
                              args.deterministic, kinds)
        for name, row in table.items():
            cells = [f"{s}/{n} ({s / n:.2f})" if n else "-" for s, n in row.values()]
            lines.append(f"| {run.name} | {name} | " + " | ".join(cells) + " |")
    print("\n".join(lines))
    return lines


if __name__ == "__main__":
    main()
