"""Each object's lift-curriculum target over a run with ``[reward] curriculum_per_object``: read
from every kept checkpoint (one per ``checkpoint_every`` iterations, and the last), with the
held rate at that target over the object's last episodes (the window the curriculum promotes
on). Writes a CSV (iteration, env_steps, minutes, then ``<object>`` targets in m and
``<object>_held`` rates) and plots the targets over env steps.

    python scripts/object_curriculum.py RUN_DIR [--csv FILE] [--png FILE]

(``trainer report`` plots the run's mean target from metrics.csv; this is the per-object view,
e.g. results/cpu-table1-together-2026-11-26/.)
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path


def rows_of(run_dir: Path) -> tuple[list[str], list[dict[str, float]]]:
    """(object names, one row per kept checkpoint, oldest first)."""
    from trainer.errors import TrainerError
    from trainer.objects import task_names
    from trainer.training.checkpoint import read_checkpoint
    from trainer.training.run_dir import RunDir

    run = RunDir(run_dir)
    cfg = run.load_config()
    if not cfg.env.reward.curriculum_per_object:
        raise TrainerError(f"{run_dir}: not a per-object curriculum run "
                           "([reward] curriculum_per_object = false): see trainer report")
    names = task_names(cfg.env)
    steps: dict[int, tuple[float, float]] = {}
    with open(run.metrics, newline="") as handle:
        for row in csv.DictReader(handle):
            steps[int(row["iteration"])] = (float(row["env_steps"]), float(row["wall_time_s"]))
    paths = [run.checkpoint(i) for i in run.checkpoint_iterations()]
    if run.last.is_file():
        paths.append(run.last)
    out: dict[int, dict[str, float]] = {}
    for path in paths:
        state = read_checkpoint(path, map_location="cpu")
        if isinstance(state, str) or state["iteration"] not in steps:
            continue
        it = int(state["iteration"])
        env_steps, seconds = steps[it]
        row = {"iteration": it, "env_steps": env_steps, "minutes": round(seconds / 60, 2)}
        for k, name in enumerate(names):
            row[name] = float(state["h_bar"][k])
            window = state["target_outcomes"].get(k, [])
            row[f"{name}_held"] = sum(window) / len(window) if window else float("nan")
        out[it] = row
    if not out:
        raise TrainerError(f"{run_dir}: no readable checkpoint with metrics: train it first")
    return names, [out[i] for i in sorted(out)]


def plot(names: list[str], rows: list[dict[str, float]], png: Path) -> None:
    from trainer.report import _pyplot, _save

    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(8, 4.5))
    x = [r["env_steps"] / 1e6 for r in rows]
    for name in names:
        ax.plot(x, [r[name] for r in rows], label=name, drawstyle="steps-post")
    ax.set_xlabel("env steps (M)")
    ax.set_ylabel("lift target (m)")
    ax.set_title("per-object lift curriculum")
    ax.legend(fontsize=7, ncol=2)
    _save(fig, png)


def main(argv: list[str] | None = None) -> list[dict[str, float]]:
    from trainer.errors import TrainerError

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("run_dir", type=Path)
    parser.add_argument("--csv", type=Path, default=None, help="default: RUN_DIR/curriculum.csv")
    parser.add_argument("--png", type=Path, default=None, help="default: beside the CSV")
    args = parser.parse_args(argv)
    try:
        names, rows = rows_of(args.run_dir)
    except TrainerError as exc:
        raise SystemExit(f"object_curriculum: {exc}") from None
    out = args.csv or args.run_dir / "curriculum.csv"
    with open(out, "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    plot(names, rows, args.png or out.with_suffix(".png"))
    last = rows[-1]
    print(f"{len(rows)} checkpoints, to iteration {last['iteration']} "
          f"({last['env_steps'] / 1e6:.2f} M env steps, {last['minutes']:.0f} min): {out}")
    for name in names:
        print(f"  {name:24} {last[name]:.2f} m, held {last[f'{name}_held']:.2f}")
    return rows


if __name__ == "__main__":
    main()
