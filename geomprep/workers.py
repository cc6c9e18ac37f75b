"""Worker processes of a parallel build: they die with the build and leave Ctrl-C to it.

``pipeline`` runs stages on a ``ProcessPoolExecutor`` (spawn). Without care, ``kill -9`` of the
build leaves its workers computing for nobody (hundreds of MB each) and then idle forever, and a
Ctrl-C in the terminal reaches every worker of the process group, which print tracebacks.

- ``init`` is the pool's initializer: it ignores SIGINT (the parent handles Ctrl-C and stops
  the pool) and makes the worker die with its parent (Linux: ``PR_SET_PDEATHSIG``; everywhere:
  a thread that watches the parent pid).
- ``sigint_blocked`` wraps ``submit`` (which spawns workers): a worker starts with SIGINT
  blocked, so a Ctrl-C during its start-up stays pending until ``init`` discards it; and the
  build's own KeyboardInterrupt waits until ``submit`` has returned (raised in the middle of a
  spawn, it would leave the new worker reading a half-sent start-up message: a traceback).
- ``stop`` kills the workers at once when the build is interrupted.

This module imports only the standard library: the pool unpickles the initializer before
anything else, so a worker is protected after milliseconds, not after the stages' imports.
"""

from __future__ import annotations

import ctypes
import os
import signal
import sys
import threading
import time
from collections.abc import Iterator
from concurrent.futures import ProcessPoolExecutor
from contextlib import contextmanager

_PR_SET_PDEATHSIG = 1  # from <linux/prctl.h>


@contextmanager
def sigint_blocked() -> Iterator[None]:
    """Hold Ctrl-C off for the block; it takes effect when the block ends.

    SIGINT is blocked in this thread, so a process spawned meanwhile inherits the mask and a
    Ctrl-C to the terminal's process group while it is still starting stays pending instead of
    printing a KeyboardInterrupt traceback. The mask alone does not shield this thread: the
    kernel hands the signal to another thread, and Python raises KeyboardInterrupt here at the
    next bytecode. So in the main thread, Python's SIGINT handler is also replaced for the
    block by one that only notes the signal; the old handler runs once the block is over."""
    noted: list[int] = []
    handler = None
    if threading.current_thread() is threading.main_thread():
        handler = signal.signal(signal.SIGINT, lambda signum, frame: noted.append(signum))
    mask = None
    if hasattr(signal, "pthread_sigmask"):  # Windows: no signal masks
        mask = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        if mask is not None:
            signal.pthread_sigmask(signal.SIG_SETMASK, mask)
        if handler is not None:
            signal.signal(signal.SIGINT, handler)
            if noted and callable(handler):
                handler(signal.SIGINT, None)  # Python's default: raise KeyboardInterrupt
            elif noted and handler == signal.SIG_DFL:
                signal.raise_signal(signal.SIGINT)


def init(parent_pid: int) -> None:
    """Pool initializer: ignore Ctrl-C, die with the parent (``parent_pid``)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if hasattr(signal, "pthread_sigmask"):
        # Ignored first, then unblocked: a Ctrl-C pending since the spawn is discarded.
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    if sys.platform.startswith("linux"):
        # The kernel sends SIGKILL when the parent dies, even while this process is in C code
        # that holds the GIL (where the watcher thread below could not run).
        try:
            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(_PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)
        except (OSError, AttributeError):
            pass  # the watcher still covers it
    if os.getppid() != parent_pid:  # the parent died before the prctl took effect
        os._exit(1)
    threading.Thread(target=_watch_parent, args=(parent_pid,), daemon=True).start()


def _watch_parent(parent_pid: int, interval_s: float = 1.0) -> None:
    # An orphan is re-parented (to init or a subreaper): its parent pid changes.
    while os.getppid() == parent_pid:
        time.sleep(interval_s)
    os._exit(1)


def stop(pool: ProcessPoolExecutor) -> None:
    """Kill the pool's workers now: ``shutdown`` alone would wait for their running stages
    (tens of seconds). Their half-written outputs are temporary files, never taken for done."""
    # The executor has no public handle on its processes; _processes exists since Python 3.2.
    processes = list(getattr(pool, "_processes", {}).values())
    pool.shutdown(wait=False, cancel_futures=True)
    for process in processes:
        process.terminate()
    for process in processes:
        process.join(timeout=10)
