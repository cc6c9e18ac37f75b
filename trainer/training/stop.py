"""Stopping a training run between iterations on SIGINT (Ctrl-C) or SIGTERM (``timeout``,
a job scheduler) instead of losing every iteration since its last checkpoint."""

from __future__ import annotations

import signal
import sys
import threading
from types import FrameType, TracebackType
from typing import Any

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


class StopSignals:
    """While active (a ``with`` block), SIGINT and SIGTERM only set ``received`` (the signal's
    name): the loop finishes its iteration, writes a checkpoint and leaves. A second signal
    acts as it did before the block (Ctrl-C twice: at once). On leaving the block the earlier
    handlers are back, and ``reraise`` delivers the signal to them, so a stopped run then ends
    as the signal would have ended it (click's "aborted" for Ctrl-C, termination for SIGTERM).

    Only the main thread can take signals: elsewhere this does nothing; a signal the process
    ignores (``SIG_IGN``) is left ignored.

    ``again_stops=False`` (a process of a torchrun run): later signals are swallowed too. A
    Ctrl-C reaches each worker twice, from the terminal and forwarded by torchrun, which must
    not count as "stop at once"; torchrun itself kills its workers if they have not ended 30 s
    after it forwarded a signal."""

    def __init__(self, again_stops: bool = True) -> None:
        self.received: signal.Signals | None = None
        self.again_stops = again_stops
        self._previous: dict[signal.Signals, Any] = {}

    def __enter__(self) -> StopSignals:
        if threading.current_thread() is threading.main_thread():
            for sig in STOP_SIGNALS:
                # An ignored signal stays ignored: a run started in the background by a
                # non-interactive shell (``cmd &``) must not start answering Ctrl-C.
                if signal.getsignal(sig) is not signal.SIG_IGN:
                    self._previous[sig] = signal.signal(sig, self._handle)
        return self

    def __exit__(
        self, kind: type[BaseException] | None, exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        self._restore()

    def reraise(self) -> None:
        """Deliver the received signal (if any) to the handlers from before the block."""
        if self.received is not None:
            self._restore()
            signal.raise_signal(self.received)

    def _handle(self, signum: int, frame: FrameType | None) -> None:
        if self.received is not None:  # (only without again_stops)
            return
        self.received = signal.Signals(signum)
        if not self.again_stops:
            print(f"\n{self.received.name}: stopping at the end of this iteration, with a "
                  "checkpoint", file=sys.stderr, flush=True)
            return
        self._restore()  # a second signal: as before
        print(
            f"\n{self.received.name}: stopping at the end of this iteration, with a checkpoint "
            "(send it again to stop at once)", file=sys.stderr, flush=True,
        )

    def _restore(self) -> None:
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)
        self._previous = {}
