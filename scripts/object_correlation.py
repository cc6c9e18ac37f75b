"""Which objects succeed together across runs: per pair of objects, Spearman's rank correlation
of their ``trainer eval`` successes over the runs given (each run's ``eval/per_object.csv``).
Two objects a policy learns with one skill rise and fall together from run to run; an object
that needs another skill does not follow them (results/cpu-comparison-2026-11-29/, 2026-11-30:
the knife and the dice against the plate).

    python scripts/object_correlation.py RUN_DIR... --objects A,B[,C...]

Prints the runs' successes per object, then a markdown table of the correlations (ties given
their average rank; "—" where one object has the same count in every run).
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path


def successes(run_dirs: list[Path], objects: list[str]) -> list[list[int]]:
    """Per run, the evaluation's successes of each of ``objects`` (TrainerError naming the run
    where one has no evaluation or lacks an object)."""
    from trainer.errors import TrainerError
    from trainer.report import read_per_object

    out = []
    for run in run_dirs:
        path = run / "eval" / "per_object.csv"
        if not path.is_file():
            raise TrainerError(f"{path}: missing; evaluate the run with trainer eval first")
        evaluated = read_per_object(path)
        missing = [name for name in objects if name not in evaluated]
        if missing:
            raise TrainerError(f"{path}: no {', '.join(missing)}; its objects: "
                               f"{', '.join(evaluated)}")
        out.append([evaluated[name][1] for name in objects])
    return out


def correlations(counts: list[list[int]]) -> list[list[float]]:
    """Spearman's rho between every two columns of ``counts`` (runs x objects); NaN where a
    column is constant."""
    from trainer.report import spearman

    columns = list(zip(*counts, strict=True))
    return [[spearman(a, b) for b in columns] for a in columns]


def table(run_dirs: list[Path], objects: list[str], counts: list[list[int]]) -> list[str]:
    lines = ["| run | " + " | ".join(objects) + " |", "|---|" + "---:|" * len(objects)]
    lines += [f"| {run.name} | " + " | ".join(str(c) for c in row) + " |"
              for run, row in zip(run_dirs, counts, strict=True)]
    rho = correlations(counts)
    lines += ["", f"Spearman's rho over {len(run_dirs)} runs:", "",
              "| | " + " | ".join(objects) + " |", "|---|" + "---:|" * len(objects)]
    for name, row in zip(objects, rho, strict=True):
        lines.append(f"| {name} | " + " | ".join("—" if math.isnan(r) else f"{r:+.2f}"
                                                 for r in row) + " |")
    return lines


def main(argv: list[str] | None = None) -> list[str]:
    from trainer.errors import TrainerError

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("run_dir", type=Path, nargs="+")
    parser.add_argument("--objects", required=True, help="two or more, comma-separated")
    args = parser.parse_args(argv)
    objects = args.objects.split(",")
    if len(objects) < 2 or len(set(objects)) < len(objects):
        parser.error(f"--objects {args.objects}: two or more different objects")
    if len(args.run_dir) < 3:
        parser.error("a correlation over fewer than three runs says nothing: give three or more")
    try:
        lines = table(args.run_dir, objects, successes(args.run_dir, objects))
    except TrainerError as exc:
        raise SystemExit(f"object_correlation: {exc}") from None
    print("\n".join(lines))
    return lines


if __name__ == "__main__":
    main()
