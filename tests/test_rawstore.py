"""Tests for geomprep.rawstore (object names, source.json, atomic install) and geomprep.hashing."""

from __future__ import annotations

import hashlib
import re
from pathlib import Path

import pytest

from geomprep import cli, pipeline
from geomprep.config import Config
from geomprep.errors import GeomprepError
from geomprep.hashing import file_md5, file_sha256
from geomprep.rawstore import (
    MAX_NAME_LENGTH,
    RESERVED_NAMES,
    complete_objects,
    install_object,
    name_problem,
    read_source,
)
from geomprep.ycb import OBJECTS as YCB_OBJECTS


def _commands_named(message: str) -> list[tuple[str, list[str]]]:
    """Each 'geomprep COMMAND --option ...' quoted in ``message``: (command, [options])."""
    quoted = re.findall(r"'geomprep ([^']*)'", message)
    return [(q.split()[0], [w for w in q.split() if w.startswith("--")]) for q in quoted]


def assert_real_commands(message: str) -> None:
    """Every geomprep command (and option) that ``message`` suggests exists in the CLI."""
    named = _commands_named(message)
    assert named, message
    for command, options in named:
        assert command in cli.cli.commands, f"{message!r} names no such command {command!r}"
        known = {opt for param in cli.cli.commands[command].params for opt in param.opts}
        assert set(options) <= known, f"{message!r}: {command} has no {set(options) - known}"


def test_complete_objects_and_read_source_missing(tmp_path: Path) -> None:
    assert complete_objects(tmp_path / "absent") == []
    (tmp_path / "half").mkdir()
    assert complete_objects(tmp_path) == []
    with pytest.raises(GeomprepError, match="not in"):
        read_source(tmp_path, "half")
    with pytest.raises(GeomprepError, match="invalid object name"):
        read_source(tmp_path, "../etc")


def test_read_source_missing_suggests_real_commands(tmp_path: Path) -> None:
    """The fix it names must be a command the CLI has (there is no 'geomprep import')."""
    with pytest.raises(GeomprepError) as err:
        read_source(tmp_path, "box")
    assert "\n" not in str(err.value)
    assert_real_commands(str(err.value))


@pytest.mark.parametrize("name", ["a", "box.v2", "my-box_2", "x" * MAX_NAME_LENGTH, *YCB_OBJECTS])
def test_valid_names(name: str) -> None:
    assert name_problem(name) is None


@pytest.mark.parametrize(
    ("name", "pattern"),
    [
        ("", "empty"),
        ("my box", "must use only letters"),
        ("../x", "must use only letters"),
        (".hidden", "must use only letters"),
        ("-x", "must use only letters"),
        ("a,b", "must use only letters"),  # a comma would split 'build-all --objects a,b'
        ("x" * (MAX_NAME_LENGTH + 1), f"{MAX_NAME_LENGTH + 1} characters long"),
        ("all", "reserved for the object set 'all'"),
        ("builtin", "reserved for the object set 'builtin'"),
        ("ycb", "reserved for the object set 'ycb'"),
    ],
)
def test_invalid_names(name: str, pattern: str) -> None:
    assert re.search(pattern, name_problem(name) or "")


def test_name_length_leaves_room_for_suffixes(tmp_path: Path) -> None:
    """The longest valid name still fits the longest file names the pipeline makes from it."""
    name = "x" * MAX_NAME_LENGTH
    pid = "4194304"  # Linux's largest pid
    for file_name in (f".{name}.old-{pid}", f".{name}.png.tmp-{pid}", f"{name}-{'0' * 16}.npy"):
        (tmp_path / file_name).write_text("")


def test_reserved_names_are_the_pipeline_object_sets(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Each reserved name selects a set in resolve_objects, so an object of that name could not
    be selected on its own."""
    monkeypatch.setattr(pipeline, "ensure_builtin", lambda cfg, names: None)
    cfg = Config(data_dir=tmp_path / "data")
    for name in RESERVED_NAMES - {"ycb"}:
        pipeline.resolve_objects(cfg, name)  # a set: no 'unknown object' error
    # No YCB object imported: the set is empty, which is an error of its own (not a silent
    # 'build-all --objects ycb' that builds nothing and exits 0).
    with pytest.raises(GeomprepError, match="the object set 'ycb' is empty.*geomprep fetch"):
        pipeline.resolve_objects(cfg, "ycb")
    with pytest.raises(GeomprepError, match="unknown object"):
        pipeline.resolve_objects(cfg, "not_a_set")


def _populate_box(stage: Path) -> str:
    (stage / "box.stl").write_text("solid box\nendsolid box\n")
    return "box.stl"


@pytest.mark.parametrize("name", ["x" * 250, "ycb", "my box"])
def test_install_refuses_invalid_name(tmp_path: Path, name: str) -> None:
    """A bad name is named as such, not reported as a disk problem after staging fails."""
    with pytest.raises(GeomprepError, match="invalid object name") as err:
        install_object(
            tmp_path, name, _populate_box, mass_kg=None, density_kg_m3=500.0, origin="test"
        )
    assert "disk space" not in str(err.value)
    assert list(tmp_path.iterdir()) == []


def test_install_records_source(tmp_path: Path) -> None:
    install_object(
        tmp_path, "box", _populate_box, mass_kg=0.2, density_kg_m3=None, origin="dir: test"
    )
    data = (tmp_path / "box" / "box.stl").read_bytes()
    assert complete_objects(tmp_path) == ["box"]
    assert read_source(tmp_path, "box") == {
        "name": "box",
        "mesh": "box.stl",
        "mass_kg": 0.2,
        "density_kg_m3": None,
        "origin": "dir: test",
        "mesh_sha256": hashlib.sha256(data).hexdigest(),
    }


def test_file_digests_match_hashlib(tmp_path: Path) -> None:
    """Over several read blocks, the digests equal those of the whole byte string."""
    data = bytes(range(256)) * (3 * 4096 + 7)  # ~3 MiB, not a whole number of blocks
    path = tmp_path / "blob"
    path.write_bytes(data)
    assert file_sha256(path) == hashlib.sha256(data).hexdigest()
    assert file_md5(path) == hashlib.md5(data).hexdigest()
