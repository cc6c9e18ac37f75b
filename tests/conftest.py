"""Shared fixtures: the YCB directory, and data directories built once per test session."""

from __future__ import annotations

import os

# MuJoCo chooses its OpenGL backend at first import; the rendering tests need EGL (no display).
os.environ.setdefault("MUJOCO_GL", "egl")

from pathlib import Path  # noqa: E402

import pytest  # noqa: E402
import trimesh  # noqa: E402

from geomprep import importer, mesh, pipeline  # noqa: E402
from geomprep.config import Config  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def _find_ycb() -> Path:
    """$GEOMPREP_YCB_DIR, else a ``shared/ycb`` beside the checkout or inside it."""
    if "GEOMPREP_YCB_DIR" in os.environ:
        return Path(os.environ["GEOMPREP_YCB_DIR"])
    candidates = (ROOT.parent / "shared" / "ycb", ROOT / "shared" / "ycb")
    return next((c for c in candidates if c.is_dir()), candidates[0])


YCB_DIR = _find_ycb()
YCB_TEST_OBJECTS = ("032_knife", "062_dice", "025_mug", "029_plate")


def require_ycb() -> Path:
    if not (YCB_DIR / "032_knife" / "google_16k" / "textured.obj").is_file():
        pytest.skip(f"YCB models not found at {YCB_DIR} (set GEOMPREP_YCB_DIR)")
    return YCB_DIR


def ycb_mesh(name: str) -> trimesh.Trimesh:
    """A YCB object's cleaned geometry mesh in its object frame (origin at the COM), as the
    mesh stage makes it; skips the test if the YCB models are absent."""
    source = mesh.load_source(require_ycb() / name / "google_16k" / "textured.obj")
    norm = mesh.normalize_mesh(source, Config().mesh, None, 500.0, label=name)
    return trimesh.Trimesh(norm.vertices, norm.faces, process=False)


@pytest.fixture(scope="session")
def builtin_data(tmp_path_factory: pytest.TempPathFactory) -> Config:
    """A data directory with the whole built-in set built (all stages, packed)."""
    cfg = Config(data_dir=tmp_path_factory.mktemp("builtin") / "data")
    names = pipeline.resolve_objects(cfg, "builtin")
    report = pipeline.build(cfg, names, jobs=2, progress=False)
    assert not report.failed, report.failed
    return cfg


def build_ycb(tmp_path_factory: pytest.TempPathFactory, label: str, names: tuple[str, ...]) -> Config:  # noqa: E501
    """A fresh data directory with ``names`` imported from YCB_DIR and built (skips the test
    if the YCB models are absent)."""
    ycb = require_ycb()
    cfg = Config(data_dir=tmp_path_factory.mktemp(label) / "data")
    importer.import_directory(ycb, cfg.raw_dir, names)
    report = pipeline.build(cfg, list(names), jobs=2, progress=False)
    assert not report.failed, report.failed
    return cfg


@pytest.fixture(scope="session")
def ycb_data(tmp_path_factory: pytest.TempPathFactory) -> Config:
    """A data directory with the four test YCB objects imported from YCB_DIR and built."""
    return build_ycb(tmp_path_factory, "ycb", YCB_TEST_OBJECTS)


@pytest.fixture(params=["builtin", "ycb"])
def built(request: pytest.FixtureRequest) -> tuple[Config, list[str]]:
    """Both built data sets in turn, with their object names."""
    if request.param == "builtin":
        cfg = request.getfixturevalue("builtin_data")
        return cfg, list(pipeline.builtin.NAMES)
    return request.getfixturevalue("ycb_data"), list(YCB_TEST_OBJECTS)
