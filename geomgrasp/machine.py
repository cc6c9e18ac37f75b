"""The machine this process runs on and the code it runs, in words: run folders record them
beside their timings, because minutes and steps per second compare only between runs on one
machine, and a run resumed across sessions may have changed code."""

from __future__ import annotations

import os
import platform
import subprocess
from importlib import metadata
from pathlib import Path


def cpu_model() -> str:
    """The CPU's model name (``/proc/cpuinfo``), else what ``platform`` knows of it."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name") and ":" in line:
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine() or "unknown CPU"


def usable_cores() -> int:
    """The cores this process may run on (its affinity; all of the machine's elsewhere)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # (not on every platform)
        return os.cpu_count() or 1


def niceness() -> int:
    """This process's scheduling niceness (0 unless started with ``nice``)."""
    try:
        return os.nice(0)
    except (AttributeError, OSError):
        return 0


def code_version() -> str:
    """The commit of this checkout (12 hex digits, ``+changes`` where the packages' tracked
    files differ from it: a run's outputs under results/ do not count), or the installed
    package's version where it is not a git checkout."""
    root = Path(__file__).resolve().parents[1]
    packages = [str(root / name) for name in ("geomgrasp", "geomprep", "trainer")]
    try:
        head = subprocess.run(["git", "-C", str(root), "rev-parse", "--short=12", "HEAD"],
                              capture_output=True, text=True, timeout=10, check=True)
        status = subprocess.run(["git", "-C", str(root), "status", "--porcelain",
                                 "--untracked-files=no", "--", *packages],
                                capture_output=True, text=True, timeout=10, check=True)
    except (OSError, subprocess.SubprocessError):
        try:
            return f"geomgrasp {metadata.version('geomgrasp')}"
        except metadata.PackageNotFoundError:
            return "unknown"
    return head.stdout.strip() + ("+changes" if status.stdout.strip() else "")
