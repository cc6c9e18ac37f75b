"""A training run on disk: its folder, its resolved config, its metrics file and where its
checkpoints go (what is in a checkpoint: ``trainer.training.checkpoint``).

Torch-free, so that ``trainer report`` can read runs without importing the training stack."""

from __future__ import annotations

import csv
import dataclasses
import json
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from geomgrasp.files import atomic_path
from trainer.config import TrainConfig, config_dict, predated_fields, read_train_config
from trainer.errors import TrainerError

METRICS = (
    "iteration", "env_steps", "wall_time_s", "fps", "success_rate", "object_success_rate", "h_bar",
    "target_success_rate", "episodes", "episode_return", "episode_length", "unstable_resets",
    "loss_objective", "loss_critic", "loss_entropy", "entropy", "kl_approx", "clip_fraction",
    "action_std", "lr",
)
"""The columns of ``metrics.csv``, one row per PPO iteration."""

LAUNCH_COLUMNS = (
    "first_iteration", "started", "code", "cpu", "cores", "nice", "device", "processes",
    "sim_threads", "torch_threads",
)
"""The columns of ``launches.csv``: one row per launch of the run (start or resume), from the
iteration it trains first: when it started (UTC), the code that ran (``geomgrasp.machine.
code_version``), the CPU, the cores the process may use, its niceness, the torch device (a GPU
by name), the processes (torchrun) and each one's simulation and torch threads. A run resumed
across sessions may change machines and code: its minutes and env steps per second compare
only where they did not."""

BY_START_COLUMNS = (
    "object", "face_up_episodes", "face_up_successes", "upside_down_episodes",
    "upside_down_successes",
)
"""The columns of an evaluation's ``by_start.csv`` (``trainer eval`` writes it into the run's
evaluation folder, ``trainer report`` reads it): per object, the episodes whose target started
face up and upside down, and their successes."""

EVALUATED_ON = "Evaluated on "
"""How the last line of an evaluation's ``table.md`` starts: ``Evaluated on CPU with code
COMMIT, DATE.`` (``trainer eval`` writes it since 2026-11-30, ``trainer report`` reads it):
the same checkpoint and seed end some contact-rich episodes differently on another CPU model."""


def evaluated_on(cpu: str, code: str, when: str) -> str:
    """table.md's last line: the CPU model and code that evaluated, and when."""
    return f"{EVALUATED_ON}{cpu} with code {code}, {when}."


def read_evaluated_on(line: str) -> tuple[str, str] | None:
    """(CPU model, code) from a line ``evaluated_on`` wrote; None for any other line."""
    if not line.startswith(EVALUATED_ON) or " with code " not in line:
        return None
    cpu, rest = line.removeprefix(EVALUATED_ON).split(" with code ", 1)
    return cpu, rest.split(",", 1)[0]

GROWABLE = ("run.total_steps", "run.max_minutes")
"""The config keys a resumed run may change: it may only grow longer."""


@dataclass(frozen=True)
class RunDir:
    """A training run on disk: ``config.json`` (the resolved config), ``metrics.csv`` (one row
    per iteration), ``launches.csv`` (the code and machine of each start and resume), ``tb/``
    (TensorBoard), ``checkpoints/iter_NNNNNN.pt`` and ``last.pt``, and with ``[run]
    grasp_starts`` ``grasp_starts.pt``, with ``[run] warmup_objects`` ``warmup/``."""

    path: Path

    @property
    def config(self) -> Path:
        return self.path / "config.json"

    @property
    def metrics(self) -> Path:
        return self.path / "metrics.csv"

    @property
    def launches(self) -> Path:
        return self.path / "launches.csv"

    @property
    def tensorboard(self) -> Path:
        return self.path / "tb"

    @property
    def checkpoints(self) -> Path:
        return self.path / "checkpoints"

    @property
    def last(self) -> Path:
        return self.checkpoints / "last.pt"

    @property
    def grasp_starts(self) -> Path:
        """The states ``[run] grasp_starts`` recorded (a resume loads them, not records)."""
        return self.path / "grasp_starts.pt"

    @property
    def warmup(self) -> Path:
        """The run of ``[run] warmup_objects`` this run starts from (a run folder of its own)."""
        return self.path / "warmup"

    def has_checkpoint(self) -> bool:
        """Whether any checkpoint file (readable or not) was written here."""
        return self.checkpoints.is_dir() and any(self.checkpoints.glob("*.pt"))

    def checkpoint(self, iteration: int) -> Path:
        """The checkpoint written at the end of ``iteration``."""
        return self.checkpoints / f"iter_{iteration:06d}.pt"

    def checkpoint_iterations(self) -> list[int]:
        """The iterations that have an ``iter_NNNNNN.pt``, oldest first."""
        return sorted(int(p.stem[5:]) for p in self.checkpoints.glob("iter_*.pt"))

    # --- the config --------------------------------------------------------------------------
    def load_config(self) -> TrainConfig:
        if not self.path.is_dir():
            raise TrainerError(
                f"{self.path}: no such run directory: pass one written by trainer run"
            )
        return read_train_config(self.config)

    def write_config(self, cfg: TrainConfig) -> None:
        self.path.mkdir(parents=True, exist_ok=True)
        with atomic_path(self.config) as tmp:
            tmp.write_text(json.dumps(config_dict(cfg), indent=2))

    def config_to_resume(self, cfg: TrainConfig | None, world_size: int = 1) -> TrainConfig:
        """The config a resumed run continues with: its own config.json, or ``cfg`` if that
        differs from it only in the keys of ``GROWABLE`` (a run continues bit for bit only with
        its own config). A config.json written before a field existed is refused, naming the
        value to add (today's default may not be what it ran with); so is a launch of another
        ``world_size`` (processes) than the run's ``run.world_size``."""
        stored = self.load_config()
        if stored.run.world_size != world_size:
            n = stored.run.world_size
            how = "" if n == 1 else f"torchrun --nproc_per_node {n} $(which trainer) "
            raise TrainerError(
                f"{self.path} was trained by {n} process{'es' if n > 1 else ''}, this launch "
                f"has {world_size}: resume it with {n} ({how or ''}"
                f"{'' if how else 'trainer '}run --resume {self.path})"
            )
        if cfg is not None and cfg.run.world_size != world_size:  # (a launch records its own)
            cfg = dataclasses.replace(cfg, run=dataclasses.replace(cfg.run, world_size=world_size))
        for dotted, value in predated_fields(self.config).items():
            parent, name = dotted.rsplit(".", 1)
            raise TrainerError(
                f"{self.path} predates {dotted} (it trained with {name} = {value}, not today's "
                f"default): to resume it as it ran, add \"{name}\": {json.dumps(value)} under "
                f"{parent} in its config.json"
            )
        if cfg is None:
            return stored
        check_same_run(self, stored, cfg)
        return cfg

    # --- a fresh run -------------------------------------------------------------------------
    def holds_run(self) -> bool:
        """Whether a run (even one killed before its first checkpoint) wrote here."""
        return any(
            p.exists() for p in (self.config, self.metrics, self.checkpoints, self.warmup)
        )

    def make_room(self, overwrite: bool) -> None:
        """Prepare for a fresh run: a directory that holds a run is refused (appending to its
        metrics would mix two runs) unless ``overwrite``, which deletes that run first."""
        if not self.holds_run():
            return
        if not overwrite:
            can_resume = self.has_checkpoint() or RunDir(self.warmup).has_checkpoint()
            how = f"resume it with --resume {self.path}, or " if can_resume else ""
            raise TrainerError(
                f"{self.path} already holds a run: {how}start it afresh with --overwrite, or "
                "choose another --run-dir or --seed"
            )
        self.clear()

    def clear(self) -> None:
        """Delete what a run writes here (nothing else in the directory)."""
        for path in (self.config, self.metrics, self.launches, self.grasp_starts):
            path.unlink(missing_ok=True)
        for path in (self.checkpoints, self.tensorboard, self.path / "eval", self.warmup):
            shutil.rmtree(path, ignore_errors=True)

    # --- metrics.csv -------------------------------------------------------------------------
    def append_metrics(self, row: dict[str, Any]) -> None:
        """One iteration's row (the ``METRICS`` columns of ``row``)."""
        new = not self.metrics.is_file()
        with open(self.metrics, "a", newline="") as handle:
            writer = csv.DictWriter(handle, fieldnames=METRICS)
            if new:
                writer.writeheader()
            writer.writerow({k: row[k] for k in METRICS})

    def truncate_metrics(self, iteration: int) -> None:
        """Drop the rows a killed run wrote after its last checkpoint (``iteration``): they
        will be redone."""
        if not self.metrics.is_file():
            return
        with open(self.metrics, newline="") as handle:
            rows = [r for r in csv.DictReader(handle) if int(r["iteration"]) <= iteration]
        with atomic_path(self.metrics) as tmp, open(tmp, "w", newline="") as handle:
            writer = csv.DictWriter(handle, fieldnames=METRICS)
            writer.writeheader()
            writer.writerows(rows)


def check_same_run(run: RunDir, stored: TrainConfig, cfg: TrainConfig) -> None:
    """A resumed run continues bit for bit only with its own config; its length may grow."""
    changed = [
        k for k in changed_keys(config_dict(stored), config_dict(cfg)) if k not in GROWABLE
    ]
    if changed:
        raise TrainerError(
            f"{run.path}: a resumed run keeps its config.json, but {', '.join(changed)} differ: "
            "start a new run to change them"
        )


def changed_keys(a: dict[str, Any], b: dict[str, Any], prefix: str = "") -> list[str]:
    """The dotted keys whose values differ between the nested dicts ``a`` and ``b``."""
    changed = []
    for key in sorted(set(a) | set(b)):
        if isinstance(a.get(key), dict) and isinstance(b.get(key), dict):
            changed += changed_keys(a[key], b[key], f"{prefix}{key}.")
        elif a.get(key) != b.get(key):
            changed.append(prefix + key)
    return changed


# --- launches.csv ----------------------------------------------------------------------------
def read_launches(run: RunDir) -> list[dict[str, str]]:
    """``run``'s ``launches.csv`` rows (``LAUNCH_COLUMNS``), oldest first; none for a run
    trained before the file existed (2026-11-30) or one whose file is unreadable."""
    try:
        with open(run.launches, newline="") as handle:
            rows = list(csv.DictReader(handle))
    except (OSError, csv.Error, UnicodeDecodeError):
        return []
    if not rows or any(set(LAUNCH_COLUMNS) - set(r) for r in rows):
        return []
    return rows


def record_launch(run: RunDir, row: dict[str, Any]) -> None:
    """Append a launch of ``run`` (``row``: ``LAUNCH_COLUMNS``); the
    rows of earlier launches from its ``first_iteration`` on are dropped, as their iterations
    will be redone (a killed run resumes from its last checkpoint)."""
    first = int(row["first_iteration"])
    kept = [r for r in read_launches(run) if int(r["first_iteration"]) < first]
    with atomic_path(run.launches) as tmp, open(tmp, "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=LAUNCH_COLUMNS)
        writer.writeheader()
        writer.writerows([*kept, {k: row[k] for k in LAUNCH_COLUMNS}])
