"""Compare finished training runs: markdown tables and plots like the paper's Table II and Fig. 4.

A run directory is read as the trainer writes it::

    RUN_DIR/config.json            env.task, env.bin.num_objects, env.context,
                                   env.representation, env.reward.kind, env.robot.kind, run.seed
    RUN_DIR/metrics.csv            one row per PPO iteration: env_steps, wall_time_s,
                                   object_success_rate (the mean over objects; success_rate, over
                                   all ended episodes, in runs logged before it existed)
    RUN_DIR/launches.csv           optional: the code and machine of each start and resume
    RUN_DIR/eval/per_object.csv    optional (``trainer eval``): object, episodes, successes;
                                   ``eval`` or another folder of ``trainer eval --out`` (the
                                   report's ``eval_dir``), with the success criterion in table.md

Runs are grouped by (task, representation, reward kind, robot kind), where the task is ``lift`` or
``binN`` (N objects per bin) and the representation gains ``+ctx`` when the policy also sees the
other objects (``context``): a bin run and a lift run are different groups even with the same
representation. Run directories written before the tasks existed (no ``env.task``) are lift
runs. Runs of one such group whose configs differ in anything else (physics, PPO settings, the
budget; not in the seed or in ``NOT_THE_EXPERIMENT``, and only in fields every one of them
records, or that ``config.ABSENT_MEANS`` fills in) are split further, and the representation names
the difference, e.g. ``bbox [noslip_iterations=5]``; so is a group whose runs differ from most
of the report's runs in such a field, even alone (``pc128 [pointnet_hidden=[16, 32, 64]]`` among
arms of the default encoder). The runs of a group are then taken to
differ by seed, and every table cell is a mean ± std (ddof = 0) over them. Units: env steps are
counted over all parallel environments, wall time is seconds in the data and minutes in tables
and plots, success rates are fractions in [0, 1].

Groups are the arms of the paper's comparison: ordered as its Table I (``PAPER_ORDER``), then
the reward ablations (the paper's are bbox runs with reward kind ``com`` and ``none``), then any
other group in the order the runs came. Labels: ``sq`` (lift), ``bbox (reward com)``, ``bbox (no
shaping)``, ``bin5-bbox``, ``bin5-bbox+ctx``, and ``(robot floating)`` for another robot than the
paper's. The paper's numbers (``PAPER_TABLE_I``, ``PAPER_TABLE_II``) stand beside the arms that
are its own: a lift run, no context, the SDF reward, the UR5e.
"""

from __future__ import annotations

import csv
import json
import math
import os
import re
import shlex
from collections import Counter
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Literal, NamedTuple

import numpy as np

from geomgrasp.files import atomic_path
from trainer.config import ABSENT_MEANS
from trainer.errors import TrainerError
from trainer.training.run_dir import (
    BY_START_COLUMNS,
    RunDir,
    read_evaluated_on,
    read_launches,
)

GroupKey = tuple[str, str, str, str]
"""(task, representation, reward kind, robot kind): task ``lift`` or ``binN``, representation
with ``+ctx`` when the policy sees the context (see ``task_name`` and ``view_name``)."""

NOT_THE_EXPERIMENT = frozenset({
    "run.seed", "run.torch_threads", "run.checkpoint_every", "env.nthread", "env.compile",
    "env.data_dir", "env.device",
})
"""Config fields that seeds of one experiment may differ in: the seed, and how and where it ran."""
THRESHOLDS = (0.9, 0.95)
"""Table II's success rates (the paper's); ``trainer report --thresholds`` picks others."""
CURVE_POINTS = 200
_DASH = "—"

PAPER_ORDER = ("com", "sdf", "bbox", "sq", "pc32", "pc128", "pc512")
"""The representations in the order of the paper's Table I and II columns / rows."""
WORST = 10
"""Objects listed per arm in the report's worst-objects table (the paper's all-78 layout names
its worst ten)."""
_REWARD_NOTES = {"com": "reward com", "none": "no shaping"}
"""How a label names a reward kind other than the paper's ``sdf``; ablations ordered thus."""

_P = PAPER_ORDER
PAPER_TABLE_I: dict[str, dict[str, tuple[float, float]]] = {
    # Table I of the paper ("Variations in lifting success rates for different representations of
    # object geometry", label object_specific_success_rates): final test success, mean and std
    # over seeds, columns COM, SDF, BBox, SQ, PC-32, PC-128, PC-512 (PAPER_ORDER).
    name: dict(zip(_P, cells, strict=True))
    for name, cells in {
        "007_tuna_fish_can": ((0.99, 0.0), *[(1.0, 0.0)] * 6),
        "013_apple": ((1.0, 0.0),) * 7,
        "029_plate": ((0.74, 0.14), (0.95, 0.0), (0.93, 0.02), (0.95, 0.04), (0.5, 0.39),
                      (0.94, 0.03), (0.94, 0.04)),
        "032_knife": ((0.77, 0.07), (0.81, 0.07), (0.96, 0.02), (0.85, 0.1), (0.71, 0.02),
                      (0.9, 0.02), (0.79, 0.06)),
        "053_mini_soccer_ball": ((1.0, 0.0),) * 7,
        "062_dice": ((0.65, 0.3), (0.85, 0.08), (0.95, 0.02), (0.94, 0.01), (0.55, 0.07),
                     (0.86, 0.0), (0.6, 0.12)),
        "065-a_cups": ((0.99, 0.0), *[(1.0, 0.0)] * 6),
        "072-a_toy_airplane": ((0.93, 0.02), (0.99, 0.01), (0.99, 0.01), (0.97, 0.03),
                               (0.95, 0.01), (0.99, 0.0), (0.96, 0.02)),
        "073-g_lego_duplo": ((0.9, 0.01), (0.97, 0.01), (0.99, 0.0), (0.96, 0.02), (0.95, 0.01),
                             (0.99, 0.0), (0.98, 0.01)),
        "077_rubiks_cube": ((1.0, 0.0),) * 7,
    }.items()
}
PAPER_ALL_OBJECTS: dict[str, tuple[float, float]] = dict(zip(_P, (
    # Table I's last row, "All 78 YCB objects".
    (0.95, 0.02), (0.96, 0.01), (0.97, 0.01), (0.96, 0.02), (0.92, 0.03), (0.97, 0.0),
    (0.95, 0.02),
), strict=True))
PAPER_TABLE_II: dict[str, dict[float, tuple[tuple[float, float], tuple[float, float]]]] = {
    # Table II of the paper ("Sample efficiency of different object representations",
    # label sample_efficiency_of_object_representations): per threshold, (env steps in
    # millions, runtime in minutes), each (mean, std) over seeds.
    rep: {0.9: (cells[0], cells[1]), 0.95: (cells[2], cells[3])}
    for rep, cells in zip(_P, (
        ((149, 30), (47, 9), (550, 161), (116, 34)),
        ((134, 5), (72, 3), (276, 51), (152, 28)),
        ((165, 8), (69, 3), (274, 44), (127, 23)),
        ((178, 18), (58, 6), (436, 52), (220, 26)),
        ((196, 15), (52, 4), (474, 170), (178, 63)),
        ((173, 4), (47, 2), (232, 1), (65, 1)),
        ((219, 19), (62, 6), (277, 12), (87, 4)),
    ), strict=True)
}


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
    endings: dict[str, dict[str, int]] | None = None
    """Per object, how its evaluation episodes ended (``endings.csv`` of ``trainer eval``:
    ending -> episodes; None where the evaluation did not record them)."""
    eval_criterion: str | None = None
    """The success criterion of the evaluation (its table.md's ``Success:`` line without the
    prefix, e.g. "the target lifted by 0.2 m ..."), if stated."""
    by_start: dict[str, tuple[int, int, int, int]] | None = None
    """Per object, (face-up episodes, their successes, upside-down episodes, their successes)
    from ``trainer eval``'s ``by_start.csv`` (how the target rested after the first action);
    None where the evaluation did not record it."""
    machines: tuple[tuple[int, str, str], ...] = ()
    """(first iteration, the machine in words, the code) per launch, from ``launches.csv``;
    empty for a run trained before the file existed."""
    eval_machine: tuple[str, str] | None = None
    """(CPU model, code) that made the evaluation (its table.md's last line); None where not
    recorded (evaluations before 2026-11-30)."""

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

    @property
    def paper_arm(self) -> str | None:
        """The representation when the run is one of the paper's Table I / II arms (lift, no
        context, the SDF reward, the UR5e), else None."""
        own = (self.task, self.context, self.reward, self.robot) == ("lift", "none", "sdf", "ur5e")
        return self.representation if own and self.representation in PAPER_ORDER else None

    @property
    def steps_per_second(self) -> float:
        """Env steps per second of training wall time, over the whole run (its last row)."""
        seconds = float(self.wall_time_s[-1])
        return float(self.env_steps[-1]) / seconds if seconds > 0 else math.nan


# --------------------------------------------------------------------------------------- loading


def load_run(path: str | Path, eval_dir: str = "eval") -> Run:
    """Read a run directory, its evaluation from the folder ``eval_dir`` in it (``trainer eval
    --out``); raise TrainerError naming the file and the fix if it is unusable."""
    path = Path(path)
    if not path.is_dir():
        raise TrainerError(
            f"{path}: not a directory; pass a run directory written by trainer run"
        )
    _check_eval_dir(eval_dir)
    run = RunDir(path)
    config = _read_config(run.config)
    env_steps, wall_time_s, success_rate, h_bar, target_rate = _read_metrics(run.metrics)
    per_object_path = path / eval_dir / "per_object.csv"
    per_object = _read_per_object(per_object_path) if per_object_path.is_file() else None
    table = _read_lines(path / eval_dir / "table.md") if per_object else []
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
        eval_criterion=_criterion(table) if per_object else None,
        eval_machine=_eval_machine(table) if per_object else None,
        endings=_read_endings(path / eval_dir / "endings.csv") if per_object else None,
        by_start=_read_by_start(path / eval_dir / "by_start.csv") if per_object else None,
        machines=tuple((int(r["first_iteration"]), _machine_words(r), r["code"])
                       for r in read_launches(run)),
    )


def _machine_words(row: dict[str, str]) -> str:
    """A ``launches.csv`` row in words, e.g. ``AMD EPYC, 2 cores, nice 5``."""
    words = [row["cpu"], f"{row['cores']} cores"]
    if row["nice"] not in ("", "0"):
        words.append(f"nice {row['nice']}")
    if row["device"] != "cpu":
        words.append(row["device"])
    if row["processes"] not in ("", "1"):
        words.append(f"{row['processes']} processes")
    return ", ".join(words)


def machines_text(runs: Sequence[Run], out_dir: Path) -> list[str]:
    """Per run, the machines (and code) that trained which of its iterations (``launches.csv``),
    and whether the arms' minutes and env steps/s compare: only where one machine trained them
    all."""
    lines, seen = [], set()
    for r in runs:
        last = len(r.env_steps)
        spans = []
        if not r.machines or r.machines[0][0] > 1:
            end = r.machines[0][0] - 1 if r.machines else last
            spans.append(f"iterations 1-{end}: not recorded")
            seen.add(None)
        for k, (first, words, code) in enumerate(r.machines):
            end = r.machines[k + 1][0] - 1 if k + 1 < len(r.machines) else last
            if first <= end:
                spans.append(f"iterations {first}-{end}: {words} (code {code})")
            seen.add(re.sub(r", nice -?[0-9]+", "", words))  # (the same machine, niced or not)
        lines.append(f"- `{_relative_to(r.path, out_dir)}`: " + "; ".join(spans))
    if seen == {next(iter(seen))} and None not in seen:
        verdict = "One machine trained every run: minutes and env steps/s compare across arms."
    else:
        verdict = ("**Minutes and env steps/s compare only between runs on one machine**, and "
                   "these runs were trained on more than one or on machines not recorded "
                   "(`launches.csv` exists since 2026-11-30): compare the arms by env steps.")
    return [verdict, "", *lines, "", *_evaluation_machines(runs, out_dir)]


def _evaluation_machines(runs: Sequence[Run], out_dir: Path) -> list[str]:
    """Which CPU models evaluated the runs (table.md's last line): one line where one did them
    all, else each run's, since the same checkpoint and seed end some episodes differently on
    another CPU model."""
    evaluated = [r for r in runs if r.per_object is not None]
    if not evaluated:
        return []
    cpus = {r.eval_machine[0] if r.eval_machine else None for r in evaluated}
    if len(cpus) == 1 and None not in cpus:
        codes = sorted({r.eval_machine[1] for r in evaluated if r.eval_machine})
        return [f"One CPU model evaluated every run: {next(iter(cpus))} (code "
                f"{', '.join(codes)}).", ""]
    return [
        "**The evaluations were made on more than one CPU model or on one not recorded** "
        "(table.md's last line, since 2026-11-30): the same checkpoint and seed end some "
        "contact-rich episodes differently on another CPU model (up to 5 of 50 per object, "
        "0.016 overall: results/cpu-comparison-2026-11-29/), as another evaluation seed would.",
        "",
        *(f"- `{_relative_to(r.path, out_dir)}`: "
          + (f"{r.eval_machine[0]} (code {r.eval_machine[1]})" if r.eval_machine
             else "not recorded") for r in evaluated),
        "",
    ]


def _read_endings(path: Path) -> dict[str, dict[str, int]] | None:
    """``endings.csv`` (object, episodes, one column per ending): object -> ending -> episodes
    (the column names with spaces for underscores); None if absent or unreadable (an
    evaluation from before the endings were recorded, or a damaged file: the report leaves
    the endings out rather than stop)."""
    if not path.is_file():
        return None
    try:
        with path.open(newline="") as f:
            rows = list(csv.DictReader(f))
        out = {row["object"]: {k.replace("_", " "): int(v) for k, v in row.items()
                               if k not in ("object", "episodes")} for row in rows}
        # every row: a success column, and endings that add up to its episodes
        if not rows or any("success" not in by or sum(by.values()) != int(row["episodes"])
                           for row, by in zip(rows, out.values(), strict=True)):
            return None
        return out
    except (OSError, UnicodeDecodeError, csv.Error, KeyError, TypeError, ValueError):
        return None


def _read_by_start(path: Path) -> dict[str, tuple[int, int, int, int]] | None:
    """``by_start.csv`` (object, face-up episodes and successes, upside-down ones); None if
    absent or unreadable (the table that reads it is left out rather than the report)."""
    columns = BY_START_COLUMNS[1:]
    if not path.is_file():
        return None
    try:
        with path.open(newline="") as f:
            return {row["object"]: tuple(int(row[c]) for c in columns)  # type: ignore[misc]
                    for row in csv.DictReader(f)}
    except (OSError, UnicodeDecodeError, csv.Error, KeyError, TypeError, ValueError):
        return None


def upside_down_table(runs: Sequence[Run]) -> str:
    """The objects that fail when they start upside down (the plate: a dome no grasp of this
    hand lifts): those whose upside-down episodes, pooled over every evaluated run, succeed at
    less than half the rate of their face-up ones. One row per such object, one column per arm
    with the record: its success over all resets and over the face-up ones (mean over seeds),
    and the face-up share of the episodes. Empty where no object qualifies."""
    recorded = [r for r in runs if r.by_start]
    pooled: dict[str, list[int]] = {}
    for r in recorded:
        for name, counts in r.by_start.items():  # type: ignore[union-attr]
            pooled[name] = [a + b for a, b in zip(pooled.get(name, [0] * 4), counts, strict=True)]
    failing = sorted(
        name for name, (up, up_held, down, down_held) in pooled.items()
        if up and down and up_held and down_held / down < 0.5 * up_held / up
    )
    if not failing:
        return ""
    labels = group_labels(runs)
    groups = {k: [r for r in m if r.by_start] for k, m in group_runs(runs).items()}
    groups = {k: m for k, m in groups.items() if m}
    lines = ["| object | " + " | ".join(labels[k] for k in groups) + " |",
             "|---|" + "---:|" * len(groups)]
    for name in failing:
        cells = [name]
        for members in groups.values():
            rows = [r.by_start[name] for r in members if name in r.by_start]  # type: ignore[index]
            if not rows:
                cells.append(_DASH)
                continue
            every = np.mean([(b + d) / max(1, a + c) for a, b, c, d in rows])
            up = [b / a for a, b, _, _ in rows if a]
            share = sum(a for a, _, _, _ in rows) / max(1, sum(a + c for a, _, c, _ in rows))
            face_up = f"{np.mean(up):.2f}" if up else _DASH
            cells.append(f"{every:.2f} / {face_up} ({share:.0%} face up)")
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def _check_eval_dir(eval_dir: str) -> None:
    parts = Path(eval_dir).parts
    if not parts or Path(eval_dir).is_absolute() or ".." in parts:
        raise TrainerError(
            f"eval folder {eval_dir!r}: give the name of a folder inside the run directories "
            "(as trainer eval --out names it), e.g. eval or eval-it350"
        )


def _read_lines(path: Path) -> list[str]:
    """The lines of ``trainer eval``'s table.md; none where it is absent or unreadable."""
    try:
        return path.read_text().splitlines() if path.is_file() else []
    except (OSError, UnicodeDecodeError):
        return []


def _criterion(table: list[str]) -> str | None:
    """The success criterion of table.md's ``Success: ...`` line; None where it has none
    (evaluations before it stated one)."""
    return next((line.removeprefix("Success: ").strip() for line in table
                 if line.startswith("Success: ")), None)


def _eval_machine(table: list[str]) -> tuple[str, str] | None:
    """(CPU model, code) of the evaluation whose table.md lines these are; None if not
    recorded (evaluations before 2026-11-30)."""
    return next((found for line in table if (found := read_evaluated_on(line))), None)


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


GROUP_FIELDS = frozenset({
    "env.task", "env.representation", "env.context", "env.bin.num_objects", "env.reward.kind",
    "env.robot.kind",
})
"""The config fields of the group key (``Run.group``): how arms differ by design."""


def _uncommon_settings(runs: Sequence[Run]) -> dict[int, set[str]]:
    """Per run (by id), the settings outside ``GROUP_FIELDS`` in which it differs from most of
    ``runs`` (the value most of them have; on a tie, every run's): an arm that ran with another
    network than the others (the authors' point-cloud encoder, say) is named so even alone."""
    out: dict[int, set[str]] = {id(r): set() for r in runs}
    fields = set().union(*(set(r.settings) for r in runs)) - GROUP_FIELDS
    for k in fields:
        having = [r for r in runs if k in r.settings]  # (a run may predate the field)
        counts = Counter(r.settings[k] for r in having)
        if len(counts) < 2:
            continue
        (_, top), *rest = counts.most_common()
        tied = rest[0][1] == top
        for r in having:
            if tied or counts[r.settings[k]] < top:
                out[id(r)].add(k)
    return out


def group_runs(runs: Iterable[Run]) -> dict[GroupKey, list[Run]]:
    """Runs by group key, groups in the paper's order (``arm_order``), runs within a group by
    seed. Runs of one ``Run.group`` whose settings differ are split: their representation gains
    `` [name=value, ...]`` for every setting that differs (see the module docstring), and for
    every setting in which a run differs from most of the runs (``_uncommon_settings``)."""
    runs = list(runs)
    uncommon = _uncommon_settings(runs)
    by_group: dict[GroupKey, list[Run]] = {}
    for run in runs:
        by_group.setdefault(run.group, []).append(run)
    groups: dict[GroupKey, list[Run]] = {}
    for key, members in by_group.items():
        shared = set.intersection(*(set(r.settings) for r in members))
        differ = {k for k in shared if len({r.settings[k] for r in members}) > 1}
        for run in members:
            variant = ", ".join(
                f"{k.rsplit('.', 1)[-1]}={json.loads(run.settings[k])}"
                for k in sorted(differ | (uncommon[id(run)] & shared))
            )
            split = (key[0], f"{key[1]} [{variant}]", *key[2:]) if variant else key
            groups.setdefault(split, []).append(run)
    for members in groups.values():
        members.sort(key=lambda r: (r.seed is None, r.seed if r.seed is not None else 0))
    # sorted() is stable: groups of one rank keep the order in which the runs came.
    return dict(sorted(groups.items(), key=lambda item: arm_order(item[1][0])))


def arm_order(run: Run) -> tuple[int, int]:
    """Where a run's group stands in the tables: the paper's arms in ``PAPER_ORDER``, then its
    representations with the ablated rewards (``com``, then ``none``), any other reward, and
    last everything else (bin tasks, context, another robot)."""
    if (run.task, run.context, run.robot) != ("lift", "none", "ur5e") or (
        run.representation not in PAPER_ORDER
    ):
        return len(_REWARD_NOTES) + 2, 0
    rewards = ("sdf", *_REWARD_NOTES)
    tier = rewards.index(run.reward) if run.reward in rewards else len(rewards)
    return tier, PAPER_ORDER.index(run.representation)


def group_labels(runs: Iterable[Run]) -> dict[GroupKey, str]:
    """A label per group: the task and view (``sq``, ``bin5-bbox``, ``bin5-bbox+ctx``), with
    what differs from the paper's reward and robot in brackets: ``bbox (reward com)``, ``bbox
    (no shaping)`` (reward kind ``none``), ``bbox (robot floating)``."""
    labels = {}
    for key in group_runs(runs):
        notes = [] if key[2] == "sdf" else [_REWARD_NOTES.get(key[2], f"reward {key[2]}")]
        notes += [] if key[3] == "ur5e" else [f"robot {key[3]}"]
        labels[key] = _label(key) + (f" ({'; '.join(notes)})" if notes else "")
    return labels


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


def _seed_rates(members: Sequence[Run]) -> list[dict[str, float]]:
    """Per evaluated run of a group: object -> successes / episodes (objects with episodes)."""
    return [
        {name: s / e for name, (e, s) in run.per_object.items() if e}
        for run in members
        if run.per_object is not None
    ]


def _per_object_rates(members: Sequence[Run]) -> dict[str, float]:
    """Per object, the mean over seeds of each seed's successes / episodes (evaluated runs only)."""
    rates: dict[str, list[float]] = {}
    for seed in _seed_rates(members):
        for name, rate in seed.items():
            rates.setdefault(name, []).append(rate)
    return {name: float(np.mean(values)) for name, values in rates.items()}


def overall_success(members: Sequence[Run]) -> list[float]:
    """Per evaluated run of a group, its mean success over the objects it was evaluated on (each
    object weighs the same, as in the paper's Table I); the mean of these is Table I's overall."""
    return [float(np.mean(list(seed.values()))) for seed in _seed_rates(members) if seed]


def paper_overall(representation: str, objects: Iterable[str]) -> tuple[float, str]:
    """The paper's overall success of a representation to set beside ours on ``objects``: its
    Table I mean over the same objects where it lists them all, else its all-78-objects value.
    Returns (value, which of the two it is in words)."""
    objects = sorted(set(objects))
    if objects and all(name in PAPER_TABLE_I for name in objects):
        values = [PAPER_TABLE_I[name][representation][0] for name in objects]
        return float(np.mean(values)), "its mean over the same objects"
    return PAPER_ALL_OBJECTS[representation][0], "its value over all 78 objects"


# --------------------------------------------------------------------------------------- tables


def _mean_std(values: Sequence[float], fmt: str = ".2f") -> str:
    """``mean ± std`` (ddof 0) over the finite values, the mean alone for one, "—" for none."""
    finite = np.array([v for v in values if math.isfinite(v)], dtype=np.float64)
    if finite.size == 0:
        return _DASH
    if finite.size == 1:
        return format(finite[0], fmt)
    return f"{format(finite.mean(), fmt)} ± {format(finite.std(ddof=0), fmt)}"


def _percent(threshold: float) -> str:
    return f"{threshold * 100:g} %"


def _paper_note(value: float | None, fmt: str) -> str:
    return f" ({_DASH if value is None else format(value, fmt)})"


def summary_table(
    runs: Sequence[Run], thresholds: Sequence[float] = THRESHOLDS, last_fraction: float = 0.1
) -> str:
    """Markdown table in the layout of the paper's Table II, one line per group (arm, in the
    paper's order): seeds, final success (``final_success``), env steps per second of training
    wall time, and per threshold how many seeds reached it, and the env steps (M) and minutes to
    it, mean ± std over the seeds that did ("not reached" where none did). In brackets beside
    steps and minutes the paper's Table II mean, for its arms at its thresholds (90 %, 95 %)."""
    header = ["arm", "seeds", "final success", "env steps/s"]
    for threshold in thresholds:
        p = _percent(threshold)
        header += [f"reached {p}", f"steps to {p} (M)", f"minutes to {p}"]
    lines = ["| " + " | ".join(header) + " |", "|---|" + "---:|" * (len(header) - 1)]
    labels = group_labels(runs)
    for key, members in group_runs(runs).items():
        arm = members[0].paper_arm
        cells = [labels[key], str(len(members))]
        cells.append(_mean_std([final_success(r, last_fraction) for r in members]))
        cells.append(_mean_std([r.steps_per_second for r in members], ".0f"))
        for threshold in thresholds:
            reached = [steps_to_reach(r, threshold) for r in members]
            hits = sum(math.isfinite(steps) for steps, _ in reached)
            paper = PAPER_TABLE_II.get(arm or "", {}).get(round(threshold, 6))
            steps = _mean_std([s / 1e6 for s, _ in reached]) if hits else "not reached"
            minutes = _mean_std([t / 60 for _, t in reached], ".1f") if hits else "not reached"
            if paper is not None:
                steps += _paper_note(paper[0][0], "g")
                minutes += _paper_note(paper[1][0], "g")
            cells += [f"{hits}/{len(members)}", steps, minutes]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def per_object_table(runs: Sequence[Run]) -> str:
    """Markdown table in the layout of the paper's Table I: one row per object, one column per
    group with eval data (arms in the paper's order), each cell the mean ± std over that group's
    evaluated seeds of the object's success rate, then in brackets the paper's Table I value
    ("—" where it has none). "†" marks a cell some evaluated seeds lack the object in. Then
    the overall row (per seed the mean over its objects, mean ± std over seeds, beside the
    paper's ``paper_overall``), the paper's all-78-objects row, and the seeds evaluated."""
    labels = group_labels(runs)
    groups = {
        key: members
        for key, members in group_runs(runs).items()
        if any(r.per_object is not None for r in members)
    }
    if not groups:
        raise TrainerError(
            "no run has an evaluation (per_object.csv); run trainer eval on the runs first"
        )
    seeds = {key: _seed_rates(members) for key, members in groups.items()}
    arms = {key: members[0].paper_arm for key, members in groups.items()}
    objects = sorted(set().union(*(rates for per_seed in seeds.values() for rates in per_seed)))
    lines = [
        "| object | " + " | ".join(labels[key] for key in groups) + " |",
        "|---|" + "---:|" * len(groups),
    ]
    for name in objects:
        cells = []
        for key, per_seed in seeds.items():
            values = [rates[name] for rates in per_seed if name in rates]
            paper = PAPER_TABLE_I.get(name, {}).get(arms[key] or "")
            mark = "†" if values and len(values) < len(per_seed) else ""
            cells.append(_mean_std(values) + mark + _paper_note(paper[0] if paper else None, ".2f"))
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    overall = []
    for key, members in groups.items():
        arm = arms[key]
        columns = set().union(*seeds[key])
        paper = paper_overall(arm, columns)[0] if arm else None
        overall.append(f"**{_mean_std(overall_success(members))}**" + _paper_note(paper, ".2f"))
    lines.append("| **mean over objects** | " + " | ".join(overall) + " |")
    every = [
        _paper_note(PAPER_ALL_OBJECTS[a][0] if a else None, ".2f").strip() for a in arms.values()
    ]
    lines.append("| all 78 YCB objects (paper) | " + " | ".join(every) + " |")
    lines.append("| seeds evaluated | " + " | ".join(str(len(s)) for s in seeds.values()) + " |")
    return "\n".join(lines) + "\n"


def spearman(xs: Sequence[float], ys: Sequence[float]) -> float:
    """Spearman's rank correlation: the Pearson correlation of the ranks, ties given their
    average rank; NaN for fewer than two pairs or when one side is all ties."""
    if len(xs) != len(ys):
        raise TrainerError(f"spearman needs pairs, got {len(xs)} and {len(ys)} values")
    if len(xs) < 2:
        return math.nan
    from scipy.stats import rankdata

    rx, ry = rankdata(xs), rankdata(ys)
    if np.ptp(rx) == 0 or np.ptp(ry) == 0:
        return math.nan
    return float(np.corrcoef(rx, ry)[0, 1])


@dataclass(frozen=True)
class Ranking:
    """Our ordering of the paper's representations by overall success against the paper's:
    ``arms`` in the paper's order, ``ours`` (Table I's mean over objects, mean over seeds) and
    ``paper`` (``paper_overall`` on the same objects), Spearman's ``rho`` between them, and
    ``basis`` saying which paper value was used."""

    arms: tuple[str, ...]
    ours: tuple[float, ...]
    paper: tuple[float, ...]
    rho: float
    basis: str
    left_out: tuple[str, ...] = ()
    """Representations in several groups (e.g. split by a setting), not ranked."""
    seeds: tuple[tuple[float, ...], ...] = ()
    """Per arm (``arms``' order), the overall success of each evaluated seed (``settled``);
    ``ours`` is their mean."""


def paper_ranking(runs: Sequence[Run]) -> Ranking:
    """The ``Ranking`` over the paper's arms that were evaluated (one group each)."""
    by_arm: dict[str, list[list[Run]]] = {}
    for members in group_runs(runs).values():
        arm = members[0].paper_arm
        if arm is not None and overall_success(members):
            by_arm.setdefault(arm, []).append(members)
    arms = tuple(a for a in PAPER_ORDER if len(by_arm.get(a, ())) == 1)
    ours, paper, bases, seeds = [], [], set(), []
    for arm in arms:
        members = by_arm[arm][0]
        seeds.append(tuple(overall_success(members)))
        ours.append(float(np.mean(seeds[-1])))
        value, basis = paper_overall(arm, set().union(*_seed_rates(members)))
        paper.append(value)
        bases.add(basis)
    return Ranking(
        arms=arms, ours=tuple(ours), paper=tuple(paper), rho=spearman(ours, paper),
        basis=" / ".join(sorted(bases)),
        left_out=tuple(a for a in PAPER_ORDER if len(by_arm.get(a, ())) > 1),
        seeds=tuple(seeds),
    )


def _ordering(arms: Sequence[str], values: Sequence[float]) -> str:
    """``bbox 0.810 > sq 0.600 = com 0.600``, best first."""
    order = sorted(range(len(arms)), key=lambda i: -values[i])
    text = f"{arms[order[0]]} {values[order[0]]:.3f}"
    for prev, i in zip(order, order[1:], strict=False):
        relation = "=" if math.isclose(values[i], values[prev]) else ">"
        text += f" {relation} {arms[i]} {values[i]:.3f}"
    return text


def ranking_text(ranking: Ranking) -> str:
    """Sentences on the ranking: rho, both orderings, and the pairs they agree and disagree on."""
    left = (
        f" Left out, being in several groups: {', '.join(ranking.left_out)}."
        if ranking.left_out else ""
    )
    if len(ranking.arms) < 2:
        have = ", ".join(ranking.arms) or "none"
        return (
            "The rank correlation with the paper needs at least two of its representations "
            f"(lift, SDF reward) evaluated; here {have}.{left}"
        )
    rho = "undefined (all tied on one side)" if math.isnan(ranking.rho) else f"{ranking.rho:+.2f}"
    agree, disagree, tied, settled_disagree = [], [], [], []
    for i in range(len(ranking.arms)):
        for j in range(i + 1, len(ranking.arms)):
            a, b = ranking.arms[i], ranking.arms[j]
            ours = ranking.ours[i] - ranking.ours[j]
            paper = ranking.paper[i] - ranking.paper[j]
            ours_tie = math.isclose(ranking.ours[i], ranking.ours[j])
            paper_tie = math.isclose(ranking.paper[i], ranking.paper[j])
            if ours_tie or paper_tie:
                side = "both" if ours_tie and paper_tie else "ours" if ours_tie else "the paper"
                tied.append(f"{a} = {b} ({side})")
            elif (ours > 0) == (paper > 0):
                agree.append(f"{a} > {b}" if ours > 0 else f"{b} > {a}")
            else:
                disagree.append(f"{a} > {b}" if ours > 0 else f"{b} > {a}")
                high, low = (i, j) if ours > 0 else (j, i)
                if settled(ranking.seeds[high], ranking.seeds[low]):
                    settled_disagree.append(disagree[-1])
    pairs = len(ranking.arms) * (len(ranking.arms) - 1) // 2
    text = (
        f"Spearman's rank correlation of our ordering of the {len(ranking.arms)} representations "
        f"by overall success (Table I's mean over objects) with the paper's ({ranking.basis}): "
        f"ρ = {rho}. Ours: {_ordering(ranking.arms, ranking.ours)}; the "
        f"paper's: {_ordering(ranking.arms, ranking.paper)}. "
    )
    text += f"Of the {pairs} pairs, the orderings agree on {len(agree)}"
    text += f" ({', '.join(agree)})" if agree else ""
    text += f" and disagree on {len(disagree)}"
    text += f" (ours {', '.join(disagree)}; the paper's the reverse)" if disagree else ""
    text += f"; tied: {', '.join(tied)}." if tied else "."
    if disagree:
        text += (
            f" Of the pairs that disagree, our seeds settle {len(settled_disagree)}"
            + (f" ({', '.join(settled_disagree)})" if settled_disagree else "")
            + " (every seed of the one above every seed of the other, two seeds or more "
            "each); the others are inside the seed spread or rest on one seed."
        )
    return text + left


def settled(higher: Sequence[float], lower: Sequence[float]) -> bool:
    """Whether the seeds settle that one arm is above another: both evaluated with two seeds or
    more, and every seed of ``higher`` above every seed of ``lower`` (overall success)."""
    return len(higher) >= 2 and len(lower) >= 2 and min(higher) > max(lower)


def seeds_table(runs: Sequence[Run]) -> str:
    """Per evaluated arm, best mean first: its overall success per seed, the arms the seeds
    settle it above (``settled``), and those whose seeds overlap with its own (a difference
    inside the seed spread; an arm with one seed is in neither column); then the seeds' spread
    against the arms' (``seed_and_arm_spread``)."""
    labels = group_labels(runs)
    overall = {labels[k]: overall_success(m) for k, m in group_runs(runs).items()}
    overall = {label: rates for label, rates in overall.items() if rates}
    order = sorted(overall, key=lambda label: -float(np.mean(overall[label])))
    lines = ["| arm | seeds | overall per seed | settled above | seeds overlap with |",
             "|---|---:|---|---|---|"]
    for label in order:
        mine = overall[label]
        above = [o for o in order if o != label and settled(mine, overall[o])]
        overlap = [
            o for o in order
            if o != label and not settled(mine, overall[o]) and not settled(overall[o], mine)
            and len(mine) >= 2 and len(overall[o]) >= 2
        ]
        per_seed = ", ".join(f"{rate:.3f}" for rate in mine)
        lines.append(f"| {label} | {len(mine)} | {per_seed} | {', '.join(above) or _DASH} | "
                     f"{', '.join(overlap) or _DASH} |")
    spread = seed_and_arm_spread(list(overall.values()))
    if spread is not None:
        lines += ["", f"Over the {spread.arms} arms with two seeds or more: the seeds of one arm "
                  f"spread by {spread.within:.3f} (pooled std, ddof 1), the arms' means by "
                  f"{spread.between:.3f} (std of the means, ddof 1); were the arms alike, "
                  f"their means would spread by about {spread.alike:.3f}."]
    return "\n".join(lines) + "\n"


class SeedSpread(NamedTuple):
    """How much the seeds of one arm differ, against how much the arms do (overall success)."""

    within: float
    """Pooled standard deviation of the seeds within an arm (ddof 1)."""
    between: float
    """Standard deviation of the arms' means (ddof 1)."""
    alike: float
    """What ``between`` would be were the arms alike: ``within`` / sqrt(seeds per arm, their
    harmonic mean)."""
    arms: int


def seed_and_arm_spread(arms: Sequence[Sequence[float]]) -> SeedSpread | None:
    """The ``SeedSpread`` over the arms (each its seeds' overall success) with two seeds or
    more; None for fewer than two such arms."""
    kept = [np.asarray(a, dtype=np.float64) for a in arms if len(a) >= 2]
    if len(kept) < 2:
        return None
    dof = sum(a.size - 1 for a in kept)
    within = math.sqrt(sum(float(((a - a.mean()) ** 2).sum()) for a in kept) / dof)
    between = float(np.std([a.mean() for a in kept], ddof=1))
    alike = within * math.sqrt(sum(1 / a.size for a in kept) / len(kept))
    return SeedSpread(within, between, alike, len(kept))


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


def _style(run: Run, others: int) -> dict[str, str]:
    """Line colour and style of a group: each of the paper's representations has its own colour
    in every plot (C0..C6 in ``PAPER_ORDER``), its ablations dashed, other groups (the
    ``others``-th of them) C7 on, dotted."""
    tier, index = arm_order(run)
    if tier > len(_REWARD_NOTES) + 1:
        return {"color": f"C{(7 + others) % 10}", "linestyle": ":"}
    return {"color": f"C{index}", "linestyle": "-" if tier == 0 else "--"}


def plot_curves(
    runs: Sequence[Run],
    out_png: str | Path,
    x: Literal["env_steps", "wall_time_s"] = "env_steps",
    thresholds: Sequence[float] = (),
) -> Path:
    """Success rate vs env steps (M) or vs wall time (min): per group, the mean over seeds with a
    ± std band (see ``mean_curve``; with two seeds the band is their min-max), and a grey dashed
    line at each of ``thresholds``. Writes ``out_png`` atomically and returns it."""
    if x not in ("env_steps", "wall_time_s"):
        raise TrainerError(f"x must be env_steps or wall_time_s, got {x!r}")
    scale, xlabel = (1e6, "env steps (M)") if x == "env_steps" else (60.0, "wall time (min)")
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(7, 4.5))
    labels = group_labels(runs)
    for threshold in thresholds:
        ax.axhline(threshold, color="0.5", linewidth=0.8, linestyle="--")
    others = 0
    for key, members in group_runs(runs).items():
        style = _style(members[0], others)
        others += style["linestyle"] == ":"
        curve = mean_curve(members, x)
        if curve is None:
            continue
        grid, mean, std = curve
        ax.plot(
            grid / scale,
            mean,
            marker="o" if grid.size == 1 else None,
            label=f"{labels[key]} ({len(members)} seed{'' if len(members) == 1 else 's'})",
            **style,
        )
        # A rate cannot leave [0, 1] even where mean ± std does.
        band = np.clip(mean - std, 0.0, 1.0), np.clip(mean + std, 0.0, 1.0)
        ax.fill_between(grid / scale, *band, color=style["color"], alpha=0.2)
    ax.set_xlabel(xlabel)
    ax.set_ylabel("success rate")
    ax.set_ylim(0.0, 1.02)
    ax.grid(alpha=0.3)
    if ax.get_legend_handles_labels()[0]:
        ax.legend(loc="best", fontsize="small")
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
    args = ["trainer", "report", *(_relative_to(Path(d), cwd) for d in run_dirs)]
    args += ["--out", _relative_to(Path(out_dir), cwd)]
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


def allowing_differences(runs: list[Run], allow_differ: Sequence[str]) -> list[Run]:
    """The runs with the settings in ``allow_differ`` dropped, so that seeds that differ in
    them are one group; a name no run's config has is refused (a typo would drop nothing)."""
    unknown = [
        name for name in allow_differ
        if name not in NOT_THE_EXPERIMENT and not any(name in r.settings for r in runs)
    ]
    if unknown:
        raise TrainerError(
            f"--allow-differ {', '.join(unknown)}: no run's config.json has such a field; name "
            "dotted config fields, e.g. run.max_minutes"
        )
    drop = set(allow_differ)
    return [
        replace(r, settings={k: v for k, v in r.settings.items() if k not in drop}) for r in runs
    ]


def comparable_endings(endings: Sequence[Mapping[str, int]]) -> list[Counter[str]]:
    """Episodes by ending (``trainer eval``'s names, spaces and all), one mapping per
    evaluation, counted alike: an evaluation from before 2026-11-30 counted never reached as
    never lifted, so where any lacks never reached, every one's is folded into never lifted."""
    fold = not all("never reached" in by for by in endings)
    out = []
    for by_ending in endings:
        by = Counter(by_ending)
        if fold and "never reached" in by:
            by["never lifted"] += by.pop("never reached")
        out.append(by)
    return out


def worst_objects_table(runs: Sequence[Run], count: int = WORST) -> str:
    """Per arm whose evaluations recorded how episodes ended: its ``count`` objects of lowest
    success (episodes pooled over the seeds), each with its episodes by ending, worst first.
    The empty string when no arm has them."""
    labels = group_labels(runs)
    blocks = []
    for key, members in group_runs(runs).items():
        ended = [r for r in members if r.endings is not None and r.per_object is not None]
        if not ended:
            continue
        names = [name for r in ended for name in r.endings]
        counted = comparable_endings([by for r in ended for by in r.endings.values()])
        totals: dict[str, Counter[str]] = {}
        for name, by in zip(names, counted, strict=True):
            totals.setdefault(name, Counter()).update(by)
        endings = list(dict.fromkeys(e for by in totals.values() for e in by))
        episodes = {name: sum(by.values()) for name, by in totals.items()}
        rate = {name: by.get("success", 0) / max(1, episodes[name])
                for name, by in totals.items()}
        worst = sorted(totals, key=lambda name: (rate[name], name))[:count]
        seeds = f"{len(ended)} seed{'s' * (len(ended) != 1)}"
        blocks += [f"**{labels[key]}** ({seeds}, {len(totals)} objects):", "",
                   "| object | episodes | " + " | ".join(endings) + " |",
                   "|---|---:|" + "---:|" * len(endings)]
        blocks += [f"| {name} | {episodes[name]} | "
                   + " | ".join(str(totals[name].get(e, 0)) for e in endings) + " |"
                   for name in worst]
        blocks.append("")
    return "\n".join(blocks)


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
    _check_eval_dir(eval_dir)
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
        f"Made by this command, run in `{_relative_to(Path.cwd(), out_dir)}` (relative to this "
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
        rel = _relative_to(r.path, out_dir)
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
