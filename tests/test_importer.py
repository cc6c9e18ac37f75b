"""Tests for geomprep.importer: importing a local directory (YCB layout or plain mesh files)."""

from __future__ import annotations

import hashlib
import json
import sys
from pathlib import Path

import pytest
import trimesh

from geomprep import cli, importer
from geomprep.errors import GeomprepError
from geomprep.importer import import_directory
from geomprep.masses import read_masses
from geomprep.rawstore import complete_objects, read_source
from tests.conftest import YCB_DIR
from tests.raw_samples import MTL_TEXT, assert_absent, box_obj, png_bytes

KNIFE = "032_knife"
DICE = "062_dice"

needs_ycb = pytest.mark.skipif(not YCB_DIR.is_dir(), reason=f"no YCB copy at {YCB_DIR}")


@needs_ycb
def test_import_ycb_dir_with_masses(tmp_path: Path) -> None:
    raw = tmp_path / "raw"
    assert import_directory(YCB_DIR, raw, [DICE, KNIFE]) == [KNIFE, DICE]

    assert complete_objects(raw) == [KNIFE, DICE]
    masses = read_masses(YCB_DIR / "masses.csv")
    for name in (KNIFE, DICE):
        src = read_source(raw, name)
        assert src["mesh"] == "google_16k/textured.obj"
        assert src["mass_kg"] == masses[name] and src["density_kg_m3"] is None
        assert src["origin"] == f"dir: {YCB_DIR.resolve()}"
        copied = raw / name / "google_16k"
        assert sorted(p.name for p in copied.iterdir()) == sorted(
            p.name for p in (YCB_DIR / name / "google_16k").iterdir()
        )
        assert (
            src["mesh_sha256"] == hashlib.sha256((copied / "textured.obj").read_bytes()).hexdigest()
        )
    assert read_source(raw, KNIFE)["mass_kg"] == 0.031
    mesh = trimesh.load(raw / DICE / "google_16k" / "textured.obj", force="mesh")
    assert len(mesh.faces) > 1000


@needs_ycb
def test_import_skips_complete_unless_forced(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    raw = tmp_path / "raw"
    import_directory(YCB_DIR, raw, [DICE])
    copies: list[Path] = []
    real_copy = importer._copy_file
    monkeypatch.setattr(importer, "_copy_file", lambda s, d: (copies.append(s), real_copy(s, d)))

    assert import_directory(YCB_DIR, raw, [DICE]) == [DICE]
    assert copies == []
    assert import_directory(YCB_DIR, raw, [DICE], force=True, density_kg_m3=900.0) == [DICE]
    assert len(copies) == 3
    assert complete_objects(raw) == [DICE]
    assert not list(raw.glob(".*"))


def _write_plain_meshes(src: Path) -> None:
    """box.stl, ball.ply and a textured cube.obj (with its mtl and texture) in ``src``."""
    src.mkdir(parents=True, exist_ok=True)
    trimesh.creation.box(extents=(0.1, 0.2, 0.3)).export(src / "box.stl")
    trimesh.creation.icosphere(subdivisions=1, radius=0.05).export(src / "ball.ply")
    obj = trimesh.creation.box(extents=(0.05, 0.05, 0.05)).export(file_type="obj")
    (src / "cube.obj").write_text("mtllib mats/cube.mtl\nusemtl red\n" + obj)
    (src / "mats").mkdir()
    (src / "mats" / "cube.mtl").write_text("newmtl red\nmap_Kd -s 1 1 1 ../tex/red.png\n")
    (src / "tex").mkdir()
    (src / "tex" / "red.png").write_bytes(png_bytes())
    (src / "unrelated.png").write_bytes(png_bytes())
    (src / "notes.txt").write_text("not a mesh")


def test_import_plain_files_with_density(tmp_path: Path) -> None:
    src, raw = tmp_path / "meshes", tmp_path / "raw"
    _write_plain_meshes(src)

    assert import_directory(src, raw, density_kg_m3=1000.0) == ["ball", "box", "cube"]

    for name, ext in (("ball", "ply"), ("box", "stl"), ("cube", "obj")):
        rec = read_source(raw, name)
        assert rec["mesh"] == f"{name}.{ext}"
        assert rec["mass_kg"] is None and rec["density_kg_m3"] == 1000.0
        mesh = trimesh.load(raw / name / rec["mesh"], force="mesh")
        assert mesh.is_watertight
    assert trimesh.load(raw / "box" / "box.stl").volume == pytest.approx(0.006)
    # The OBJ keeps its material and texture at the paths its mtllib/map_Kd lines name.
    assert (raw / "cube" / "mats" / "cube.mtl").is_file()
    assert (raw / "cube" / "tex" / "red.png").is_file()
    assert not (raw / "cube" / "unrelated.png").exists()


def test_import_mixed_layout_with_src_masses(tmp_path: Path) -> None:
    src, raw = tmp_path / "src", tmp_path / "raw"
    _write_plain_meshes(src)
    ycb = src / "my_can" / "google_16k"
    ycb.mkdir(parents=True)
    (ycb / "textured.obj").write_text(box_obj())
    (ycb / "textured.mtl").write_text(MTL_TEXT)
    (ycb / "texture_map.png").write_bytes(png_bytes())
    (src / "masses.csv").write_text("object,mass_kg\nmy_can,0.35\nbox,0.2\n")

    assert import_directory(src, raw, ["my_can", "box", "ball"]) == ["ball", "box", "my_can"]

    assert read_source(raw, "my_can")["mass_kg"] == 0.35
    assert read_source(raw, "my_can")["mesh"] == "google_16k/textured.obj"
    assert read_source(raw, "box")["mass_kg"] == 0.2
    assert read_source(raw, "ball")["density_kg_m3"] == 500.0  # not in masses.csv: density
    assert "cube" not in complete_objects(raw)

    # An explicit masses file wins over src/masses.csv.
    other = tmp_path / "other.csv"
    other.write_text("object,mass_kg\nbox,0.9\n")
    import_directory(src, raw, ["box"], masses_csv=other, force=True)
    assert read_source(raw, "box")["mass_kg"] == 0.9


def test_import_unknown_name(tmp_path: Path) -> None:
    src = tmp_path / "src"
    _write_plain_meshes(src)
    with pytest.raises(GeomprepError, match=r"'?bxo'? not found") as err:
        import_directory(src, tmp_path / "raw", ["bxo"])
    assert "NAME/google_16k/textured.obj" in str(err.value)
    assert complete_objects(tmp_path / "raw") == []


def test_import_empty_directory(tmp_path: Path) -> None:
    (tmp_path / "empty").mkdir()
    (tmp_path / "empty" / "readme.txt").write_text("nothing here")
    with pytest.raises(GeomprepError, match=r"no objects found.*expected"):
        import_directory(tmp_path / "empty", tmp_path / "raw")


def test_import_invalid_file_name(tmp_path: Path) -> None:
    src = tmp_path / "src"
    src.mkdir()
    trimesh.creation.box().export(src / "my box.stl")
    with pytest.raises(GeomprepError, match=r"my box.stl: its object name must use only") as err:
        import_directory(src, tmp_path / "raw")
    assert str(err.value).endswith("rename the file")


def test_import_bad_density(tmp_path: Path) -> None:
    src = tmp_path / "src"
    _write_plain_meshes(src)
    with pytest.raises(GeomprepError, match="density"):
        import_directory(src, tmp_path / "raw", density_kg_m3=0.0)


def test_import_crash_midway_then_rerun(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    src, raw = tmp_path / "src", tmp_path / "raw"
    _write_plain_meshes(src)
    real_copy = importer._copy_file
    calls = {"n": 0}

    def flaky_copy(a: Path, b: Path) -> None:
        calls["n"] += 1
        if calls["n"] == 2:  # the cube's mtl, after its obj was copied
            raise OSError(28, "No space left on device")
        real_copy(a, b)

    monkeypatch.setattr(importer, "_copy_file", flaky_copy)
    with pytest.raises(GeomprepError, match="No space left") as err:
        import_directory(src, raw, ["cube"])
    assert "\n" not in str(err.value)
    assert_absent(raw, "cube")

    monkeypatch.setattr(importer, "_copy_file", real_copy)
    assert import_directory(src, raw, ["cube"]) == ["cube"]
    assert complete_objects(raw) == ["cube"]


def test_import_after_hard_crash_leftovers(tmp_path: Path) -> None:
    """A killed process leaves a half object dir and a staging dir: the rerun cleans both."""
    src, raw = tmp_path / "src", tmp_path / "raw"
    _write_plain_meshes(src)
    (raw / "box").mkdir(parents=True)
    (raw / "box" / "box.stl").write_bytes(b"half")
    dead_pid = 2**22 + 12345  # above Linux's pid_max default: no such process
    stage = raw / f".box.tmp-{dead_pid}"
    stage.mkdir()
    (stage / "source.json").write_text(json.dumps({"name": "box"}))
    assert complete_objects(raw) == []

    assert import_directory(src, raw, ["box"]) == ["box"]

    assert complete_objects(raw) == ["box"]
    assert (raw / "box" / "box.stl").read_bytes() == (src / "box.stl").read_bytes()
    assert not stage.exists()


# --------------------------------------------------------------------------------------------
# Bad input a user would give: one line naming the fix, nothing imported
# --------------------------------------------------------------------------------------------


def _import_error(src: Path, raw: Path, names: list[str] | None = None) -> str:
    """The one-line message import_directory raises; asserts nothing was imported."""
    with pytest.raises(GeomprepError) as err:
        import_directory(src, raw, names)
    message = str(err.value)
    assert "\n" not in message
    assert complete_objects(raw) == []
    return message


def _ycb_object(src: Path, name: str, variant: str = "google_16k", obj: str | None = None) -> None:
    """A YCB-layout folder ``src/name/variant/`` with a textured box."""
    folder = src / name / variant
    folder.mkdir(parents=True)
    (folder / "textured.obj").write_text(box_obj() if obj is None else obj)
    (folder / "textured.mtl").write_text(MTL_TEXT)
    (folder / "texture_map.png").write_bytes(png_bytes())


@pytest.mark.parametrize("reserved", ["ycb", "all", "builtin"])
def test_import_refuses_reserved_names(tmp_path: Path, reserved: str) -> None:
    """An object named like an object set could never be built on its own: refuse it."""
    src, raw = tmp_path / "src", tmp_path / "raw"
    _write_plain_meshes(src)
    trimesh.creation.box().export(src / f"{reserved}.stl")

    message = _import_error(src, raw)
    assert f"{src / reserved}.stl: its object name is reserved for the object set" in message
    assert message.endswith("rename the file")
    message = _import_error(src, raw, [reserved])
    assert f"invalid object name '{reserved}': it is reserved" in message
    assert "rename the file or folder" in message
    # The other objects are still importable by name.
    assert import_directory(src, raw, ["box"]) == ["box"]


def test_import_refuses_built_in_object_names(tmp_path: Path) -> None:
    """A file named builtin_box.stl would silently replace the built-in box in every build."""
    src, raw = tmp_path / "src", tmp_path / "raw"
    _write_plain_meshes(src)
    trimesh.creation.box().export(src / "builtin_box.stl")

    message = _import_error(src, raw)
    assert f"{src / 'builtin_box'}.stl: its object name is the name of a built-in" in message
    assert message.endswith("rename the file")
    assert "builtin_box" in _import_error(src, raw, ["builtin_box"])
    assert not (raw / "builtin_box").exists()
    assert import_directory(src, raw, ["box"]) == ["box"]


def test_import_refuses_reserved_folder_name(tmp_path: Path) -> None:
    src, raw = tmp_path / "src", tmp_path / "raw"
    _ycb_object(src, "ycb")
    message = _import_error(src, raw)
    assert "reserved for the object set 'ycb'" in message and message.endswith("rename the folder")


def test_cli_fetch_from_reserved_name_is_one_line(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """`geomprep fetch --from DIR` with DIR/ycb.stl: exit 1 and one error line, no object."""
    src, data = tmp_path / "src", tmp_path / "data"
    src.mkdir()
    trimesh.creation.box().export(src / "ycb.stl")
    argv = ["geomprep", "--data-dir", str(data), "fetch", "--from", str(src)]
    monkeypatch.setattr(sys, "argv", argv)
    with pytest.raises(SystemExit) as exit_info:
        cli.main()
    assert exit_info.value.code == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and "\n" not in err
    assert "reserved" in err and "rename the file" in err
    assert complete_objects(data / "raw") == []


def test_import_refuses_overlong_name(tmp_path: Path) -> None:
    """A 250-character name is a naming error, not 'check free disk space'."""
    src, raw = tmp_path / "src", tmp_path / "raw"
    src.mkdir()
    trimesh.creation.box().export(src / f"{'k' * 250}.stl")
    message = _import_error(src, raw)
    assert "its object name is 250 characters long (at most 128): rename the file" in message
    assert "disk space" not in message


def test_import_source_does_not_exist(tmp_path: Path) -> None:
    message = _import_error(tmp_path / "missing", tmp_path / "raw")
    assert message.startswith(f"{tmp_path / 'missing'} does not exist: pass the directory")


def test_import_source_is_a_file(tmp_path: Path) -> None:
    src = tmp_path / "src"
    _write_plain_meshes(src)
    message = _import_error(src / "box.stl", tmp_path / "raw")
    assert message == (
        f"{src / 'box.stl'} is a file, not a directory: pass the directory that holds it ({src})"
    )


def test_import_source_is_one_ycb_object(tmp_path: Path) -> None:
    """Pointing at one object's folder (or its google_16k) names the folder to pass instead."""
    src, raw = tmp_path / "ycb", tmp_path / "raw"
    _ycb_object(src, KNIFE)
    assert _import_error(src / KNIFE, raw).endswith(f"pass its parent {src}")
    assert _import_error(src / KNIFE / "google_16k", raw).endswith(f"pass {src}")
    # Without the check the google_16k folder imported one wrong object named 'textured'.
    assert not (raw / "textured").exists()


@pytest.mark.parametrize("layout", ["plain", "ycb"])
def test_import_empty_mesh_file(tmp_path: Path, layout: str) -> None:
    src, raw = tmp_path / "src", tmp_path / "raw"
    src.mkdir()
    if layout == "plain":
        (src / "box.stl").write_bytes(b"")
        empty = src / "box.stl"
    else:
        _ycb_object(src, "box", obj="")
        empty = src / "box" / "google_16k" / "textured.obj"
    trimesh.creation.box().export(src / "good.stl")
    expected = f"mesh file {empty} is empty (0 bytes): export or copy it again"

    assert _import_error(src, raw) == expected
    assert _import_error(src, raw, ["box"]) == expected
    assert import_directory(src, raw, ["good"]) == ["good"]


@pytest.mark.parametrize("suffix", [".glb", ".off", ".fbx"])
def test_import_unsupported_extension(tmp_path: Path, suffix: str) -> None:
    src, raw = tmp_path / "src", tmp_path / "raw"
    src.mkdir()
    (src / f"drill{suffix}").write_bytes(b"mesh data")
    expected = (
        f"{src / 'drill'}{suffix} is a {suffix} file, which import does not read: "
        "convert it to .obj, .ply, .stl"
    )
    assert _import_error(src, raw) == expected
    assert _import_error(src, raw, ["drill"]) == expected


def test_import_unsupported_beside_its_export_is_fine(tmp_path: Path) -> None:
    """A modelling file next to its export (drill.blend + drill.stl) is not a problem."""
    src, raw = tmp_path / "src", tmp_path / "raw"
    src.mkdir()
    (src / "drill.blend").write_bytes(b"blender")
    trimesh.creation.box().export(src / "drill.stl")
    assert import_directory(src, raw) == ["drill"]


def test_import_ycb_folder_in_another_variant(tmp_path: Path) -> None:
    """A YCB object downloaded as google_64k (no google_16k) is named, not silently skipped."""
    src, raw = tmp_path / "src", tmp_path / "raw"
    _ycb_object(src, KNIFE, variant="google_64k")
    _ycb_object(src, DICE)
    message = _import_error(src, raw)
    assert message.startswith(f"{src / KNIFE} has no google_16k/textured.obj (only google_64k/)")
    assert _import_error(src, raw, [KNIFE]) == message
    assert import_directory(src, raw, [DICE]) == [DICE]


def test_import_duplicate_name_only_blocks_that_object(tmp_path: Path) -> None:
    src, raw = tmp_path / "src", tmp_path / "raw"
    _write_plain_meshes(src)
    trimesh.creation.box().export(src / "box.obj")  # box.obj beside box.stl
    expected = f"object 'box' appears twice in {src} (box.obj and box.stl): keep one of them"
    assert _import_error(src, raw) == expected
    assert _import_error(src, raw, ["box"]) == expected
    assert import_directory(src, raw, ["ball"]) == ["ball"]


def test_import_problems_are_counted(tmp_path: Path) -> None:
    """Several bad entries: the first is named, the others counted, all on one line."""
    src, raw = tmp_path / "src", tmp_path / "raw"
    _write_plain_meshes(src)
    (src / "a.glb").write_bytes(b"x")
    (src / "b.stl").write_bytes(b"")
    trimesh.creation.box().export(src / "ycb.stl")
    message = _import_error(src, raw)
    assert message.startswith(f"{src / 'a'}.glb is a .glb file")
    assert message.endswith(f"(and 2 more problems in {src})")
