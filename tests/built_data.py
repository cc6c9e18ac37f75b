"""Private copies of the session's built data, for tests that damage or change it."""

from __future__ import annotations

import shutil
from collections.abc import Sequence
from pathlib import Path

from geomprep.config import Config

BOX_AND_DICE = ("builtin_box", "builtin_dice")


def copy_built(built: Config, data_dir: Path, names: Sequence[str] = BOX_AND_DICE) -> Config:
    """Copy ``names`` (raw, interim with build records, processed) out of ``built`` into
    ``data_dir``. copytree keeps mtimes, so the build records still take their fast path."""
    cfg = Config(data_dir=data_dir)
    for name in names:
        for sub in ("raw", "interim", "processed"):
            src = built.data_dir / sub / name
            if src.exists():
                shutil.copytree(src, cfg.data_dir / sub / name)
        shutil.copy2(built.processed_dir / f"{name}.h5", cfg.processed_dir / f"{name}.h5")
    return cfg
