"""Tests for geomprep.masses: reading masses.csv and checking a fallback density."""

from __future__ import annotations

from pathlib import Path

import pytest

from geomprep.errors import GeomprepError
from geomprep.masses import check_density, mass_fields, read_masses


def test_read_masses(tmp_path: Path) -> None:
    path = tmp_path / "m.csv"
    path.write_text("object,mass_kg\na,0.5\n\nb_2,1e-3\n")
    assert read_masses(path) == {"a": 0.5, "b_2": 0.001}


def test_read_masses_spreadsheet_export(tmp_path: Path) -> None:
    """A BOM, CRLF line ends and padded cells, as spreadsheets write them, are accepted."""
    path = tmp_path / "m.csv"
    path.write_bytes(b"\xef\xbb\xbfobject , mass_kg\r\n 032_knife , 0.031 \r\n")
    assert read_masses(path) == {"032_knife": 0.031}


@pytest.mark.parametrize(
    ("text", "pattern"),
    [
        ("", "header"),
        ("name,mass\na,1\n", "header"),
        ("object\na\n", "missing header 'object,mass_kg'"),
        ("object,mass_kg,notes\na,1,x\n", "missing header 'object,mass_kg'"),
        ("object,mass_kg\na\n", r":2: expected 2 columns, got 1"),
        ("object,mass_kg\na,0,5\n", r":2: expected 2 columns, got 3"),
        ("object,mass_kg\na,1\nb,heavy\n", r":3: mass of 'b'"),
        ("object,mass_kg\na,\n", r"mass of 'a' is ''"),
        ("object,mass_kg\na,-1\n", "positive"),
        ("object,mass_kg\na,0\n", "positive"),
        ("object,mass_kg\na,nan\n", "positive"),
        ("object,mass_kg\na,inf\n", "positive"),
        ("object,mass_kg\na,1\na,2\n", r":3: 'a' is listed twice"),
        ("object,mass_kg\n../x,1\n", "invalid object name"),
        ("object,mass_kg\nycb,1\n", r"invalid object name 'ycb': it is reserved"),
        ("object,mass_kg\n" + "a" * 200 + ",1\n", r"200 characters long \(at most 128\)"),
    ],
)
def test_read_masses_malformed(tmp_path: Path, text: str, pattern: str) -> None:
    path = tmp_path / "m.csv"
    path.write_text(text)
    with pytest.raises(GeomprepError, match=pattern) as err:
        read_masses(path)
    assert "\n" not in str(err.value)


def test_read_masses_missing_file(tmp_path: Path) -> None:
    with pytest.raises(GeomprepError, match="cannot read masses file"):
        read_masses(tmp_path / "nope.csv")


def test_read_masses_not_utf8(tmp_path: Path) -> None:
    """A CSV saved in a legacy code page is a one-line error, not a UnicodeDecodeError."""
    path = tmp_path / "m.csv"
    path.write_bytes("object,mass_kg\ncafé_mug,0.3\n".encode("cp1252"))
    with pytest.raises(GeomprepError, match=r"cannot read masses file .*: not UTF-8 text") as err:
        read_masses(path)
    assert "\n" not in str(err.value)


@pytest.mark.parametrize("density", [0.0, -1.0, float("nan"), float("inf"), "heavy"])
def test_check_density_rejects(density: object) -> None:
    with pytest.raises(GeomprepError, match="invalid density"):
        check_density(density)  # type: ignore[arg-type]


def test_mass_fields_prefers_listed_mass() -> None:
    assert mass_fields("a", {"a": 0.2}, 500.0) == (0.2, None)
    assert mass_fields("b", {"a": 0.2}, 500.0) == (None, 500.0)
    assert mass_fields("b", None, 500.0) == (None, 500.0)
