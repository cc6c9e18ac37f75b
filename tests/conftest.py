"""Shared fixtures: the YCB directory, and data directories built once per test session."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from geomprep import fetch, pipeline
from geomprep.config import Config

YCB_DIR = Path(
    os.environ.get("GEOMPREP_YCB_DIR", Path(__file__).resolve().parents[2] / "shared" / "ycb")
)
YCB_TEST_OBJECTS = ("032_knife", "062_dice", "025_mug", "029_plate")


def require_ycb() -> Path:
    if not (YCB_DIR / "032_knife" / "google_16k" / "textured.obj").is_file():
        pytest.skip(f"YCB models not found at {YCB_DIR} (set GEOMPREP_YCB_DIR)")
    return YCB_DIR


@pytest.fixture(scope="session")
def builtin_data(tmp_path_factory: pytest.TempPathFactory) -> Config:
    """A data directory with the whole built-in set built (all stages, packed)."""
    cfg = Config(data_dir=tmp_path_factory.mktemp("builtin") / "data")
    names = pipeline.resolve_objects(cfg, "builtin")
    report = pipeline.build(cfg, names, jobs=2, progress=False)
    assert not report.failed, report.failed
    return cfg


@pytest.fixture(scope="session")
def ycb_data(tmp_path_factory: pytest.TempPathFactory) -> Config:
    """A data directory with the four test YCB objects imported from YCB_DIR and built."""
    ycb = require_ycb()
    cfg = Config(data_dir=tmp_path_factory.mktemp("ycb") / "data")
    fetch.import_directory(ycb, cfg.raw_dir, YCB_TEST_OBJECTS)
    report = pipeline.build(cfg, list(YCB_TEST_OBJECTS), jobs=2, progress=False)
    assert not report.failed, report.failed
    return cfg


@pytest.fixture(params=["builtin", "ycb"])
def built(request: pytest.FixtureRequest) -> tuple[Config, list[str]]:
    """Both built data sets in turn, with their object names."""
    if request.param == "builtin":
        cfg = request.getfixturevalue("builtin_data")
        return cfg, list(pipeline.builtin.NAMES)
    return request.getfixturevalue("ycb_data"), list(YCB_TEST_OBJECTS)
