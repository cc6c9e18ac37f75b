"""geomprep.contract: the processed object's layout, its reader, and that a reader of processed
objects (the trainer) does not load the mesh stack."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import h5py
import numpy as np
import pytest

from geomprep import builtin, contract, importer, pipeline, rawstore
from geomprep.config import Config
from geomprep.errors import GeomprepError

MESH_STACK = ("trimesh", "coacd", "open3d", "geomprep.pipeline")


@pytest.mark.parametrize("module", ["geomprep.contract", "trainer.objects", "trainer.tasks"])
def test_readers_do_not_import_the_mesh_stack(module: str) -> None:
    code = textwrap.dedent(f"""
        import sys
        import {module}
        print(",".join(m for m in {MESH_STACK!r} if m in sys.modules))
    """)
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True,
        cwd=Path(__file__).parents[1],
    )
    assert done.stdout.strip() == "", f"importing {module} loaded {done.stdout.strip()}"


def test_reader_returns_what_the_stages_wrote(builtin_data: Config) -> None:
    obj = contract.read_object(builtin_data, "builtin_box")
    assert obj.h5_path == builtin_data.processed_dir / "builtin_box.h5"
    assert obj.xml_path == builtin_data.processed_dir / "builtin_box" / "builtin_box.xml"
    assert obj.xml_path.is_file()
    assert obj.mass_kg == pytest.approx(builtin.BUILDERS["builtin_box"][1])
    # A 0.16 x 0.06 x 0.21 m box: its oriented box has those edges (in some order).
    np.testing.assert_allclose(np.sort(obj.bbox_extents), [0.06, 0.16, 0.21], atol=1e-4)
    assert obj.bbox_rotation.shape == (3, 3) and obj.sq_params.shape == (11,)
    assert obj.points.shape == (contract.POINTS_READ, 3) and obj.points.dtype == np.float32
    grid = obj.sdf_grid()
    assert grid.ndim == 3 and grid.dtype == np.float32
    # The grid cube contains the box, and the box's centre (its COM, the origin) is inside it.
    lower, voxel = obj.sdf_bounds_min, obj.sdf_voxel_size
    centre = np.floor((0.0 - lower) / voxel).astype(int)
    assert grid[tuple(centre)] < 0
    assert contract.read_sdf_frame(obj.h5_path)[1] == voxel
    with h5py.File(obj.h5_path, "r") as f:
        assert set(contract.STAGE_GROUPS.values()) <= set(f)
        assert f.attrs["contract"] == contract.CONTRACT
        assert obj.mjcf_key == f[contract.GROUP_MJCF].attrs[contract.MJCF_CACHE_KEY]


def test_the_mjcf_key_is_the_mjcf_stage_key(builtin_data: Config) -> None:
    keys = pipeline.expected_keys(builtin_data, "builtin_dice")
    assert contract.read_object(builtin_data, "builtin_dice").mjcf_key == keys["mjcf"]


def test_incomplete_file_is_one_line_naming_the_rebuild(tmp_path: Path) -> None:
    dirs = contract.DataDirs(tmp_path)
    dirs.processed_dir.mkdir()
    with h5py.File(contract.processed_path(dirs, "thing"), "w") as f:
        f.create_group(contract.GROUP_BBOX)
    with pytest.raises(GeomprepError) as err:
        contract.read_object(dirs, "thing")
    message = str(err.value)
    assert "\n" not in message and "is incomplete" in message
    assert message.endswith("`geomprep build-all --objects thing`")
    with pytest.raises(GeomprepError, match="build it with `geomprep sdf`"):
        contract.read_sdf_grid(contract.processed_path(dirs, "thing"))


def test_verify_names_a_missing_file(tmp_path: Path) -> None:
    why = contract.verify_processed(contract.DataDirs(tmp_path), "thing")
    assert why == f"{tmp_path / 'processed' / 'thing.h5'} does not exist"


def test_the_contract_resolves_built_in_names_without_writing(tmp_path: Path) -> None:
    dirs = contract.DataDirs(tmp_path)
    assert contract.resolve_objects(dirs, "builtin_box,builtin_dice") == [
        "builtin_box", "builtin_dice"
    ]
    assert not dirs.raw_dir.exists()  # the contract reads; writing sources is a build step


def test_builtin_sources_are_written_only_when_missing(
    builtin_data: Config, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    real_write = builtin.write_source
    writes: list[str] = []

    def write_source(name: str, directory: Path) -> tuple[Path, float]:
        writes.append(name)
        return real_write(name, directory)

    monkeypatch.setattr(builtin, "write_source", write_source)
    assert importer.import_builtin(builtin_data.raw_dir, builtin.NAMES) == []
    assert writes == []  # all present: the mesh stack is not needed
    raw = tmp_path / "raw"
    assert importer.import_builtin(raw, ["builtin_box", "builtin_dice"]) == [
        "builtin_box", "builtin_dice"
    ]
    assert writes == ["builtin_box", "builtin_dice"]
    assert rawstore.complete_objects(raw) == ["builtin_box", "builtin_dice"]
    assert not list(raw.glob(".builtin-*"))  # the staging folder is gone
    assert importer.import_builtin(raw, ["builtin_box"]) == []


@pytest.mark.parametrize("caller", ["geomprep", "trainer"])
def test_the_callers_that_need_sources_run_the_build_step(
    caller: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """geomprep's commands (``pipeline.resolve_objects``) and the trainer
    (``objects.resolve_names``) write the built-in objects they name, as when the contract did."""
    from trainer.objects import resolve_names

    steps: list[tuple[Path, list[str]]] = []
    monkeypatch.setattr(
        importer, "import_builtin", lambda raw_dir, names: steps.append((raw_dir, list(names)))
    )
    if caller == "geomprep":
        names = pipeline.resolve_objects(Config(data_dir=tmp_path), "builtin_box,builtin_dice")
    else:
        names = resolve_names("builtin_box,builtin_dice", tmp_path)
    assert names == ["builtin_box", "builtin_dice"]
    assert steps == [(tmp_path / "raw", ["builtin_box", "builtin_dice"])]


def test_geomprep_config_is_a_data_layout() -> None:
    cfg = Config(data_dir=Path("/d"))
    assert isinstance(cfg, contract.DataDirs)
    assert (cfg.raw_dir, cfg.interim_dir, cfg.processed_dir) == (
        Path("/d/raw"), Path("/d/interim"), Path("/d/processed")
    )
