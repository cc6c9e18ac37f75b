"""Caching, resumption after a kill, bad input, and the command line."""

from __future__ import annotations

import dataclasses
import signal
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np
import pytest
import trimesh
from click.testing import CliRunner

from geomprep import cache, cli, importer, mesh, pipeline, rawstore, store
from geomprep.config import Config, load_config
from geomprep.errors import GeomprepError
from tests.built_data import copy_built
from tests.conftest import require_ycb


@pytest.fixture()
def box_data(tmp_path: Path, builtin_data: Config) -> Config:
    """A private copy of the built-in data with only builtin_box and builtin_dice (fast to redo)."""
    return copy_built(builtin_data, tmp_path / "data")


def _mtimes(cfg: Config, name: str) -> dict[str, float]:
    return {
        s: pipeline.stage_path(cfg, name, s).stat().st_mtime_ns for s in (*pipeline.STAGES, "pack")
    }


def test_rerun_with_nothing_changed_computes_nothing(box_data, monkeypatch):
    before = _mtimes(box_data, "builtin_box")
    hashed: list[str] = []
    real_sha256 = cache.file_sha256
    monkeypatch.setattr(cache, "file_sha256", lambda p: hashed.append(str(p)) or real_sha256(p))
    report = pipeline.build(box_data, ["builtin_box", "builtin_dice"], jobs=2, progress=False)
    assert report.seconds == {} and not report.failed
    assert len(report.skipped) == 2 * 8
    # Cheap: the records' size + mtime vouch for every file, nothing is read or hashed again.
    assert hashed == []
    assert _mtimes(box_data, "builtin_box") == before


def test_changed_parameter_reruns_only_that_stage_and_pack(box_data):
    before = _mtimes(box_data, "builtin_box")
    cfg = dataclasses.replace(box_data, pc=dataclasses.replace(box_data.pc, seed=7))
    report = pipeline.build(cfg, ["builtin_box"], jobs=1, progress=False)
    assert set(report.seconds) == {("builtin_box", "pc"), ("builtin_box", "pack")}
    after = _mtimes(cfg, "builtin_box")
    assert [s for s in after if after[s] != before[s]] == ["pc", "pack"]


def test_changed_source_reruns_everything(box_data):
    raw = box_data.raw_dir / "builtin_dice"
    source = rawstore.read_source(box_data.raw_dir, "builtin_dice")
    bigger = trimesh.creation.box(extents=(0.02, 0.02, 0.02))
    bigger.export(raw / source["mesh"])
    assert set(pipeline.stage_status(box_data, "builtin_dice").values()) == {"stale"}
    report = pipeline.build(box_data, ["builtin_dice"], jobs=1, progress=False)
    assert len(report.seconds) == 8
    box, _ = store.read_group(box_data.processed_dir / "builtin_dice.h5", "bbox")
    np.testing.assert_allclose(box["extents"], 0.02, atol=1e-4)


def test_failed_stage_leaves_no_complete_looking_file(box_data, monkeypatch):
    path = pipeline.stage_path(box_data, "builtin_box", "sdf")
    path.unlink()

    def crash(*args, **kwargs):
        raise KeyboardInterrupt  # like Ctrl-C in the middle of the stage

    monkeypatch.setattr(pipeline.sdf, "compute_sdf", crash)
    with pytest.raises(KeyboardInterrupt):
        pipeline.build(box_data, ["builtin_box"], stages=["sdf"], jobs=1, progress=False)
    assert not path.exists()
    # No leftovers; the record of the deleted output stays, trusted for nothing without it.
    assert [p.name for p in path.parent.iterdir() if "sdf" in p.name] == ["sdf.record.json"]
    assert pipeline.stage_status(box_data, "builtin_box")["sdf"] == "missing"


def test_killed_build_resumes(box_data):
    """SIGKILL in the middle of the SDF stage: no valid-looking output; a rerun completes it."""
    for name in ("builtin_box", "builtin_dice"):
        pipeline.stage_path(box_data, name, "sdf").unlink()
    cmd = [sys.executable, "-m", "geomprep.cli", "--data-dir", str(box_data.data_dir)]
    proc = subprocess.Popen([*cmd, "build-all", "--objects", "builtin_box,builtin_dice", "-j", "1"])
    deadline = time.time() + 60
    tmp_seen = False
    while time.time() < deadline and proc.poll() is None:
        tmps = list((box_data.interim_dir / "builtin_box").glob(".sdf.h5.tmp-*"))
        tmps += list((box_data.interim_dir / "builtin_dice").glob(".sdf.h5.tmp-*"))
        if tmps:
            tmp_seen = True
            break
        time.sleep(0.01)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    # Whatever was being written is not a stage output: the status says so.
    statuses = [pipeline.stage_status(box_data, n)["sdf"] for n in ("builtin_box", "builtin_dice")]
    assert "missing" in statuses
    for name in ("builtin_box", "builtin_dice"):
        path = pipeline.stage_path(box_data, name, "sdf")
        if path.exists():  # finished before the kill: then it is complete and valid
            with h5py.File(path, "r") as f:
                assert f["sdf/grid"].shape == (200, 200, 200)
    report = pipeline.build(box_data, ["builtin_box", "builtin_dice"], jobs=1, progress=False)
    assert not report.failed
    assert ("builtin_box", "mesh") in report.skipped  # resumed, not restarted
    assert {s for _, s in report.seconds} <= {"sdf", "pack"}
    assert all(v == "done" for v in pipeline.stage_status(box_data, "builtin_box").values())
    assert tmp_seen, "the build finished before it could be killed mid-write"
    assert not list(box_data.interim_dir.glob("*/.sdf.h5.tmp-*"))  # leftovers cleaned on rerun


# ---- bad input: one clear line each ----------------------------------------------------------


def _one_line_error(exc_info: pytest.ExceptionInfo) -> str:
    message = str(exc_info.value)
    assert "\n" not in message and len(message) < 300
    return message


def test_missing_mesh_file(tmp_path):
    with pytest.raises(GeomprepError) as exc:
        mesh.load_source(tmp_path / "nothing.obj")
    assert "not found" in _one_line_error(exc)


def test_empty_mesh(tmp_path):
    path = tmp_path / "empty.obj"
    path.write_text("# no geometry\n")
    with pytest.raises(GeomprepError) as exc:
        mesh.load_source(path)
    assert "no triangles" in _one_line_error(exc)


def test_nan_vertices(tmp_path):
    box = trimesh.creation.box()
    vertices = box.vertices.copy()
    vertices[3] = np.nan
    broken = trimesh.Trimesh(vertices, box.faces, process=False)
    with pytest.raises(GeomprepError) as exc:
        mesh.normalize_mesh(broken, Config().mesh, 0.1, None, "object 'x'")
    assert "NaN" in _one_line_error(exc)


def test_millimetre_mesh(tmp_path):
    """A YCB mesh exported in millimetres is caught and the fix is named."""
    ycb = require_ycb()
    src = mesh.load_source(ycb / "062_dice" / "google_16k" / "textured.obj")
    src.apply_scale(1000.0)
    with pytest.raises(GeomprepError) as exc:
        mesh.normalize_mesh(src, Config().mesh, 0.005, None, "object '062_dice'")
    message = _one_line_error(exc)
    assert "millimetres" in message and "metres" in message


def test_unknown_object_name(tmp_path):
    cfg = Config(data_dir=tmp_path / "data")
    with pytest.raises(GeomprepError) as exc:
        pipeline.resolve_objects(cfg, "032_knfe")
    assert "geomprep list" in _one_line_error(exc)
    with pytest.raises(GeomprepError) as exc:
        pipeline.resolve_objects(cfg, "032_knife")  # real YCB name, not imported yet
    assert "geomprep fetch" in _one_line_error(exc)


def test_broken_object_fails_alone(tmp_path):
    """A broken mesh fails its object with a one-line error; the other objects still build."""
    src = tmp_path / "meshes"
    src.mkdir()
    trimesh.creation.box(extents=(0.05, 0.05, 0.05)).export(src / "good_box.stl")
    (src / "bad.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")  # 1 m triangle, flat
    cfg = Config(data_dir=tmp_path / "data")
    importer.import_directory(src, cfg.raw_dir)
    report = pipeline.build(cfg, ["good_box", "bad"], stages=["decompose"], jobs=1, progress=False)
    assert set(report.failed) == {"bad"} and "\n" not in report.failed["bad"]
    assert pipeline.stage_path(cfg, "good_box", "decompose").is_file()


def test_config_file_overrides_and_rejects_unknown_keys(tmp_path):
    good = tmp_path / "good.toml"
    good.write_text('data_dir = "elsewhere"\n[sdf]\nresolution = 64\n[pc]\nsizes = [16, 64]\n')
    cfg = load_config(good)
    assert (
        cfg.sdf.resolution == 64 and cfg.pc.sizes == (16, 64) and cfg.data_dir == Path("elsewhere")
    )
    bad = tmp_path / "bad.toml"
    bad.write_text("[sdf]\nresolutoin = 64\n")
    with pytest.raises(GeomprepError) as exc:
        load_config(bad)
    assert "resolutoin" in _one_line_error(exc)


# ---- the command line ------------------------------------------------------------------------


def _invoke(args: list[str]) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "geomprep.cli", *args], capture_output=True, text=True, timeout=600
    )


def test_cli_list_show_and_errors(box_data, tmp_path):
    data = ["--data-dir", str(box_data.data_dir)]
    listed = _invoke([*data, "list"])
    assert listed.returncode == 0, listed.stderr
    box_line = next(line for line in listed.stdout.splitlines() if line.startswith("builtin_box"))
    assert box_line.split()[1:] == ["done"] * 8
    assert any(
        line.startswith("builtin_mug") and "-" in line for line in listed.stdout.splitlines()
    )

    out = tmp_path / "box.png"
    shown = _invoke([*data, "show", "builtin_box", "--out", str(out)])
    assert shown.returncode == 0, shown.stderr
    assert "hulls" in shown.stdout and "superquad" in shown.stdout
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and out.stat().st_size > 20_000

    unknown = _invoke([*data, "sdf", "no_such_object"])
    assert unknown.returncode == 1
    assert unknown.stderr.strip().count("\n") == 0 and "geomprep list" in unknown.stderr


def test_cli_single_stage_and_cached_rerun(box_data):
    data = ["--data-dir", str(box_data.data_dir)]
    pipeline.stage_path(box_data, "builtin_dice", "bbox").unlink()
    pipeline.stage_path(box_data, "builtin_dice", "pack").unlink()
    first = _invoke([*data, "bbox", "builtin_dice"])
    assert first.returncode == 0, first.stderr
    assert "2 stages computed" in first.stdout  # bbox, then pack since all else was there
    assert pipeline.stage_path(box_data, "builtin_dice", "pack").is_file()
    again = _invoke([*data, "build-all", "--objects", "builtin_dice", "--no-progress"])
    assert again.returncode == 0 and "0 stages computed, 8 cached" in again.stdout


def test_cli_help_explains_every_command():
    runner = CliRunner()
    result = runner.invoke(cli.cli, ["--help"])
    assert result.exit_code == 0
    for command in ("fetch", "list", "build-all", "show", *pipeline.STAGES):
        assert command in result.output
    assert "cache" in result.output.lower()
