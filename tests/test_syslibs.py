"""A system library that pip cannot install is named, with its fix, in one line."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from geomprep.errors import GeomprepError
from geomprep.syslibs import import_system_dependent, missing_library_message

LOADER_ERROR = "libusb-1.0.so.0: cannot open shared object file: No such file or directory"


def test_missing_library_names_the_package() -> None:
    message = missing_library_message("open3d", ImportError(LOADER_ERROR))
    assert message is not None
    assert "libusb-1.0.so.0" in message
    assert "apt-get install -y libusb-1.0-0" in message
    assert "\n" not in message


def test_unrelated_import_error_is_not_rewritten() -> None:
    assert missing_library_message("open3d", ImportError("No module named 'open3d'")) is None


def test_import_turns_loader_error_into_one_line(tmp_path: Path, monkeypatch) -> None:  # noqa: ANN001
    # A stand-in for open3d whose native extension fails to load the way open3d's does.
    (tmp_path / "fake_native_module.py").write_text(f"raise ImportError({LOADER_ERROR!r})\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.delitem(sys.modules, "fake_native_module", raising=False)
    with pytest.raises(GeomprepError, match=r"fake_native_module cannot load .*libusb-1\.0-0"):
        import_system_dependent("fake_native_module")


def test_other_import_errors_propagate(tmp_path: Path, monkeypatch) -> None:  # noqa: ANN001
    (tmp_path / "fake_broken_module.py").write_text("raise ImportError('something else')\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    with pytest.raises(ImportError, match="something else"):
        import_system_dependent("fake_broken_module")
