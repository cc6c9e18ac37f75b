"""dvc.yaml describes the same pipeline: `dvc repro` builds the built-in objects."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import h5py
import pytest

ROOT = Path(__file__).resolve().parents[1]


def _dvc(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    dvc = shutil.which("dvc")
    return subprocess.run(
        [dvc, *args], cwd=cwd, capture_output=True, text=True, timeout=900, check=False
    )


@pytest.mark.skipif(
    shutil.which("dvc") is None, reason="DVC not installed (pip install -e '.[dvc]')"
)
@pytest.mark.slow
def test_dvc_repro_builds_builtin_objects(tmp_path):
    project = tmp_path / "project"
    project.mkdir()
    shutil.copy(ROOT / "dvc.yaml", project / "dvc.yaml")
    # One object: every stage of dvc.yaml runs once (a second object would only repeat them).
    (project / "params.yaml").write_text("objects:\n  - builtin_knife\n")
    # The stages are geomprep's commands, so they read the project's geomprep.toml: a coarse
    # SDF grid and a short superquadric fit keep the build quick (the stages, not the grid, are
    # under test here; tests/test_sdf.py and tests/test_superquadric.py test those).
    (project / "geomprep.toml").write_text(
        "[sdf]\nresolution = 40\n[sq]\nn_points = 300\nmax_iters = 8\nmax_switches = 1\n"
        "surface_samples = 50\n"
    )
    assert _dvc("init", "--no-scm", cwd=project).returncode == 0

    first = _dvc("repro", cwd=project)
    assert first.returncode == 0, first.stdout + first.stderr
    with h5py.File(project / "data" / "processed" / "builtin_knife.h5", "r") as f:
        assert f["sdf/grid"].shape == (40, 40, 40)  # geomprep.toml's
        assert f["pointcloud/pc512"].shape == (512, 3)
    assert (project / "data" / "processed" / "builtin_knife" / "builtin_knife.xml").is_file()

    again = _dvc("repro", cwd=project)
    assert again.returncode == 0, again.stderr
    assert "didn't change" in again.stdout or "up to date" in again.stdout
    status = _dvc("status", cwd=project)
    assert "up to date" in status.stdout, status.stdout
