"""A training run directory, loaded for the report (``Run``, ``load_run``), and the numbers read
off one run: steps and minutes to a success rate, its training and evaluated success."""

from __future__ import annotations

import csv
import json
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from trainer.config import ABSENT_MEANS
from trainer.errors import TrainerError
from trainer.labels import task_label, task_name, view_name
from trainer.report.paper import PAPER_ORDER
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


def load_run(path: str | Path, eval_dir: str = "eval") -> Run:
    """Read a run directory, its evaluation from the folder ``eval_dir`` in it (``trainer eval
    --out``); raise TrainerError naming the file and the fix if it is unusable."""
    path = Path(path)
    if not path.is_dir():
        raise TrainerError(
            f"{path}: not a directory; pass a run directory written by trainer run"
        )
    check_eval_dir(eval_dir)
    run = RunDir(path)
    config = _read_config(run.config)
    env_steps, wall_time_s, success_rate, h_bar, target_rate = _read_metrics(run.metrics)
    per_object_path = path / eval_dir / "per_object.csv"
    per_object = read_per_object(per_object_path) if per_object_path.is_file() else None
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


def check_eval_dir(eval_dir: str) -> None:
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


def read_per_object(path: Path) -> dict[str, tuple[int, int]]:
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


def relative_to(path: Path, base: Path) -> str:
    """``path`` relative to the directory ``base`` (with ``..`` as needed), '/'-separated.

    The report names runs this way so that it holds no machine-specific absolute path and its
    links still work when the report and the runs are moved or shared together.
    """
    return Path(os.path.relpath(Path(path).resolve(), Path(base).resolve())).as_posix()


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
