"""A run's training curve in blocks of env steps, as a Markdown table: what the results READMEs
quote ("means per block of 0.25 M env steps").

    python scripts/metrics_blocks.py RUN_DIR_OR_METRICS_CSV [...] [--block 250000]

Per block of ``--block`` env steps (by each iteration's ``env_steps`` at its end): the episode
rates and means weighted by the episodes that ended in each iteration (``target_success_rate``:
held at the run's own curriculum target, episodes from home only; ``object_success_rate``: at
the task's h_bar, averaged over objects; ``episode_return``), the plain mean of the per-iteration
values (``h_bar``, ``action_std``), the sum of ``unstable_resets``, and the training minutes at
the block's end. Several runs print one table each, on the same blocks.
"""

from __future__ import annotations

import argparse
import csv
import math
from pathlib import Path

WEIGHTED = ("target_success_rate", "object_success_rate", "episode_return")
"""Columns averaged over the episodes that ended (each iteration's ``episodes``)."""
PLAIN = ("h_bar", "action_std")
"""Columns averaged over iterations."""
HEADER = ("env steps", "held at its targets", "at h_bar", "return", "mean target (cm)",
          "action std", "unstable resets", "minutes")


def read_rows(path: Path) -> list[dict[str, float]]:
    """metrics.csv of a run directory (or the file itself) as floats ('' and 'nan' -> nan)."""
    from trainer.training.run_dir import RunDir

    csv_path = RunDir(path).metrics if path.is_dir() else path
    if not csv_path.is_file():
        raise SystemExit(f"{path}: no metrics.csv there (give a run directory or the csv itself)")
    with csv_path.open() as f:
        return [{k: float(v) if v not in ("", None) else math.nan for k, v in row.items()}
                for row in csv.DictReader(f)]


def blocks(rows: list[dict[str, float]], block: int) -> list[dict[str, float]]:
    """One summary per block of ``block`` env steps that holds at least one iteration."""
    grouped: dict[int, list[dict[str, float]]] = {}
    for row in rows:
        grouped.setdefault(int((row["env_steps"] - 1) // block), []).append(row)
    out = []
    for index in sorted(grouped):
        members = grouped[index]
        summary = {"start": index * block, "end": (index + 1) * block}
        for key in WEIGHTED:
            pairs = [(r.get(key, math.nan), r.get("episodes", 0.0)) for r in members]
            pairs = [(v, w) for v, w in pairs if not math.isnan(v) and w > 0]
            total = sum(w for _, w in pairs)
            summary[key] = sum(v * w for v, w in pairs) / total if total else math.nan
        for key in PLAIN:
            values = [r[key] for r in members if not math.isnan(r.get(key, math.nan))]
            summary[key] = sum(values) / len(values) if values else math.nan
        summary["unstable_resets"] = sum(r.get("unstable_resets", 0.0) for r in members)
        summary["minutes"] = members[-1]["wall_time_s"] / 60
        out.append(summary)
    return out


def table(summaries: list[dict[str, float]]) -> list[str]:
    """Markdown lines: a header and one row per block."""
    lines = ["| " + " | ".join(HEADER) + " |", "|" + "---:|" * len(HEADER)]
    for s in summaries:
        lines.append(
            f"| {s['start'] / 1e6:.2f}-{s['end'] / 1e6:.2f} M | {s['target_success_rate']:.3f} | "
            f"{s['object_success_rate']:.3f} | {s['episode_return']:,.0f} | "
            f"{100 * s['h_bar']:.1f} | {s['action_std']:.2f} | {s['unstable_resets']:.0f} | "
            f"{s['minutes']:.0f} |")
    return lines


def main(argv: list[str] | None = None) -> list[str]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", nargs="+", type=Path, help="run directories or metrics.csv files")
    parser.add_argument("--block", type=int, default=250_000, help="env steps per block")
    args = parser.parse_args(argv)
    if args.block <= 0:
        raise SystemExit(f"--block {args.block}: give a positive number of env steps")
    lines: list[str] = []
    for run in args.runs:
        lines += [f"{run}:", "", *table(blocks(read_rows(run), args.block)), ""]
    return lines


if __name__ == "__main__":
    print("\n".join(main()))
