"""Importing the libraries that need system packages pip cannot install, with a one-line fix.

open3d loads ``libusb-1.0.so.0``, ``libGL.so.1``, ``libEGL.so.1`` and ``libgomp.so.1`` when it is
imported, even headless. On a machine without them the import fails with a bare
``ImportError: libusb-1.0.so.0: cannot open shared object file``; ``import_open3d`` turns that
into a ``GeomprepError`` naming the Debian package to install (``scripts/setup.sh`` installs them).
"""

from __future__ import annotations

import importlib
import re
from types import ModuleType

from geomprep.errors import GeomprepError

# Shared library (as the loader names it) -> the Debian/Ubuntu package that provides it.
DEBIAN_PACKAGES: dict[str, str] = {
    "libusb-1.0.so.0": "libusb-1.0-0",
    "libGL.so.1": "libgl1",
    "libEGL.so.1": "libegl1",
    "libgomp.so.1": "libgomp1",
    "libX11.so.6": "libx11-6",
    "libOpenGL.so.0": "libopengl0",
}

_MISSING_LIBRARY = re.compile(r"(lib[\w.+-]+\.so[\w.]*): cannot open shared object file")


def missing_library_message(module: str, error: BaseException) -> str | None:
    """The one-line fix for an import ``error`` caused by a missing shared library, else None."""
    match = _MISSING_LIBRARY.search(str(error))
    if match is None:
        return None
    library = match.group(1)
    package = DEBIAN_PACKAGES.get(library)
    fix = (
        f"run 'sudo apt-get install -y {package}' (or scripts/setup.sh, which installs all of them)"
        if package
        else "install the system package that provides it (scripts/setup.sh lists the usual ones)"
    )
    return f"{module} cannot load the system library {library}, which pip does not install: {fix}"


def import_system_dependent(module: str) -> ModuleType:
    """``importlib.import_module(module)``; a missing shared library becomes a GeomprepError."""
    try:
        return importlib.import_module(module)
    except (ImportError, OSError) as exc:
        message = missing_library_message(module, exc)
        if message is None:
            raise
        raise GeomprepError(message) from None


def import_open3d() -> ModuleType:
    """open3d, or a one-line GeomprepError naming the missing system package."""
    return import_system_dependent("open3d")
