"""Build records: what a stage wrote, so that a cache hit is declared only for files that still
hold those bytes.

After a stage has written its outputs it writes ``interim/<name>/<stage>.record.json``::

    {"stage": "sdf", "object": "032_knife", "key": "<cache key>",
     "files": {"interim/032_knife/sdf.h5": {"size": 9813265, "mtime_ns": ..., "sha256": "..."}}}

File paths are relative to the data directory (a moved or copied data directory keeps its
records). The record is written last, so an output without a matching record (a killed write, a
file from an older geomprep) is never trusted. One small file per stage rather than one manifest
per object: stages of one object run in parallel processes, and separate files need no locking.

Checking a file costs one ``stat`` when its size and mtime are the recorded ones; otherwise it
is hashed again (about 1 s per GB) and trusted only if the SHA-256 matches. Anything that
rewrites a file changes its mtime, so the fast path cannot miss a damaged file short of a
write within the filesystem's timestamp granularity right after the record was made.

A record never changes after it is written (DVC tracks it as an output of its stage). When a
file is found intact by hashing (a copied data directory, a ``dvc checkout``), its new mtime goes
to a sidecar, ``<stage>.mtimes.json`` (path -> [mtime_ns, sha256]), which ``read_record`` lays
over the record's mtimes where the hashes agree; the next check is one ``stat`` again.

This module uses only the standard library: the trainer and ``geomprep show`` read records
without importing the stages.
"""

from __future__ import annotations

import contextlib
import json
import os
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from geomprep.hashing import file_sha256

RECORD_SUFFIX = ".record.json"
MTIMES_SUFFIX = ".mtimes.json"
SOURCE = "source"
"""The sidecar key of the mesh record's source entry."""


def file_entry(path: Path) -> dict[str, Any]:
    """What a record keeps about one file: size, mtime (ns) and SHA-256."""
    stat = os.stat(path)
    return {"size": stat.st_size, "mtime_ns": stat.st_mtime_ns, "sha256": file_sha256(path)}


def current_sha256(path: Path, entry: Mapping[str, Any] | None) -> str:
    """The SHA-256 of ``path``: the recorded one if size and mtime still match ``entry``."""
    if entry is not None:
        stat = os.stat(path)
        if stat.st_size == entry.get("size") and stat.st_mtime_ns == entry.get("mtime_ns"):
            return str(entry["sha256"])
    return file_sha256(path)


def check_file(path: Path, entry: dict[str, Any]) -> str | None:
    """None if ``path`` holds the bytes ``entry`` records, else why not (a phrase). A file with
    a new mtime but the recorded bytes (copied, restored, touched) gets the new mtime in
    ``entry``: saved (``save_mtimes``), later checks take the fast path again."""
    try:
        stat = os.stat(path)
    except FileNotFoundError:
        return "is missing"
    except OSError as exc:
        return f"cannot be read ({exc.strerror})"
    if stat.st_size != entry.get("size"):
        return f"has {stat.st_size} bytes, not the {entry.get('size')} it was written with"
    if stat.st_mtime_ns == entry.get("mtime_ns"):
        return None
    try:
        same = file_sha256(path) == entry.get("sha256")
    except OSError as exc:
        return f"cannot be read ({exc.strerror})"
    if not same:
        return "was modified after it was written (its SHA-256 differs)"
    entry["mtime_ns"] = stat.st_mtime_ns
    return None


def record_path(interim_dir: Path, name: str, stage: str) -> Path:
    return Path(interim_dir) / name / f"{stage}{RECORD_SUFFIX}"


def read_record(interim_dir: Path, name: str, stage: str) -> dict[str, Any] | None:
    """A stage's record, or None if there is none (or it is unreadable: then nothing it
    describes is trusted, and the stage is rebuilt)."""
    try:
        record = json.loads(record_path(interim_dir, name, stage).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if not isinstance(record, dict) or not isinstance(record.get("files"), dict):
        return None
    for rel, entry in _entries(record).items():
        seen = _read_mtimes(interim_dir, name, stage).get(rel)
        # Only an mtime seen for the recorded bytes: never one left by an older build.
        if isinstance(seen, list) and len(seen) == 2 and seen[1] == entry.get("sha256"):
            entry["mtime_ns"] = seen[0]
    return record


def _entries(record: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """The record's file entries by path, with the mesh stage's source under ``SOURCE``."""
    entries = {rel: e for rel, e in record["files"].items() if isinstance(e, dict)}
    if isinstance(record.get("source"), dict):
        entries[SOURCE] = record["source"]
    return entries


def mtimes_path(interim_dir: Path, name: str, stage: str) -> Path:
    return Path(interim_dir) / name / f"{stage}{MTIMES_SUFFIX}"


def _read_mtimes(interim_dir: Path, name: str, stage: str) -> dict[str, Any]:
    try:
        seen = json.loads(mtimes_path(interim_dir, name, stage).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    return seen if isinstance(seen, dict) else {}


def save_mtimes(interim_dir: Path, name: str, stage: str, record: dict[str, Any]) -> None:
    """Remember the mtimes ``record``'s entries now hold (set by ``check_file`` after a
    rehash) in the stage's sidecar, leaving the record itself as written."""
    seen = {rel: [e.get("mtime_ns"), e.get("sha256")] for rel, e in _entries(record).items()}
    write_json_atomic(mtimes_path(interim_dir, name, stage), seen)


def write_record(
    data_dir: Path,
    interim_dir: Path,
    name: str,
    stage: str,
    key: str,
    files: Iterable[Path],
    extra: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """Hash ``files`` (paths under ``data_dir``) and write the stage's record atomically."""
    record: dict[str, Any] = {
        "stage": stage,
        "object": name,
        "key": key,
        "files": {relative(data_dir, p): file_entry(p) for p in files},
        **(extra or {}),
    }
    save_record(interim_dir, name, stage, record)
    return record


def save_record(interim_dir: Path, name: str, stage: str, record: Mapping[str, Any]) -> None:
    """Write a record atomically (a reader sees the old one or the new one, never half)."""
    with contextlib.suppress(FileNotFoundError):
        mtimes_path(interim_dir, name, stage).unlink()  # it described the previous outputs
    write_json_atomic(record_path(interim_dir, name, stage), record)


def write_json_atomic(path: Path, value: Any) -> None:
    """Write ``value`` as JSON to ``path`` via a temporary sibling and ``os.replace``: a reader
    (or a killed writer) sees the old file or the new one, never half of one."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    try:
        with open(tmp, "w", encoding="utf-8") as f:
            f.write(json.dumps(value, indent=1, sort_keys=True) + "\n")
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    finally:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()


def remove_record(interim_dir: Path, name: str, stage: str) -> None:
    for path in (record_path(interim_dir, name, stage), mtimes_path(interim_dir, name, stage)):
        with contextlib.suppress(FileNotFoundError):
            path.unlink()


def relative(data_dir: Path, path: Path) -> str:
    """``path`` relative to the data directory, with ``/`` separators (the record's key)."""
    return Path(path).relative_to(data_dir).as_posix()


def check_record(data_dir: Path, record: dict[str, Any], prefix: str = "") -> str | None:
    """None if every file of ``record`` (whose path starts with ``prefix``) is intact, else a
    phrase naming the first one that is not, e.g. ``data/processed/x/hull_000.stl is missing``."""
    for rel, entry in sorted(record["files"].items()):
        if not rel.startswith(prefix):
            continue
        problem = check_file(Path(data_dir) / rel, entry)
        if problem is not None:
            return f"{Path(data_dir) / rel} {problem}"
    return None
