"""Compare finished training runs: markdown tables and plots like the paper's Table II and Fig. 4.

A run directory is read as the trainer writes it::

    RUN_DIR/config.json            env.task, env.bin.num_objects, env.context,
                                   env.representation, env.reward.kind, env.robot.kind, run.seed
    RUN_DIR/metrics.csv            one row per PPO iteration: env_steps, wall_time_s,
                                   object_success_rate (the mean over objects; success_rate, over
                                   all ended episodes, in runs logged before it existed)
    RUN_DIR/eval/per_object.csv    optional (``trainer eval``): object, episodes, successes

Runs are grouped by (task, representation, reward kind, robot kind), where the task is ``lift`` or
``binN`` (N objects per bin) and the representation gains ``+ctx`` when the policy also sees the
other objects (``context``): a bin run and a lift run are different groups even with the same
representation. Run directories written before the tasks existed (no ``env.task``) are lift
runs. Runs of one such group whose configs differ in anything else (physics, PPO settings, the
budget; not in the seed or in ``NOT_THE_EXPERIMENT``, and only in fields every one of them
records, or that ``config.ABSENT_MEANS`` fills in) are split further, and the representation names
the difference, e.g. ``bbox [noslip_iterations=5]``. The runs of a group are then taken to
differ by seed, and every table cell is a mean ± std (ddof = 0) over them. Units: env steps are
counted over all parallel environments, wall time is seconds in the data and minutes in tables
and plots, success rates are fractions in [0, 1].
Group labels: ``sq`` (lift), ``bin5-bbox``, ``bin5-bbox+ctx``.
"""

from __future__ import annotations

import csv
import json
import math
import os
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from geomgrasp.files import atomic_path
from trainer.config import ABSENT_MEANS
from trainer.errors import TrainerError
from trainer.training.run_dir import RunDir

GroupKey = tuple[str, str, str, str]
"""(task, representation, reward kind, robot kind): task ``lift`` or ``binN``, representation
with ``+ctx`` when the policy sees the context (see ``task_name`` and ``view_name``)."""

NOT_THE_EXPERIMENT = frozenset({
    "run.seed", "run.torch_threads", "run.checkpoint_every", "env.nthread", "env.compile",
    "env.data_dir", "env.device",
})
"""Config fields that seeds of one experiment may differ in: the seed, and how and where it ran."""
THRESHOLDS = (0.9, 0.95)
CURVE_POINTS = 200
_DASH = "—"


def task_name(task: str, bin_objects: int | None = None) -> str:
    """``lift``, or ``binN`` for the bin task with N objects per bin."""
    return f"{task}{bin_objects}" if task == "bin" and bin_objects is not None else task


def view_name(representation: str, context: str = "none") -> str:
    """What the policy sees: the representation, ``+ctx`` when it also sees the context."""
    return representation if context == "none" else f"{representation}+ctx"


def task_label(
    task: str, representation: str, bin_objects: int | None = None, context: str = "none"
) -> str:
    """A short label of a task as the policy sees it: ``sq`` (lift), ``bin5-bbox``,
    ``bin5-bbox+ctx``."""
    view = view_name(representation, context)
    return view if task == "lift" else f"{task_name(task, bin_objects)}-{view}"


def _label(key: GroupKey) -> str:
    task, view = key[0], key[1]
    return view if task == "lift" else f"{task}-{view}"


@dataclass(frozen=True, eq=False)
class Run:
    """One training run directory, loaded.

    ``env_steps`` (steps summed over all environments), ``wall_time_s`` (s) and ``success_rate``
    (fraction, NaN where no episode ended) hold one entry per PPO iteration, in file order.
    ``per_object`` maps an object name to (episodes, successes) from ``eval/per_object.csv``,
    or is None when the run was not evaluated.
    """

    path: Path
    representation: str
    reward: str
    robot: str
    seed: int | None
    env_steps: np.ndarray
    wall_time_s: np.ndarray
    success_rate: np.ndarray
    per_object: dict[str, tuple[int, int]] | None
    h_bar: np.ndarray | None = None
    """The lift curriculum's training target (m) and the success rate at it, per iteration;
    None for runs logged before the curriculum existed."""
    target_success_rate: np.ndarray | None = None
    task: str = "lift"
    """``lift`` or ``bin``; ``bin_objects`` (objects per bin) and ``context`` matter for bin."""
    bin_objects: int | None = None
    context: str = "none"
    settings: dict[str, str] = field(default_factory=dict)
    """Every config field but ``NOT_THE_EXPERIMENT``'s: dotted name -> JSON value."""

    @property
    def has_curriculum(self) -> bool:
        return self.h_bar is not None and bool(np.nanmin(self.h_bar) < np.nanmax(self.h_bar))

    @property
    def group(self) -> GroupKey:
        return (
            task_name(self.task, self.bin_objects),
            view_name(self.representation, self.context),
            self.reward,
            self.robot,
        )

    @property
    def label(self) -> str:
        """The run's task and view, e.g. ``sq`` or ``bin5-bbox+ctx`` (see ``task_label``)."""
        return task_label(self.task, self.representation, self.bin_objects, self.context)


# --------------------------------------------------------------------------------------- loading


def load_run(path: str | Path) -> Run:
    """Read a run directory; raise TrainerError naming the file and the fix if it is unusable."""
    path = Path(path)
    if not path.is_dir():
        raise TrainerError(
            f"{path}: not a directory; pass a run directory written by trainer run"
        )
    run = RunDir(path)
    config = _read_config(run.config)
    env_steps, wall_time_s, success_rate, h_bar, target_rate = _read_metrics(run.metrics)
    per_object_path = path / "eval" / "per_object.csv"
    per_object = _read_per_object(per_object_path) if per_object_path.is_file() else None
    return Run(
        path=path,
        representation=config["representation"],
        reward=config["reward"],
        robot=config["robot"],
        seed=config["seed"],
        env_steps=env_steps,
        wall_time_s=wall_time_s,
        success_rate=success_rate,
        per_object=per_object,
        h_bar=h_bar,
        target_success_rate=target_rate,
        task=config["task"],
        bin_objects=config["bin_objects"],
        context=config["context"],
        settings=config["settings"],
    )


def _read_config(path: Path) -> dict[str, Any]:
    """representation, reward, robot, seed (None if absent), task, bin_objects (None unless
    bin), context. A config without ``env.task`` (a run from before the tasks) is a lift run."""
    fix = "pass a run directory written by trainer run"
    if not path.is_file():
        raise TrainerError(f"{path}: missing; {fix}")
    try:
        config = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise TrainerError(f"{path}: unreadable JSON ({err}); {fix}") from None

    def get(*keys: str) -> Any:
        node = config
        for key in keys:
            if not isinstance(node, dict) or key not in node:
                raise TrainerError(f"{path}: no {'.'.join(keys)}; {fix}")
            node = node[key]
        return node

    names = (
        get("env", "representation"),
        get("env", "reward", "kind"),
        get("env", "robot", "kind"),
    )
    for name, keys in zip(
        names, ("env.representation", "env.reward.kind", "env.robot.kind"), strict=True
    ):
        if not isinstance(name, str):
            raise TrainerError(f"{path}: {keys} is {name!r}, not a string; {fix}")
    # A seed is only a label in the tables, so a config without one is still reportable.
    run_section = config.get("run")
    seed = run_section.get("seed") if isinstance(run_section, dict) else None
    if seed is not None and (not isinstance(seed, int) or isinstance(seed, bool)):
        raise TrainerError(f"{path}: run.seed is {seed!r}, not an integer; {fix}")
    env = config["env"]
    task = env.get("task", "lift")
    context = env.get("context", "none")
    for name, key in ((task, "env.task"), (context, "env.context")):
        if not isinstance(name, str):
            raise TrainerError(f"{path}: {key} is {name!r}, not a string; {fix}")
    bin_objects = None
    if task == "bin":
        # BinConfig's default when a config leaves it out.
        section = env.get("bin")
        bin_objects = section.get("num_objects", 5) if isinstance(section, dict) else 5
        if not isinstance(bin_objects, int) or isinstance(bin_objects, bool):
            raise TrainerError(
                f"{path}: env.bin.num_objects is {bin_objects!r}, not an integer; {fix}"
            )
    return {
        "representation": names[0], "reward": names[1], "robot": names[2], "seed": seed,
        "task": task, "bin_objects": bin_objects, "context": context,
        "settings": {
            **{k: json.dumps(v) for k, v in ABSENT_MEANS.items()},
            **{k: v for k, v in _flatten(config).items() if k not in NOT_THE_EXPERIMENT},
        },
    }


def _flatten(node: dict, prefix: str = "") -> dict[str, str]:
    """A nested config as dotted name -> JSON text of the value."""
    out: dict[str, str] = {}
    for key, value in node.items():
        if isinstance(value, dict):
            out.update(_flatten(value, f"{prefix}{key}."))
        else:
            out[f"{prefix}{key}"] = json.dumps(value)
    return out


def _read_metrics(path: Path) -> tuple[np.ndarray, ...]:
    """env_steps, wall_time_s, success rate, then h_bar and target_success_rate (None where the
    file predates them).

    The success rate is ``object_success_rate`` (the mean over the objects of their own rates,
    the paper's measure) where the run logged it, else ``success_rate`` (over the last ended
    episodes, which favours the objects that are lifted: their episodes end sooner)."""
    fix = "pass a run directory written by trainer run"
    if not path.is_file():
        raise TrainerError(f"{path}: missing; {fix}")
    columns: tuple[str, ...] = ("env_steps", "wall_time_s", "success_rate")
    optional = ("h_bar", "target_success_rate")
    rows: list[list[float]] = []
    try:
        with path.open(newline="") as f:
            reader = csv.DictReader(f)
            header = reader.fieldnames or ()
            if "object_success_rate" in header:
                columns = ("env_steps", "wall_time_s", "object_success_rate")
            missing = [c for c in columns if c not in header]
            if missing:
                raise TrainerError(f"{path}: header lacks {', '.join(missing)}; {fix}")
            present = [c for c in optional if c in header]
            for row in reader:
                rows.append(
                    [
                        # A rate is empty until the first episode ends: NaN, skipped by every
                        # statistic.
                        _number(row[c], path, reader.line_num, c, allow_empty=c.endswith("rate"))
                        for c in (*columns, *present)
                    ]
                )
    except (OSError, UnicodeDecodeError, csv.Error) as err:
        raise TrainerError(f"{path}: unreadable CSV ({err}); {fix}") from None
    if not rows:
        raise TrainerError(f"{path}: no iterations logged yet; report on the run once it has some")
    data = np.array(rows, dtype=np.float64)
    extra = [data[:, 3 + present.index(c)] if c in present else None for c in optional]
    return data[:, 0], data[:, 1], data[:, 2], *extra


def _number(
    text: str | None, path: Path, line: int, column: str, allow_empty: bool = False
) -> float:
    # DictReader gives None for the fields of a short row (a line cut off mid-write).
    if text is None or (text.strip() == "" and not allow_empty):
        raise TrainerError(f"{path}:{line}: no {column} value; fix or drop that line")
    if text.strip() == "":
        return math.nan
    try:
        return float(text)
    except ValueError:
        raise TrainerError(
            f"{path}:{line}: {column} {text!r} is not a number; fix or drop that line"
        ) from None


def _read_per_object(path: Path) -> dict[str, tuple[int, int]]:
    fix = "re-run trainer eval on the run"
    result: dict[str, tuple[int, int]] = {}
    try:
        with path.open(newline="") as f:
            reader = csv.DictReader(f)
            missing = [
                c for c in ("object", "episodes", "successes") if c not in (reader.fieldnames or ())
            ]
            if missing:
                raise TrainerError(f"{path}: header lacks {', '.join(missing)}; {fix}")
            for row in reader:
                name = row["object"]
                try:
                    episodes, successes = int(row["episodes"]), int(row["successes"])
                except (TypeError, ValueError):
                    raise TrainerError(
                        f"{path}:{reader.line_num}: episodes/successes are not integers; {fix}"
                    ) from None
                if not name or name in result or not 0 <= successes <= episodes:
                    raise TrainerError(
                        f"{path}:{reader.line_num}: bad row for object {name!r} (empty, repeated "
                        f"or successes outside 0..episodes); {fix}"
                    )
                result[name] = (episodes, successes)
    except (OSError, UnicodeDecodeError, csv.Error) as err:
        raise TrainerError(f"{path}: unreadable CSV ({err}); {fix}") from None
    if not result:
        raise TrainerError(f"{path}: no objects; {fix}")
    return result


# ----------------------------------------------------------------------------------- per-run stats


def steps_to_reach(run: Run, threshold: float) -> tuple[float, float]:
    """(env steps, wall time in s) at the first iteration whose success_rate >= ``threshold``.

    The raw logged rates are used, unsmoothed; iterations without a rate (NaN) never count.
    Returns (nan, nan) if the run never reaches the threshold.
    """
    hits = np.flatnonzero(run.success_rate >= threshold)  # NaN compares False
    if hits.size == 0:
        return math.nan, math.nan
    first = hits[0]
    return float(run.env_steps[first]), float(run.wall_time_s[first])


def training_success(run: Run, last_fraction: float = 0.1) -> float:
    """Mean training success_rate over the last ``last_fraction`` of iterations (at least one).

    NaN rates are ignored; NaN if the window has none.
    """
    if not 0.0 < last_fraction <= 1.0:
        raise TrainerError(f"last_fraction must be in (0, 1], got {last_fraction}")
    n = len(run.success_rate)
    # The epsilon keeps 0.1 * 30 = 3.0000000000000004 from rounding up to 4 rows.
    count = max(1, math.ceil(n * last_fraction - 1e-9))
    tail = run.success_rate[-count:]
    tail = tail[np.isfinite(tail)]
    return float(tail.mean()) if tail.size else math.nan


def eval_success(run: Run) -> float:
    """Overall ``trainer eval`` success: total successes / total episodes; NaN if not evaluated."""
    if run.per_object is None:
        return math.nan
    episodes = sum(e for e, _ in run.per_object.values())
    successes = sum(s for _, s in run.per_object.values())
    return successes / episodes if episodes else math.nan


def final_success(run: Run, last_fraction: float = 0.1) -> float:
    """The run's final success rate (fraction).

    The ``trainer eval`` overall (``eval_success``) when the run has eval/per_object.csv, because
    it is measured on a fixed set of episodes with the final policy, while the training rate mixes
    the exploring policy of several iterations and whatever episodes happened to end. Otherwise
    the training curve's tail (``training_success``), which stays available on its own.
    """
    if run.per_object is not None:
        return eval_success(run)
    return training_success(run, last_fraction)


# ------------------------------------------------------------------------------------- grouping


def group_runs(runs: Iterable[Run]) -> dict[GroupKey, list[Run]]:
    """Runs by group key, groups in order of first appearance, runs within a group by seed.
    Runs of one ``Run.group`` whose settings differ are split: their representation gains
    `` [name=value, ...]`` for every setting that differs (see the module docstring)."""
    by_group: dict[GroupKey, list[Run]] = {}
    for run in runs:
        by_group.setdefault(run.group, []).append(run)
    groups: dict[GroupKey, list[Run]] = {}
    for key, members in by_group.items():
        shared = set.intersection(*(set(r.settings) for r in members))
        differ = sorted(k for k in shared if len({r.settings[k] for r in members}) > 1)
        for run in members:
            variant = ", ".join(
                f"{k.rsplit('.', 1)[-1]}={json.loads(run.settings[k])}" for k in differ
            )
            split = (key[0], f"{key[1]} [{variant}]", *key[2:]) if variant else key
            groups.setdefault(split, []).append(run)
    for members in groups.values():
        members.sort(key=lambda r: (r.seed is None, r.seed if r.seed is not None else 0))
    return groups


def group_labels(runs: Iterable[Run]) -> dict[GroupKey, str]:
    """A column label per group: the task and view alone (``sq``, ``bin5-bbox``,
    ``bin5-bbox+ctx``) when the groups share reward and robot, else ``label/reward/robot``."""
    keys = list(group_runs(runs))
    if len({key[2:] for key in keys}) <= 1:
        return {key: _label(key) for key in keys}
    return {key: "/".join((_label(key), *key[2:])) for key in keys}


def resolve_group(runs: Sequence[Run], name: str) -> GroupKey:
    """The group a user names: by its label, else by its task and view (``bin5-bbox``) or its
    representation (``sq``) if that names one group."""
    labels = group_labels(runs)
    for key, label in labels.items():
        if label == name:
            return key
    known = ", ".join(labels.values())
    for matches in ([k for k in labels if _label(k) == name], [k for k in labels if k[1] == name]):
        if len(matches) == 1:
            return matches[0]
        if matches:
            raise TrainerError(f"{name!r} names several groups; use one of the labels: {known}")
    raise TrainerError(f"no group named {name!r}; the runs' groups are: {known}")


def _per_object_rates(members: Sequence[Run]) -> dict[str, float]:
    """Per object, the mean over seeds of each seed's successes / episodes (evaluated runs only)."""
    rates: dict[str, list[float]] = {}
    for run in members:
        for name, (episodes, successes) in (run.per_object or {}).items():
            if episodes:
                rates.setdefault(name, []).append(successes / episodes)
    return {name: float(np.mean(values)) for name, values in rates.items()}


# --------------------------------------------------------------------------------------- tables


def _mean_std(values: Sequence[float], digits: int) -> str:
    """``mean ± std`` over the finite values; "(k/n seeds)" appended when some are missing."""
    finite = np.array([v for v in values if math.isfinite(v)], dtype=np.float64)
    if finite.size == 0:
        return _DASH
    text = f"{finite.mean():.{digits}f} ± {finite.std(ddof=0):.{digits}f}"
    if finite.size < len(values):
        text += f" ({finite.size}/{len(values)} seeds)"
    return text


def _percent(threshold: float) -> str:
    return f"{threshold * 100:g} %"


def summary_table(
    runs: Sequence[Run], thresholds: Sequence[float] = THRESHOLDS, last_fraction: float = 0.1
) -> str:
    """Markdown table, one line per group (task ``lift`` or ``binN``, representation with
    ``+ctx`` when the policy sees the context, reward, robot): final success and env steps (M) /
    minutes to reach each threshold, as mean ± std over seeds. Seeds that never reach a
    threshold are left out of its mean (the cell says how many did); "—" where none did."""
    header = ["task", "representation", "reward", "robot", "seeds", "final success"]
    for threshold in thresholds:
        header += [f"steps to {_percent(threshold)} (M)", f"minutes to {_percent(threshold)}"]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for key, members in group_runs(runs).items():
        cells = [*key, str(len(members))]
        cells.append(_mean_std([final_success(r, last_fraction) for r in members], 2))
        for threshold in thresholds:
            reached = [steps_to_reach(r, threshold) for r in members]
            cells.append(_mean_std([steps / 1e6 for steps, _ in reached], 2))
            cells.append(_mean_std([seconds / 60 for _, seconds in reached], 1))
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def per_object_table(runs: Sequence[Run]) -> str:
    """Markdown table like the paper's Table I: one row per object, one column per group with
    eval data, each cell the mean over that group's seeds of the object's success rate; "—" where
    a group has no episodes of the object. The last row is the mean of each column's cells (every
    object weighs the same, whatever its episode count)."""
    labels = group_labels(runs)
    groups = {
        key: members
        for key, members in group_runs(runs).items()
        if any(r.per_object is not None for r in members)
    }
    if not groups:
        raise TrainerError("no run has eval/per_object.csv; run trainer eval on the runs first")
    rates = {key: _per_object_rates(members) for key, members in groups.items()}
    objects = sorted(set().union(*(r.keys() for r in rates.values())))
    lines = [
        "| object | " + " | ".join(labels[key] for key in groups) + " |",
        "|" + "---|" * (len(groups) + 1),
    ]
    for name in objects:
        cells = [f"{rates[key][name]:.2f}" if name in rates[key] else _DASH for key in groups]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    means = [f"{np.mean(list(r.values())):.2f}" if r else _DASH for r in rates.values()]
    lines.append("| mean | " + " | ".join(means) + " |")
    return "\n".join(lines) + "\n"


# ---------------------------------------------------------------------------------------- plots


def _pyplot() -> Any:
    # Imported on first plot so that importing the module (e.g. from the CLI) stays cheap, and
    # Agg so that plotting works on a headless training machine.
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig: Any, out_png: Path) -> Path:
    out_png = Path(out_png)
    try:
        with atomic_path(out_png) as tmp:
            # The temporary name has no .png suffix to infer the format from.
            fig.savefig(tmp, format="png", dpi=120, bbox_inches="tight")
    finally:
        _pyplot().close(fig)
    return out_png


def mean_curve(
    members: Sequence[Run],
    x: Literal["env_steps", "wall_time_s"] = "env_steps",
    points: int = CURVE_POINTS,
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """(x grid, mean, std over seeds) of the success curves of one group, or None if no seed
    has a success rate yet.

    Each seed's curve (NaN rows dropped) is linearly interpolated onto a common grid spanning the
    x range every seed covers, so nothing is extrapolated; x is in the units of the column.
    """
    curves = []
    for run in members:
        xs = getattr(run, x)
        valid = np.isfinite(run.success_rate) & np.isfinite(xs)
        if valid.any():
            curves.append((xs[valid], run.success_rate[valid]))
    if not curves:
        return None
    lo = max(float(xs[0]) for xs, _ in curves)
    hi = min(float(xs[-1]) for xs, _ in curves)
    grid = np.linspace(lo, hi, points) if hi > lo else np.array([hi])
    values = np.stack([np.interp(grid, xs, ys) for xs, ys in curves])
    return grid, values.mean(axis=0), values.std(axis=0, ddof=0)


def plot_curves(
    runs: Sequence[Run],
    out_png: str | Path,
    x: Literal["env_steps", "wall_time_s"] = "env_steps",
) -> Path:
    """Success rate vs env steps (M) or vs wall time (min): per group, the mean over seeds with a
    ± std band (see ``mean_curve``). Writes ``out_png`` atomically and returns it."""
    if x not in ("env_steps", "wall_time_s"):
        raise TrainerError(f"x must be env_steps or wall_time_s, got {x!r}")
    scale, xlabel = (1e6, "env steps (M)") if x == "env_steps" else (60.0, "wall time (min)")
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(7, 4.5))
    labels = group_labels(runs)
    for key, members in group_runs(runs).items():
        curve = mean_curve(members, x)
        if curve is None:
            continue
        grid, mean, std = curve
        line = ax.plot(
            grid / scale,
            mean,
            marker="o" if grid.size == 1 else None,
            label=f"{labels[key]} ({len(members)} seed{'' if len(members) == 1 else 's'})",
        )[0]
        # A rate cannot leave [0, 1] even where mean ± std does.
        band = np.clip(mean - std, 0.0, 1.0), np.clip(mean + std, 0.0, 1.0)
        ax.fill_between(grid / scale, *band, color=line.get_color(), alpha=0.2)
    ax.set_xlabel(xlabel)
    ax.set_ylabel("success rate")
    ax.set_ylim(0.0, 1.02)
    ax.grid(alpha=0.3)
    if ax.get_legend_handles_labels()[0]:
        ax.legend(loc="lower right")
    return _save(fig, Path(out_png))


def plot_curriculum(runs: Sequence[Run], out_png: str | Path) -> Path:
    """For the runs with a lift curriculum: the training lift target (m) and the success rate at
    it vs env steps (M), one colour per run. Writes ``out_png`` atomically and returns it."""
    plt = _pyplot()
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(7, 6), sharex=True)
    labels = group_labels(runs)
    for key, members in group_runs(runs).items():
        for run in members:
            if not run.has_curriculum:
                continue
            assert run.h_bar is not None and run.target_success_rate is not None
            label = f"{labels[key]} s{run.seed}"
            line = top.plot(run.env_steps / 1e6, run.h_bar, label=label)[0]
            bottom.plot(run.env_steps / 1e6, run.target_success_rate, color=line.get_color())
    top.set_ylabel("lift target h_bar (m)")
    top.grid(alpha=0.3)
    top.legend(loc="lower right")
    bottom.set_ylabel("success rate at the target")
    bottom.set_ylim(0.0, 1.02)
    bottom.set_xlabel("env steps (M)")
    bottom.grid(alpha=0.3)
    return _save(fig, Path(out_png))


def success_gain(runs: Sequence[Run], base: str, other: str) -> list[tuple[str, float]]:
    """Per object evaluated in both groups: mean success of ``other`` minus that of ``base``
    (fractions), largest gain first. Groups are named as in ``resolve_group``."""
    groups = group_runs(runs)
    base_rates = _per_object_rates(groups[resolve_group(runs, base)])
    other_rates = _per_object_rates(groups[resolve_group(runs, other)])
    for name, rates in ((base, base_rates), (other, other_rates)):
        if not rates:
            raise TrainerError(f"group {name!r} has no eval/per_object.csv; run trainer eval on it")
    common = sorted(base_rates.keys() & other_rates.keys())
    if not common:
        raise TrainerError(f"groups {base!r} and {other!r} were evaluated on no common object")
    gains = [(name, other_rates[name] - base_rates[name]) for name in common]
    return sorted(gains, key=lambda item: (-item[1], item[0]))


def plot_gain(runs: Sequence[Run], base: str, other: str, out_png: str | Path) -> Path:
    """Bar chart of ``success_gain`` (like the paper's Fig. 4), objects sorted by gain.
    Writes ``out_png`` atomically and returns it."""
    gains = success_gain(runs, base, other)
    names = [name for name, _ in gains]
    values = np.array([gain for _, gain in gains])
    plt = _pyplot()
    # Wide enough that rotated object names do not overlap with the full YCB set.
    fig, ax = plt.subplots(figsize=(max(6.0, 0.25 * len(names) + 2.0), 4.5))
    colors = np.where(values >= 0, "tab:green", "tab:red")
    ax.bar(np.arange(len(names)), values, color=colors)
    ax.axhline(0.0, color="k", linewidth=0.8)
    ax.set_xticks(np.arange(len(names)), names, rotation=90, fontsize=7)
    ax.set_xlim(-0.6, len(names) - 0.4)
    ax.set_ylabel(f"success gain ({other} − {base})")
    ax.set_title(f"per-object success gain of {other} over {base} (mean {values.mean():+.2f})")
    ax.grid(axis="y", alpha=0.3)
    return _save(fig, Path(out_png))


# --------------------------------------------------------------------------------------- report


def _relative_to(path: Path, base: Path) -> str:
    """``path`` relative to the directory ``base`` (with ``..`` as needed), '/'-separated.

    The report names runs this way so that it holds no machine-specific absolute path and its
    links still work when the report and the runs are moved or shared together.
    """
    return Path(os.path.relpath(Path(path).resolve(), Path(base).resolve())).as_posix()


def _file_label(name: str) -> str:
    return "".join(c if c.isalnum() or c in "-_." else "-" for c in name)


def write_report(
    run_dirs: Sequence[str | Path], out_dir: str | Path, compare: tuple[str, str] | None = None
) -> list[Path]:
    """Load the runs and write into ``out_dir``: ``success_vs_steps.png``,
    ``success_vs_time.png``, ``gain_<other>_over_<base>.png`` when ``compare = (base, other)``
    is given (group labels or representation names), and ``report.md`` with the summary table,
    the per-object table when any run has eval data, links to the images and the list of runs
    (each a link relative to ``out_dir``: no absolute path is written). Every file is written
    atomically; returns the written paths, report.md last."""
    if not run_dirs:
        raise TrainerError("no run directories given; pass at least one run directory")
    # The same directory given twice (e.g. overlapping globs) would count as an extra seed.
    unique = list(dict.fromkeys(Path(d).resolve() for d in run_dirs))
    runs = [load_run(d) for d in unique]
    out_dir = Path(out_dir)
    evaluated = [r for r in runs if r.per_object is not None]

    if compare is not None:
        success_gain(runs, *compare)  # a bad name fails here, before any file is written
    written = [
        plot_curves(runs, out_dir / "success_vs_steps.png", x="env_steps"),
        plot_curves(runs, out_dir / "success_vs_time.png", x="wall_time_s"),
    ]
    curriculum = [r for r in runs if r.has_curriculum]
    if curriculum:
        written.append(plot_curriculum(curriculum, out_dir / "curriculum.png"))
    if compare is not None:
        base, other = compare
        name = f"gain_{_file_label(other)}_over_{_file_label(base)}.png"
        written.append(plot_gain(runs, base, other, out_dir / name))

    parts = ["# Training report", ""]
    parts += [f"{len(runs)} runs in {len(group_runs(runs))} groups.", ""]
    parts += ["## Summary", "", summary_table(runs)]
    parts += [
        f"Final success: the `trainer eval` overall (successes / episodes) for the "
        f"{len(evaluated)} evaluated runs, the mean training success rate over the last 10 % of "
        f"iterations for the other {len(runs) - len(evaluated)}. Steps and minutes to a threshold "
        f"are at the first iteration whose training success rate reaches it; mean ± std over "
        f"seeds (ddof 0) of the seeds that reached it.",
        "",
    ]
    if evaluated:
        parts += ["## Success per object (`trainer eval`)", "", per_object_table(runs)]
    parts += [
        "## Curves",
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
    group_of = {id(r): key for key, members in group_runs(runs).items() for r in members}
    for r in runs:
        rel = _relative_to(r.path, out_dir)
        parts.append(f"- [`{rel}`]({rel}): {'/'.join(group_of[id(r)])}, seed {r.seed}")

    report = out_dir / "report.md"
    with atomic_path(report) as tmp:
        tmp.write_text("\n".join(parts) + "\n")
    written.append(report)
    return written
