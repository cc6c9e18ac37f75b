"""The raw object store: valid object names, ``source.json`` records and atomic installation.

The raw store is ``raw_dir/<name>/``; an object is complete only when ``raw_dir/<name>/source.json``
exists. Every object is staged in ``raw_dir/.<name>.tmp-<pid>/``, ``source.json`` is written inside
that staging directory (``cache.write_json_atomic``) and the directory is then renamed into
place, so a crashed or failed import never looks complete: the next run removes the leftovers
and redoes the object.

``source.json`` holds ``name``, ``mesh`` (path relative to the object directory), ``mass_kg`` or
``density_kg_m3`` (exactly one is non-null; kg and kg/m^3), ``origin`` and ``mesh_sha256``.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import shutil
from collections.abc import Callable
from pathlib import Path

from geomprep.cache import write_json_atomic
from geomprep.errors import GeomprepError
from geomprep.hashing import file_sha256

SOURCE_FILE = "source.json"
NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]*$")
NAME_RULE = "letters, digits, '_', '.', '-', starting with a letter or digit"
# The name becomes part of file names with suffixes added (".<name>.png.tmp-<pid>" is 17 more
# characters, the trainer's "<name>-<16 hex>.npy" 21); 128 leaves room for those within the
# 255-byte file-name limit of common file systems.
MAX_NAME_LENGTH = 128
# The object-set names of pipeline.resolve_objects: an object with one of these names could
# never be selected on its own ('build-all --objects ycb' means the set, not the object).
RESERVED_NAMES = frozenset({"all", "builtin", "ycb"})


# --------------------------------------------------------------------------------------------
# Names
# --------------------------------------------------------------------------------------------


def name_problem(name: object) -> str | None:
    """Why ``name`` cannot be an object name (a clause to follow the name), or None if it can."""
    if not isinstance(name, str) or not name:
        return "is empty"
    if len(name) > MAX_NAME_LENGTH:
        return f"is {len(name)} characters long (at most {MAX_NAME_LENGTH})"
    if not NAME_RE.match(name):
        return f"must use only {NAME_RULE}"
    if name in RESERVED_NAMES:
        return f"is reserved for the object set '{name}' ('geomprep build-all --objects {name}')"
    return None


def validate_name(name: str, fix: str = "choose another name") -> str:
    """Return ``name`` if it is a valid object name, else raise GeomprepError ending in ``fix``."""
    problem = name_problem(name)
    if problem is not None:
        raise GeomprepError(f"invalid object name {name!r}: it {problem}: {fix}")
    return name


# --------------------------------------------------------------------------------------------
# Reading the store
# --------------------------------------------------------------------------------------------


def complete_objects(raw_dir: Path) -> list[str]:
    """Sorted names of the complete objects (those with ``source.json``) in ``raw_dir``."""
    raw_dir = Path(raw_dir)
    if not raw_dir.is_dir():
        return []
    # Invalid names are staging directories (".x.tmp-1") or objects no command could select.
    return sorted(
        entry.name
        for entry in raw_dir.iterdir()
        if name_problem(entry.name) is None and (entry / SOURCE_FILE).is_file()
    )


def read_source(raw_dir: Path, name: str) -> dict:
    """Parsed ``raw_dir/<name>/source.json``; GeomprepError if the object is not complete."""
    validate_name(name, "run 'geomprep list' to see the object names")
    path = Path(raw_dir) / name / SOURCE_FILE
    if not path.is_file():
        raise GeomprepError(
            f"object '{name}' is not in {raw_dir} (no {SOURCE_FILE}): download it with "
            "'geomprep fetch' or import it with 'geomprep fetch --from DIR'"
        )
    try:
        record = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise GeomprepError(
            f"cannot read {path}: {exc}: delete the directory {path.parent} and fetch it again"
        ) from None
    if not isinstance(record, dict):
        raise GeomprepError(f"{path} is not a JSON object: delete {path.parent} and fetch it again")
    return record


# --------------------------------------------------------------------------------------------
# Installing an object
# --------------------------------------------------------------------------------------------


def _remove(path: Path) -> None:
    """Remove a file, link or directory tree if it exists."""
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path)
    elif path.exists() or path.is_symlink():
        path.unlink()


def _pid_alive(pid: int) -> bool:
    """Whether a process with this id exists (so its staging directory may still be in use)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _remove_stale_staging(raw_dir: Path, name: str) -> None:
    """Delete staging leftovers of ``name`` from crashed runs (ours, or of dead processes)."""
    for pattern in (f".{name}.tmp-*", f".{name}.old-*"):
        for path in raw_dir.glob(pattern):
            pid_text = path.name.rsplit("-", 1)[-1]
            pid = int(pid_text) if pid_text.isdigit() else None
            if pid is None or pid == os.getpid() or not _pid_alive(pid):
                _remove(path)


def install_object(
    raw_dir: Path,
    name: str,
    populate: Callable[[Path], str],
    *,
    mass_kg: float | None,
    density_kg_m3: float | None,
    origin: str,
) -> None:
    """Build object ``name`` in a staging directory and move it into ``raw_dir`` complete.

    ``populate(stage_dir)`` fills the staging directory and returns the mesh path relative to
    it. Whatever fails, the staging directory is removed and no complete object appears.
    """
    # Callers validate with their own fix; this guards the store against any that do not.
    validate_name(name)
    raw_dir.mkdir(parents=True, exist_ok=True)
    _remove_stale_staging(raw_dir, name)
    stage = raw_dir / f".{name}.tmp-{os.getpid()}"
    old = raw_dir / f".{name}.old-{os.getpid()}"
    final = raw_dir / name
    try:
        stage.mkdir()
        mesh_rel = populate(stage)
        record = {
            "name": name,
            "mesh": mesh_rel,
            "mass_kg": mass_kg,
            "density_kg_m3": density_kg_m3,
            "origin": origin,
            "mesh_sha256": file_sha256(stage / mesh_rel),
        }
        # source.json goes in before the rename, so the object appears complete in one step.
        write_json_atomic(stage / SOURCE_FILE, record)
        if final.exists() or final.is_symlink():
            # Move the old (incomplete, or forced-over) copy aside first: renaming it is atomic,
            # deleting a tree is not, and a half-deleted tree could still hold source.json.
            os.rename(final, old)
        try:
            os.rename(stage, final)
        except OSError:
            if old.exists() and not final.exists():
                os.rename(old, final)  # put the previous copy back rather than lose it
            raise
    except OSError as exc:
        raise GeomprepError(
            f"cannot import object '{name}' into {raw_dir}: {exc}: "
            "check free disk space and permissions, then rerun"
        ) from None
    finally:
        for leftover in (stage, old):
            # If this fails, a later run's _remove_stale_staging retries.
            with contextlib.suppress(OSError):
                _remove(leftover)
