"""What a training run shows and logs each iteration: a row of ``metrics.csv``, the same
scalars in TensorBoard (``tb/``) and a progress bar on stderr."""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any

from torch.utils.tensorboard import SummaryWriter
from tqdm import tqdm

from trainer.training.run_dir import RunDir


class RunClock:
    """Training time (s) that continues a resumed run's ``wall_time_s``, and env steps per
    second since the previous ``lap``."""

    def __init__(self, wall_time_s: float, steps: int) -> None:
        self.start = time.perf_counter() - wall_time_s
        self.last_time, self.last_steps = time.perf_counter(), steps

    def lap(self, steps: int) -> tuple[float, float]:
        """(training time so far (s), env steps/s since the previous lap), at ``steps`` env
        steps done."""
        now = time.perf_counter()
        fps = (steps - self.last_steps) / max(now - self.last_time, 1e-9)
        self.last_time, self.last_steps = now, steps
        return now - self.start, fps


class ProgressLog:
    """The per-iteration output of a run in ``run``: ``log`` appends a ``metrics.csv`` row and
    writes its scalars (and, with a per-object curriculum, each object's lift target as
    ``h_bar/<name>``) to TensorBoard, and moves the bar (``progress``: shown) by an iteration's
    env steps. A resumed run (``resume``) drops the TensorBoard events after its checkpoint's
    ``iteration``: they will be redone."""

    def __init__(
        self, run: RunDir, total_steps: int, iteration: int, iteration_steps: int, resume: bool,
        progress: bool,
    ) -> None:
        self.run = run
        self.writer = SummaryWriter(
            str(run.tensorboard), purge_step=iteration + 1 if resume else None
        )
        self.bar = tqdm(
            total=total_steps, initial=iteration * iteration_steps, unit="step",
            unit_scale=True, disable=not progress, dynamic_ncols=True,
        )
        self.iteration_steps = iteration_steps

    def log(
        self, row: dict[str, Any], postfix: dict[str, Any],
        object_h_bars: Sequence[tuple[str, float]] = (),
    ) -> None:
        """``row``: the ``METRICS`` of one iteration (and any more scalars for TensorBoard);
        ``postfix``: what the bar shows after the counts; ``object_h_bars``: (object name,
        lift target (m)) pairs."""
        iteration = row["iteration"]
        self.run.append_metrics(row)
        for key, value in row.items():
            if key != "iteration":
                self.writer.add_scalar(key, value, iteration)
        for name, value in object_h_bars:
            self.writer.add_scalar(f"h_bar/{name}", value, iteration)
        self.bar.update(self.iteration_steps)
        self.bar.set_postfix(postfix)

    def write(self, message: str) -> None:
        """A line above the bar."""
        self.bar.write(message)

    def close(self) -> None:
        self.bar.close()
        self.writer.close()


class NoLog:
    """``ProgressLog``'s interface doing nothing: the processes of a distributed run other than
    rank 0, which alone writes the run's files and shows its progress."""

    def log(
        self, row: dict[str, Any], postfix: dict[str, Any],
        object_h_bars: Sequence[tuple[str, float]] = (),
    ) -> None:
        pass

    def write(self, message: str) -> None:
        pass

    def close(self) -> None:
        pass
