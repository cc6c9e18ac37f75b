"""Where each run stands, as a Markdown table: what a results README's "where the arms stand"
quotes, made from the run folders alone (so that it cannot drift from them).

    python scripts/run_status.py RUN_DIR [...] [--eval eval] [--allow-differ FIELD,...]

One row per run, in ``trainer report``'s arm order and with its arm names (the settings in
which an arm differs from most runs in brackets): seed, env steps so far of the run's
``total_steps``, minutes of training (its clock: over every machine that trained it), the
machines (``launches.csv``; "not recorded" before 2026-11-30) and, once evaluated, the held
rate of ``trainer eval`` (folder ``--eval``: successes over episodes, all objects).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from trainer.errors import TrainerError  # noqa: E402
from trainer.report import (  # noqa: E402
    allowing_differences,
    eval_success,
    group_labels,
    group_runs,
    load_run,
)
from trainer.training.run_dir import RunDir  # noqa: E402

HEADER = ("arm", "seed", "env steps (M)", "minutes", "machines", "held (eval)")


def status_table(run_dirs: list[Path], eval_dir: str = "eval",
                 allow_differ: tuple[str, ...] = ()) -> str:
    runs = allowing_differences([load_run(d, eval_dir) for d in run_dirs], allow_differ)
    labels = group_labels(runs)
    lines = ["| " + " | ".join(HEADER) + " |", "|---|---:|---:|---:|---|---:|"]
    for key, members in group_runs(runs).items():
        for r in members:
            total = json.loads(RunDir(r.path).config.read_text())["run"].get("total_steps")
            steps = f"{r.env_steps[-1] / 1e6:.2f}" if len(r.env_steps) else "0"
            if total is not None:
                steps += f" of {total / 1e6:.2f}"
            minutes = f"{r.wall_time_s[-1] / 60:.0f}" if len(r.wall_time_s) else "0"
            machines = "; ".join(dict.fromkeys(words for _, words, _ in r.machines))
            if not r.machines or r.machines[0][0] > 1:
                machines = "; ".join(filter(None, ["not recorded", machines]))
            held = f"**{eval_success(r):.3f}**" if r.per_object is not None else "—"
            lines.append(f"| {labels[key]} | {r.seed} | {steps} | {minutes} | {machines} | "
                         f"{held} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", type=Path)
    parser.add_argument("--eval", default="eval", help="the evaluation folder in each run")
    parser.add_argument("--allow-differ", default="",
                        help="config fields seeds may differ in, as trainer report takes them")
    args = parser.parse_args(argv)
    allowed = tuple(f for f in args.allow_differ.split(",") if f)
    try:
        print(status_table(args.runs, args.eval, allowed), end="")
    except TrainerError as err:
        raise SystemExit(f"run_status: {err}") from None


if __name__ == "__main__":
    main()
