"""``trainer report``: the runs loaded, the plots and ``report.md`` written (``write_report``),
and the command line that makes it again (``report_command``)."""

from __future__ import annotations

import shlex
from collections.abc import Sequence
from pathlib import Path

from geomgrasp.files import atomic_path
from trainer.errors import TrainerError
from trainer.report.groups import group_labels, group_runs
from trainer.report.plots import plot_curriculum, plot_curves, plot_gain, success_gain
from trainer.report.ranking import paper_ranking, ranking_text
from trainer.report.runs import (
    GroupKey,
    Run,
    allowing_differences,
    check_eval_dir,
    load_run,
    relative_to,
)
from trainer.report.tables import (
    THRESHOLDS,
    WORST,
    machines_text,
    per_object_table,
    seeds_table,
    summary_table,
    upside_down_table,
    worst_objects_table,
)


def _file_label(name: str) -> str:
    return "".join(c if c.isalnum() or c in "-_." else "-" for c in name)


def report_command(
    run_dirs: Sequence[str | Path],
    out_dir: str | Path,
    compare: tuple[str, str] | None = None,
    eval_dir: str = "eval",
    thresholds: Sequence[float] = THRESHOLDS,
    allow_differ: Sequence[str] = (),
    worst_count: int = WORST,
) -> str:
    """The ``trainer report`` command line that writes this report, its paths relative to the
    current directory (options at their defaults left out)."""
    cwd = Path.cwd()
    args = ["trainer", "report", *(relative_to(Path(d), cwd) for d in run_dirs)]
    args += ["--out", relative_to(Path(out_dir), cwd)]
    if eval_dir != "eval":
        args += ["--eval", eval_dir]
    if tuple(thresholds) != THRESHOLDS:
        args += ["--thresholds", ",".join(f"{t:g}" for t in thresholds)]
    if allow_differ:
        args += ["--allow-differ", ",".join(allow_differ)]
    if compare is not None:
        args += ["--compare", ",".join(compare)]
    if worst_count != WORST:
        args += ["--worst", str(worst_count)]
    return shlex.join(args)


def _check_thresholds(thresholds: Sequence[float]) -> None:
    if not thresholds or any(not 0.0 < t <= 1.0 for t in thresholds):
        raise TrainerError(
            f"thresholds {list(thresholds)}: give success rates in (0, 1], e.g. 0.5,0.7"
        )
    if len(set(thresholds)) < len(thresholds):
        raise TrainerError(f"thresholds {list(thresholds)}: each at most once")


def _eval_folders(runs: Sequence[Run]) -> list[str]:
    """The folders with a per_object.csv in any of the runs (``trainer eval --out`` names)."""
    found = {p.parent.name for r in runs for p in r.path.glob("*/per_object.csv")}
    return sorted(found)


def _table_one_notes(runs: Sequence[Run], eval_dir: str, labels: dict[GroupKey, str]) -> list[str]:
    evaluated = [r for r in runs if r.per_object is not None]
    criteria: dict[str, int] = {}
    for r in evaluated:
        text = r.eval_criterion or "not stated (table.md without a Success line)."
        criteria[text] = criteria.get(text, 0) + 1
    notes = [
        f"Ours: the success per target object of `trainer eval` (folder `{eval_dir}` of each "
        "run), mean ± std over the seeds evaluated (ddof 0; one seed: its value); † where some "
        "of them lack the object. In brackets the paper's Table I (— where it has no value: "
        "other objects, the reward ablations and other tasks). The mean over objects is per "
        "seed over its objects, then over seeds; the paper's beside it is its mean over the same "
        "objects, or its all-78 value where a column has objects outside its Table I.",
        "",
    ]
    if len(criteria) == 1:
        notes += [f"Success in these evaluations: {next(iter(criteria))}", ""]
    else:
        notes += ["The evaluations differ in their success criterion:", ""]
        notes += [f"- {count} runs: {text}" for text, count in criteria.items()]
        notes.append("")
    group_of = {id(r): key for key, members in group_runs(runs).items() for r in members}
    missing = [f"{labels[group_of[id(r)]]} seed {r.seed}" for r in runs if r.per_object is None]
    if missing:
        notes += [
            f"Not evaluated (no `{eval_dir}/per_object.csv`), left out: {', '.join(missing)}.", ""
        ]
    return notes


def write_report(
    run_dirs: Sequence[str | Path],
    out_dir: str | Path,
    compare: tuple[str, str] | None = None,
    eval_dir: str = "eval",
    thresholds: Sequence[float] = THRESHOLDS,
    allow_differ: Sequence[str] = (),
    worst_count: int = WORST,
) -> list[Path]:
    """Load the runs (their evaluation from the folder ``eval_dir``; seeds may differ in the
    config fields ``allow_differ`` too) and write into ``out_dir``: ``success_vs_steps.png``
    and ``success_vs_time.png`` (learning curves with seed bands and the thresholds),
    ``curriculum.png`` for runs with a lift curriculum, ``gain_<other>_over_<base>.png`` when
    ``compare = (base, other)`` is given (group labels or representation names), and
    ``report.md``: the command that made it, Table I (``per_object_table``) when any run has
    eval data, the ranking against the paper (``paper_ranking``), the differences the seeds
    settle (``seeds_table``), Table II (``summary_table`` at ``thresholds``, with env steps per
    second), the plots, and the list of runs. Every path
    in it is relative (runs relative to ``out_dir``, the command's to the directory it ran in).
    Every file is written atomically; returns the written paths, report.md last."""
    if not run_dirs:
        raise TrainerError("no run directories given; pass at least one run directory")
    check_eval_dir(eval_dir)
    _check_thresholds(thresholds)
    # The same directory given twice (e.g. overlapping globs) would count as an extra seed.
    if worst_count < 1:
        raise TrainerError(f"--worst {worst_count}: list at least one object per arm")
    unique = list(dict.fromkeys(Path(d).resolve() for d in run_dirs))
    runs = allowing_differences([load_run(d, eval_dir) for d in unique], allow_differ)
    out_dir = Path(out_dir)
    command = report_command(unique, out_dir, compare, eval_dir, thresholds, allow_differ,
                             worst_count)
    evaluated = [r for r in runs if r.per_object is not None]
    groups = group_runs(runs)
    labels = group_labels(runs)

    if compare is not None:
        success_gain(runs, *compare)  # a bad name fails here, before any file is written
    written = [
        plot_curves(runs, out_dir / "success_vs_steps.png", "env_steps", thresholds),
        plot_curves(runs, out_dir / "success_vs_time.png", "wall_time_s", thresholds),
    ]
    curriculum = [r for r in runs if r.has_curriculum]
    if curriculum:
        written.append(plot_curriculum(curriculum, out_dir / "curriculum.png"))
    if compare is not None:
        base, other = compare
        name = f"gain_{_file_label(other)}_over_{_file_label(base)}.png"
        written.append(plot_gain(runs, base, other, out_dir / name))

    parts = ["# Training report", ""]
    parts += [
        f"Made by this command, run in `{relative_to(Path.cwd(), out_dir)}` (relative to this "
        "folder):",
        "",
        f"    {command}",
        "",
        f"{len(runs)} run{'s' * (len(runs) != 1)} in {len(groups)} "
        f"arm{'s' * (len(groups) != 1)}: "
        + ", ".join(f"{labels[k]} ({len(m)})" for k, m in groups.items()) + ".",
        "",
    ]
    if any(" [" in key[1] for key in groups):
        parts += [
            "Runs whose configs differ in more than the seed are separate arms, named by the "
            "difference (`[name=value]`); `--allow-differ FIELD,...` makes them one arm where "
            "the difference is not the experiment (e.g. `run.max_minutes`).",
            "",
        ]
    parts += [f"## Table I: success per object (`trainer eval`, folder `{eval_dir}`)", ""]
    if evaluated:
        parts += [per_object_table(runs), *_table_one_notes(runs, eval_dir, labels)]
        upside_down = upside_down_table(runs)
        if upside_down:
            parts += [
                "### Objects that fail upside down", "",
                "Where an object's episodes that started upside down (its mesh's up axis "
                "pointing down after the first action: `trainer eval`'s `by_start.csv`) "
                "succeed at less than half the rate of its face-up ones, pooled over the "
                "evaluated runs: per arm its success over all resets / over the face-up ones "
                "(mean over seeds), and the face-up share of its episodes.", "", upside_down,
            ]
        parts += ["## Ranking against the paper", "", ranking_text(paper_ranking(runs)), ""]
        parts += [
            "## Which differences the seeds settle", "",
            "Per arm, best mean first: the overall success of each evaluated seed (Table I's "
            "mean over objects); an arm is settled above another where every seed of it is "
            "above every seed of the other, both with two seeds or more. Where their seeds "
            "overlap, the difference is inside the seed spread; an arm with one seed is "
            "settled against none.", "", seeds_table(runs),
        ]
        worst = worst_objects_table(runs, worst_count)
        if worst:
            parts += [f"## The {worst_count} worst objects of each arm and how their episodes "
                      "ended", "",
                      "From `trainer eval`'s `endings.csv`: two fingertip pads never within "
                      "2 cm of the target together and its centre never rose 1 cm (never "
                      "reached: recorded since 2026-11-30, counted as never lifted before), "
                      "the pads did and it never rose 1 cm (never lifted), it "
                      "rose and ended 3 cm below its highest (dropped), stayed "
                      "up short of success (stalled), or ended 5 cm below its start (knocked "
                      "off the table).", "", worst]
    else:
        found = ", ".join(f"`{name}`" for name in _eval_folders(runs)) or "none"
        parts += [
            f"No run has `{eval_dir}/per_object.csv` (evaluation folders in the runs: {found}): "
            "run `trainer eval` on them, or name another folder with `--eval`.",
            "",
        ]
    parts += ["## Table II: sample efficiency (training curve)", ""]
    parts.append(summary_table(runs, thresholds))
    final = {
        len(runs): "the `trainer eval` overall (successes / episodes)",
        0: "the mean training success rate over the last 10 % of iterations",
    }.get(len(evaluated), (
        f"the `trainer eval` overall (successes / episodes) for the {len(evaluated)} evaluated "
        f"runs, the mean training success rate over the last 10 % of iterations for the other "
        f"{len(runs) - len(evaluated)}"
    ))
    parts += [
        f"Final success: {final}. env steps/s: a run's env steps "
        "over its training wall time (all parallel environments, PPO updates included), mean ± "
        "std over seeds. Reached: the seeds whose training success rate (metrics.csv, the mean "
        "over objects) reached the threshold; steps and minutes are at the first iteration that "
        "did, mean ± std over those seeds (ddof 0), in brackets the paper's Table II (its arms, "
        "at 90 % and 95 % only).",
        "",
    ]
    parts += ["## Machines", "", *machines_text(runs, out_dir)]
    parts += [
        "## Learning curves",
        "",
        "Training success rate, per arm the mean over seeds with a ± std band (over the env "
        "steps / minutes every seed covers); dashed grey: the thresholds.",
        "",
        "![success vs env steps](success_vs_steps.png)",
        "",
        "![success vs wall time](success_vs_time.png)",
        "",
    ]
    if curriculum:
        parts += [
            "## Lift curriculum",
            "",
            f"{len(curriculum)} runs trained with a lift curriculum: the success rates above "
            "count lifts by the task's h_bar only; the target and the success at it:",
            "",
            "![lift curriculum](curriculum.png)",
            "",
        ]
    if compare is not None:
        parts += [
            f"## Gain of {compare[1]} over {compare[0]}",
            "",
            f"![gain]({written[-1].name})",
            "",
        ]
    parts += ["## Runs", "", "Paths relative to this report's directory.", ""]
    group_of = {id(r): key for key, members in groups.items() for r in members}
    for r in runs:
        rel = relative_to(r.path, out_dir)
        key = group_of[id(r)]
        evaluation = "" if r.per_object is not None else f", no `{eval_dir}`"
        parts.append(
            f"- [`{rel}`]({rel}): {labels[key]} ({'/'.join(key)}), seed {r.seed}{evaluation}"
        )

    report = out_dir / "report.md"
    with atomic_path(report) as tmp:
        tmp.write_text("\n".join(parts) + "\n")
    written.append(report)
    return written
