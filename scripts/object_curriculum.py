"""Each object's lift-curriculum target over a run with ``[reward] curriculum_per_object``: read
from every kept checkpoint (one per ``checkpoint_every`` iterations, and the last), with the
held rate at that target over the object's last episodes (the window the curriculum promotes
on). Writes a CSV (iteration, env_steps, minutes, then ``<object>`` targets in m and
``<object>_held`` rates) and plots the targets over env steps.

    python scripts/object_curriculum.py RUN_DIR [--csv FILE] [--png FILE]
    python scripts/object_curriculum.py RUN_DIR... --final [--objects A,B]
    python scripts/object_curriculum.py RUN_DIR... --left [--objects A,B]

``--final`` writes nothing: for each run its last checkpoint's target and held rate per object
beside the run's ``trainer eval`` successes (``eval/per_object.csv``), then the (run, object)
pairs grouped by where their target ended (still on the first rung, between, at the task's
h_bar) with their evaluation: results/cpu-comparison-2026-11-29/ (2026-11-30) found the hard
objects evaluated at 0.2 m by whether training had moved them off the first rung.

``--left`` reads the CSV the first form wrote into each run (``RUN_DIR/curriculum.csv``: the
history, which outlives the checkpoints it was read from) and says, in env steps, when each
object's target first left the first rung and when it reached h_bar, beside the evaluation;
then per object over the runs, and the evaluated pairs grouped by when they left (``--edges``):
results/cpu-comparison-2026-11-29/first-rung-timing.md (2026-11-30).

(``trainer report`` plots the run's mean target from metrics.csv; this is the per-object view,
e.g. results/cpu-table1-together-2026-11-26/.)
"""

from __future__ import annotations

import argparse
import csv
import math
import statistics
from pathlib import Path


def rows_of(run_dir: Path, last_only: bool = False) -> tuple[list[str], list[dict[str, float]]]:
    """(object names, one row per kept checkpoint, oldest first; the last one only with
    ``last_only``)."""
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
    paths = [] if last_only else [run.checkpoint(i) for i in run.checkpoint_iterations()]
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


def evaluation(run_dir: Path) -> dict[str, tuple[int, int]]:
    """The run's ``trainer eval`` per object: name -> (episodes, successes); empty where the run
    was not evaluated (no ``eval/per_object.csv``)."""
    from trainer.report import read_per_object

    path = run_dir / "eval" / "per_object.csv"
    return read_per_object(path) if path.is_file() else {}


def final_rows(run_dirs: list[Path], objects: list[str] | None = None) -> list[dict]:
    """Per run and object (the run's, or ``objects``): the last checkpoint's target (m) and held
    rate at it, the first rung's target (``reward.h_bar_start``), the task's ``h_bar``, and the
    evaluation's successes and episodes (``eval/per_object.csv``; None where not evaluated)."""
    from trainer.errors import TrainerError
    from trainer.training.run_dir import RunDir

    out = []
    for run_dir in run_dirs:
        names, rows = rows_of(run_dir, last_only=True)
        reward = RunDir(run_dir).load_config().env.reward
        evaluated = evaluation(run_dir)
        for name in objects or names:
            if name not in names:
                raise TrainerError(f"{run_dir}: no object {name!r}; its objects: "
                                   f"{', '.join(names)}")
            episodes, successes = evaluated.get(name, (None, None))
            out.append({"run": run_dir, "object": name, "target": rows[-1][name],
                        "held": rows[-1][f"{name}_held"], "start": reward.h_bar_start,
                        "h_bar": reward.h_bar, "successes": successes, "episodes": episodes})
    return out


def rung(row: dict) -> str:
    """Where a (run, object) pair's target ended: ``first rung``, ``between`` or ``at h_bar``
    (1 mm tolerance: targets are stored as float32)."""
    if row["target"] <= row["start"] + 1e-3:
        return "first rung"
    return "at h_bar" if row["target"] >= row["h_bar"] - 1e-3 else "between"


def final_table(rows: list[dict]) -> list[str]:
    """The markdown lines of ``--final``: one row per (run, object), a blank line, the summary
    by ``rung`` (evaluated pairs only: their count, the median and range of the successes)."""
    lines = ["| run | object | target (m) | held at target | eval successes |",
             "|---|---|---:|---:|---:|"]
    for r in rows:
        ev = "—" if r["successes"] is None else f"{r['successes']}/{r['episodes']}"
        lines.append(f"| {r['run'].name} | {r['object']} | {r['target']:.2f} | "
                     f"{r['held']:.2f} | {ev} |")
    lines += ["", "| target at the end | (run, object) pairs | eval successes: median (range) |",
              "|---|---:|---|"]
    for where in ("first rung", "between", "at h_bar"):
        got = sorted(r["successes"] for r in rows
                     if rung(r) == where and r["successes"] is not None)
        if got:
            lines.append(f"| {where} | {len(got)} | {statistics.median(got):g} "
                         f"({got[0]}-{got[-1]}) |")
    return lines


def left_rows(run_dirs: list[Path], objects: list[str] | None = None) -> list[dict]:
    """Per run and object (the run's, or ``objects``): ``left``, the env steps of the first row
    of the run's curriculum.csv whose target is above the first rung (``reward.h_bar_start``;
    None if none is), ``first`` and ``last``, the env steps of its first and last rows (a run
    whose first kept checkpoint already has the object off the first rung left it by then, not
    at it), ``top``, those of the first row whose target is the task's ``h_bar`` (None if
    none), ``target``, the last row's target (m), and ``successes`` and ``episodes`` of the
    run's evaluation (``eval/per_object.csv``; None where not evaluated)."""
    from trainer.errors import TrainerError
    from trainer.training.run_dir import RunDir

    lacking = [str(d) for d in run_dirs if not (d / "curriculum.csv").is_file()]
    if lacking:
        raise TrainerError(f"no curriculum.csv in {', '.join(lacking)}: write it with "
                           "scripts/object_curriculum.py RUN_DIR from the run's kept checkpoints")
    out = []
    for run_dir in run_dirs:
        path = run_dir / "curriculum.csv"
        reward = RunDir(run_dir).load_config().env.reward
        evaluated = evaluation(run_dir)
        try:
            with open(path, newline="") as handle:
                rows = [{k: float(v) for k, v in row.items()} for row in csv.DictReader(handle)]
        except (OSError, UnicodeDecodeError, csv.Error, TypeError, ValueError) as err:
            raise TrainerError(f"{path}: unreadable ({err}); write it again from the run's "
                               "checkpoints") from None
        if not rows:
            raise TrainerError(f"{path}: no rows; write it again from the run's checkpoints")
        names = [k for k in rows[0] if k not in ("iteration", "env_steps", "minutes")
                 and not k.endswith("_held")]
        for name in objects or names:
            if name not in names:
                raise TrainerError(f"{path}: no object {name!r}")
            # 1 mm tolerance: targets are stored as float32 (see ``rung``).
            left = next((r["env_steps"] for r in rows if r[name] > reward.h_bar_start + 1e-3),
                        None)
            top = next((r["env_steps"] for r in rows if r[name] >= reward.h_bar - 1e-3), None)
            episodes, successes = evaluated.get(name, (None, None))
            out.append({"run": run_dir, "object": name, "left": left, "top": top,
                        "first": rows[0]["env_steps"], "last": rows[-1]["env_steps"],
                        "target": rows[-1][name], "successes": successes, "episodes": episodes})
    return out


def left_table(rows: list[dict], edges: tuple[float, ...] = (2.5, 3.5)) -> list[str]:
    """The markdown lines of ``--left``: one row per (run, object) with its evaluation, a blank
    line, then per object the runs whose target left the first rung and the median and range
    of when (M env steps; a run that had left by its first kept row counts at that row), and
    the runs whose target reached ``h_bar``; then the evaluated pairs by when they left (before
    each of ``edges``, M env steps, after the last, not at all) with their evaluation."""
    def when(r: dict) -> str:
        if r["left"] is None:
            return f"not by {r['last'] / 1e6:.2f}"
        return f"{'by ' if r['left'] == r['first'] else ''}{r['left'] / 1e6:.2f}"

    def successes(r: dict) -> str:
        return "—" if r["successes"] is None else f"{r['successes']}/{r['episodes']}"

    lines = ["| run | object | left the first rung (M env steps) | at h_bar (M env steps) | "
             "target at the last row (m) | eval successes |", "|---|---|---:|---:|---:|---:|"]
    lines += [f"| {r['run'].name} | {r['object']} | {when(r)} | "
              f"{'—' if r['top'] is None else format(r['top'] / 1e6, '.2f')} | "
              f"{r['target']:.2f} | {successes(r)} |" for r in rows]
    lines += ["", "| object | runs that left it | when (M env steps): median (range) | runs at "
              "h_bar |", "|---|---:|---|---:|"]
    for name in dict.fromkeys(r["object"] for r in rows):
        mine = [r for r in rows if r["object"] == name]
        got = sorted(r["left"] / 1e6 for r in mine if r["left"] is not None)
        spread = f"{statistics.median(got):.2f} ({got[0]:.2f}-{got[-1]:.2f})" if got else "—"
        top = sum(r["top"] is not None for r in mine)
        lines.append(f"| {name} | {len(got)} of {len(mine)} | {spread} | {top} |")
    bounds = [0.0, *edges, math.inf]
    groups = [(f"{lo:g}-{hi:g}" if hi < math.inf else f"after {lo:g}",
               [r for r in rows if r["left"] is not None and lo <= r["left"] / 1e6 < hi])
              for lo, hi in zip(bounds, bounds[1:], strict=False)]
    groups.append(("not at all", [r for r in rows if r["left"] is None]))
    lines += ["", "| left the first rung (M env steps) | evaluated pairs | eval successes: median "
              "(range) |", "|---|---:|---|"]
    for label, members in groups:
        got = sorted(r["successes"] for r in members if r["successes"] is not None)
        if got:
            lines.append(f"| {label} | {len(got)} | {statistics.median(got):g} "
                         f"({got[0]}-{got[-1]}) |")
    return lines


def plot(names: list[str], rows: list[dict[str, float]], png: Path) -> None:
    from trainer.report import pyplot, save_png

    plt = pyplot()
    fig, ax = plt.subplots(figsize=(8, 4.5))
    x = [r["env_steps"] / 1e6 for r in rows]
    for name in names:
        ax.plot(x, [r[name] for r in rows], label=name, drawstyle="steps-post")
    ax.set_xlabel("env steps (M)")
    ax.set_ylabel("lift target (m)")
    ax.set_title("per-object lift curriculum")
    ax.legend(fontsize=7, ncol=2)
    save_png(fig, png)


def main(argv: list[str] | None = None) -> list[dict[str, float]] | list[str]:
    from trainer.errors import TrainerError

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("run_dir", type=Path, nargs="+")
    parser.add_argument("--csv", type=Path, default=None, help="default: RUN_DIR/curriculum.csv")
    parser.add_argument("--png", type=Path, default=None, help="default: beside the CSV")
    parser.add_argument("--final", action="store_true",
                        help="the last targets beside the evaluation, over the runs given")
    parser.add_argument("--left", action="store_true",
                        help="when each object left the first rung, from RUN_DIR/curriculum.csv")
    parser.add_argument("--edges", default="2.5,3.5",
                        help="with --left: M env steps that split the pairs by when they left")
    parser.add_argument("--objects", default=None,
                        help="with --final or --left: comma-separated")
    args = parser.parse_args(argv)
    if args.left:
        if args.final:
            parser.error("--left goes without --final")
        objects = args.objects.split(",") if args.objects else None
        try:
            edges = tuple(float(e) for e in args.edges.split(","))
        except ValueError:
            edges = ()
        if not edges or list(edges) != sorted(set(edges)):
            parser.error(f"--edges {args.edges}: M env steps, rising, comma-separated (2.5,3.5)")
        try:
            lines = left_table(left_rows(args.run_dir, objects), edges)
        except TrainerError as exc:
            raise SystemExit(f"object_curriculum: {exc}") from None
        print("\n".join(lines))
        return lines
    if args.final:
        objects = args.objects.split(",") if args.objects else None
        try:
            lines = final_table(final_rows(args.run_dir, objects))
        except TrainerError as exc:
            raise SystemExit(f"object_curriculum: {exc}") from None
        print("\n".join(lines))
        return lines
    if len(args.run_dir) > 1 or args.objects:
        parser.error("several runs and --objects go with --final or --left")
    args.run_dir = args.run_dir[0]
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
