"""Whether two sets of reference runs (``scripts/reference_runs.sh``) measured the same: every
metrics.csv column but the timings (``wall_time_s``, ``fps``), row for row, and the eval tables
line for line (but table.md's machine line, ``Evaluated on ...``, and blank lines).

    python scripts/compare_runs.py NEW REFERENCE [--runs lift,bin,floating,starts,warmup]

Prints IDENTICAL or DIFFERENT (with the first differences) per run; exits 1 if any differs.
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

from trainer.training.run_dir import EVALUATED_ON

TIMINGS = ("wall_time_s", "fps")
EVAL_FILES = ("eval/per_object.csv", "eval/table.md")


def differences(new: Path, reference: Path) -> list[str]:
    """What differs between the run directories ``new`` and ``reference`` (empty: nothing)."""
    for run in (new, reference):
        if not (run / "metrics.csv").is_file():
            return [f"{run} holds no metrics.csv"]
    rows = [list(csv.DictReader((run / "metrics.csv").open())) for run in (new, reference)]
    found = []
    if len(rows[0]) != len(rows[1]):
        found.append(f"{len(rows[0])} rows vs {len(rows[1])}")
    for i, (a, b) in enumerate(zip(*rows, strict=False)):
        for key in sorted(set(a) | set(b)):
            if key not in TIMINGS and a.get(key) != b.get(key):
                found.append(f"row {i + 1} {key}: {a.get(key)} vs {b.get(key)}")
    for name in EVAL_FILES:
        a, b = new / name, reference / name
        if a.is_file() != b.is_file() or (a.is_file() and _results(a) != _results(b)):
            found.append(f"{name} differs")
    return found


def _results(path: Path) -> list[str]:
    """An evaluation file's non-blank lines but table.md's machine, code and time
    (``Evaluated on ...``: like the timings, not a result)."""
    return [line for line in path.read_text().splitlines()
            if line.strip() and not line.startswith(EVALUATED_ON)]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("new", type=Path)
    parser.add_argument("reference", type=Path)
    parser.add_argument("--runs", default="lift,bin,floating,starts,warmup")
    args = parser.parse_args(argv)
    failed = False
    for run in args.runs.split(","):
        found = differences(args.new / run, args.reference / run)
        print(f"{run}: {'DIFFERENT' if found else 'IDENTICAL'}")
        for line in found[:8]:
            print(f"  {line}")
        failed |= bool(found)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
