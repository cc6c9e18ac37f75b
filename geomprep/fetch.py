"""Get object meshes into the raw object store: download YCB scans or import a local directory.

The raw store is ``raw_dir/<name>/``; an object is complete only when ``raw_dir/<name>/source.json``
exists. Every import is staged in ``raw_dir/.<name>.tmp-<pid>/``, ``source.json`` is written inside
that staging directory (via ``source.json.tmp`` + ``os.replace``) and the directory is then renamed
into place, so a crashed or failed import never looks complete: the next run removes the leftovers
and redoes the object.

``source.json`` holds ``name``, ``mesh`` (path relative to the object directory), ``mass_kg`` or
``density_kg_m3`` (exactly one is non-null; kg and kg/m^3), ``origin`` and ``mesh_sha256``.
"""

from __future__ import annotations

import contextlib
import csv
import hashlib
import json
import math
import os
import posixpath
import re
import shutil
import tarfile
import time
import urllib.error
import urllib.request
import zlib
from collections.abc import Callable, Iterable, Sequence
from http.client import HTTPException
from pathlib import Path, PurePosixPath

from tqdm import tqdm

from geomprep import __version__
from geomprep.errors import GeomprepError

YCB_BASE_URL = "http://ycb-benchmarks.s3-website-us-east-1.amazonaws.com/data/google/"

# The 78 objects of the YCB Object and Model Set that have Google 16k scans (official names).
YCB_OBJECTS: tuple[str, ...] = (
    "002_master_chef_can", "003_cracker_box", "004_sugar_box", "005_tomato_soup_can",
    "006_mustard_bottle", "007_tuna_fish_can", "008_pudding_box", "009_gelatin_box",
    "010_potted_meat_can", "011_banana", "012_strawberry", "013_apple", "014_lemon",
    "015_peach", "016_pear", "017_orange", "018_plum", "019_pitcher_base",
    "021_bleach_cleanser", "022_windex_bottle", "024_bowl", "025_mug", "026_sponge",
    "028_skillet_lid", "029_plate", "030_fork", "031_spoon", "032_knife", "033_spatula",
    "035_power_drill", "036_wood_block", "037_scissors", "038_padlock", "040_large_marker",
    "042_adjustable_wrench", "043_phillips_screwdriver", "044_flat_screwdriver", "048_hammer",
    "050_medium_clamp", "051_large_clamp", "052_extra_large_clamp", "053_mini_soccer_ball",
    "054_softball", "055_baseball", "056_tennis_ball", "057_racquetball", "058_golf_ball",
    "059_chain", "061_foam_brick", "062_dice", "063-a_marbles", "063-b_marbles",
    "065-a_cups", "065-b_cups", "065-c_cups", "065-d_cups", "065-e_cups", "065-f_cups",
    "065-g_cups", "065-h_cups", "065-i_cups", "065-j_cups", "070-a_colored_wood_blocks",
    "070-b_colored_wood_blocks", "071_nine_hole_peg_test", "072-a_toy_airplane",
    "072-b_toy_airplane", "072-c_toy_airplane", "072-d_toy_airplane", "072-e_toy_airplane",
    "073-a_lego_duplo", "073-b_lego_duplo", "073-c_lego_duplo", "073-d_lego_duplo",
    "073-e_lego_duplo", "073-f_lego_duplo", "073-g_lego_duplo", "077_rubiks_cube",
)  # fmt: skip

SOURCE_FILE = "source.json"
YCB_MESH = "google_16k/textured.obj"
MESH_SUFFIXES = (".obj", ".ply", ".stl")
NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]*$")

# Seconds before the first retry; doubled per attempt and capped. A module constant so tests
# can set it to 0 instead of sleeping.
RETRY_BACKOFF_S = 1.0
RETRY_BACKOFF_MAX_S = 30.0
CHUNK_BYTES = 1 << 20
DOWNLOADS_DIR = ".downloads"

# An S3 ETag is the object's MD5 (quoted) unless it was a multipart upload ("<md5>-<parts>").
_MD5_ETAG_RE = re.compile(r'^"?([0-9a-fA-F]{32})"?$')
_CONTENT_RANGE_RE = re.compile(r"^bytes (\d+)-(\d+)/(\d+|\*)$")
# MTL statements that name a texture file (the file is the last token, options come first).
_MTL_MAP_KEYWORDS = frozenset({
    "map_ka", "map_kd", "map_ks", "map_ke", "map_ns", "map_d", "map_bump", "bump", "disp",
    "decal", "refl", "norm", "map_pr", "map_pm", "map_ps",
})  # fmt: skip


# --------------------------------------------------------------------------------------------
# Raw store: names, source.json, staging
# --------------------------------------------------------------------------------------------


def validate_name(name: str) -> str:
    """Return ``name`` if it is a valid object name, else raise GeomprepError."""
    if not isinstance(name, str) or not NAME_RE.match(name):
        raise GeomprepError(
            f"invalid object name {name!r}: use letters, digits, '_', '.', '-' "
            "and start with a letter or digit"
        )
    return name


def complete_objects(raw_dir: Path) -> list[str]:
    """Sorted names of the complete objects (those with ``source.json``) in ``raw_dir``."""
    raw_dir = Path(raw_dir)
    if not raw_dir.is_dir():
        return []
    return sorted(
        entry.name
        for entry in raw_dir.iterdir()
        if NAME_RE.match(entry.name) and (entry / SOURCE_FILE).is_file()
    )


def read_source(raw_dir: Path, name: str) -> dict:
    """Parsed ``raw_dir/<name>/source.json``; GeomprepError if the object is not complete."""
    validate_name(name)
    path = Path(raw_dir) / name / SOURCE_FILE
    if not path.is_file():
        raise GeomprepError(
            f"object '{name}' is not in {raw_dir} (no {SOURCE_FILE}): "
            "fetch or import it first ('geomprep fetch' / 'geomprep import')"
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


def _write_json_atomic(path: Path, record: dict) -> None:
    """Write ``record`` to ``path`` via ``path.tmp`` + ``os.replace`` (never half-written)."""
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "w", encoding="utf-8") as f:
        json.dump(record, f, indent=2)
        f.write("\n")
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def _sha256(path: Path) -> str:
    """Hex SHA-256 of a file's bytes."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(CHUNK_BYTES), b""):
            digest.update(block)
    return digest.hexdigest()


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


def _mass_fields(
    name: str, masses: dict[str, float] | None, density_kg_m3: float
) -> tuple[float | None, float | None]:
    """(mass_kg, density_kg_m3) for source.json: the listed mass if any, else the density."""
    if masses is not None and name in masses:
        return masses[name], None
    return None, density_kg_m3


def _check_density(density_kg_m3: float) -> float:
    """Return the density (kg/m^3) if it is a finite positive number, else raise."""
    try:
        value = float(density_kg_m3)
    except (TypeError, ValueError):
        value = math.nan
    if not math.isfinite(value) or value <= 0:
        raise GeomprepError(
            f"invalid density {density_kg_m3!r} kg/m^3: pass a positive number (e.g. 500)"
        )
    return value


def _install(
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
            "mesh_sha256": _sha256(stage / mesh_rel),
        }
        # source.json goes in before the rename, so the object appears complete in one step.
        _write_json_atomic(stage / SOURCE_FILE, record)
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


# --------------------------------------------------------------------------------------------
# Masses
# --------------------------------------------------------------------------------------------


def read_masses(csv_path: Path) -> dict[str, float]:
    """Read a CSV with header ``object,mass_kg`` into {object name: mass in kg}.

    Blank lines are ignored; a malformed row, a duplicate name or a mass that is not a finite
    positive number raises GeomprepError naming the file and line.
    """
    csv_path = Path(csv_path)
    fix = "expected a CSV with header 'object,mass_kg' and one 'name,mass' row per object"
    try:
        text = csv_path.read_text(encoding="utf-8-sig")  # tolerate a BOM from spreadsheets
    except OSError as exc:
        raise GeomprepError(f"cannot read masses file {csv_path}: {exc.strerror}: {fix}") from None
    rows = [
        (lineno, row)
        for lineno, row in enumerate(csv.reader(text.splitlines()), start=1)
        if any(cell.strip() for cell in row)
    ]
    if not rows or [cell.strip() for cell in rows[0][1]] != ["object", "mass_kg"]:
        raise GeomprepError(f"{csv_path}: missing header 'object,mass_kg': {fix}")
    masses: dict[str, float] = {}
    for lineno, row in rows[1:]:
        where = f"{csv_path}:{lineno}"
        if len(row) != 2:
            raise GeomprepError(f"{where}: expected 2 columns, got {len(row)}: {fix}")
        name, mass_text = row[0].strip(), row[1].strip()
        if not NAME_RE.match(name):
            raise GeomprepError(f"{where}: invalid object name {name!r}: {fix}")
        try:
            mass = float(mass_text)
        except ValueError:
            mass = math.nan
        if not math.isfinite(mass) or mass <= 0:
            raise GeomprepError(
                f"{where}: mass of '{name}' is {mass_text!r}: give a positive number of kg"
            )
        if name in masses:
            raise GeomprepError(f"{where}: '{name}' is listed twice: keep one row per object")
        masses[name] = mass
    return masses


# --------------------------------------------------------------------------------------------
# Local import
# --------------------------------------------------------------------------------------------


def _copy_file(src: Path, dst: Path) -> None:
    """Copy one file (contents and times), creating ``dst``'s directory. Tests patch this."""
    dst.parent.mkdir(parents=True, exist_ok=True)
    shutil.copy2(src, dst)


def _safe_relpath(text: str) -> str | None:
    """Normalized relative POSIX path, or None if it is absolute or leaves its directory."""
    text = text.strip().replace("\\", "/")
    if not text or text.startswith("/") or re.match(r"^[A-Za-z]:", text):
        return None
    norm = posixpath.normpath(text)
    if norm == "." or norm == ".." or norm.startswith("../"):
        return None
    return norm


def _referenced_files(root: Path, file_rel: str, keywords: Iterable[str]) -> list[str]:
    """Existing files named by ``keywords`` lines of text file ``root/file_rel``.

    Names are resolved against that file's directory and returned relative to ``root``; names
    leaving ``root`` are ignored. The name is the rest of the line (it may contain spaces) or,
    failing that, its last token (MTL map statements put options before the name).
    """
    keywords = frozenset(keywords)
    base = posixpath.dirname(file_rel)
    found: list[str] = []
    with open(root / file_rel, encoding="utf-8", errors="replace") as f:
        for line in f:
            parts = line.split(None, 1)
            if len(parts) < 2 or parts[0].lower() not in keywords:
                continue
            rest = parts[1].strip().replace("\\", "/")
            for candidate in (rest, rest.split()[-1]):
                if candidate.startswith("/"):
                    continue
                rel = _safe_relpath(posixpath.join(base, candidate))
                if rel is not None and (root / rel).is_file():
                    if rel not in found:
                        found.append(rel)
                    break
    return found


def _obj_sidecars(obj_path: Path) -> list[str]:
    """Paths (relative to the OBJ's directory) of its .mtl files and their texture images."""
    root = obj_path.parent
    sidecars: list[str] = []
    for mtl_rel in _referenced_files(root, obj_path.name, ("mtllib",)):
        sidecars.append(mtl_rel)
        for tex_rel in _referenced_files(root, mtl_rel, _MTL_MAP_KEYWORDS):
            if tex_rel not in sidecars:
                sidecars.append(tex_rel)
    return sidecars


def _populate_from_ycb_dir(obj_dir: Path) -> Callable[[Path], str]:
    """Populate step copying ``obj_dir/google_16k/*`` (obj, mtl, textures, ...) as-is."""

    def populate(stage: Path) -> str:
        src = obj_dir / "google_16k"
        for item in sorted(src.iterdir()):
            if item.is_file():
                _copy_file(item, stage / "google_16k" / item.name)
        return YCB_MESH

    return populate


def _populate_from_file(mesh: Path, name: str) -> Callable[[Path], str]:
    """Populate step copying a plain mesh file to ``<name>.<ext>`` plus an OBJ's mtl/textures."""

    def populate(stage: Path) -> str:
        mesh_rel = f"{name}{mesh.suffix.lower()}"
        _copy_file(mesh, stage / mesh_rel)
        if mesh.suffix.lower() == ".obj":
            # Keep the sidecars at the same relative paths: the OBJ's mtllib lines point there.
            for rel in _obj_sidecars(mesh):
                _copy_file(mesh.parent / rel, stage / rel)
        return mesh_rel

    return populate


def _discover(src: Path) -> tuple[dict[str, Path], list[str]]:
    """Objects in ``src``: ({name: YCB object dir or mesh file}, [invalid names seen])."""
    found: dict[str, Path] = {}
    invalid: list[str] = []
    for entry in sorted(src.iterdir()):
        if entry.name.startswith("."):
            continue
        if entry.is_dir() and (entry / YCB_MESH).is_file():
            name = entry.name
        elif entry.is_file() and entry.suffix.lower() in MESH_SUFFIXES:
            name = entry.stem
        else:
            continue
        if not NAME_RE.match(name):
            invalid.append(entry.name)
            continue
        if name in found:
            raise GeomprepError(
                f"object '{name}' appears twice in {src} ({found[name].name} and {entry.name}): "
                "keep one of them"
            )
        found[name] = entry
    return found, invalid


def _expected_layout(src: Path) -> str:
    """The one-line description of what import_directory looks for."""
    return (
        f"expected {src}/NAME/google_16k/textured.obj (YCB layout) "
        f"or mesh files {src}/NAME.obj|.ply|.stl"
    )


def import_directory(
    src: Path,
    raw_dir: Path,
    names: Sequence[str] | None = None,
    *,
    density_kg_m3: float = 500.0,
    masses_csv: Path | None = None,
    force: bool = False,
) -> list[str]:
    """Import objects from a local directory into the raw store.

    ``src`` holds objects in the YCB layout (``NAME/google_16k/textured.obj`` with its mtl and
    textures) and/or plain mesh files ``NAME.obj|.ply|.stl`` (an OBJ's mtl and texture files
    come along). Masses (kg) come from ``masses_csv``, else ``src/masses.csv`` if present;
    objects not listed there get ``density_kg_m3`` (kg/m^3) instead. Complete objects are kept
    unless ``force``. ``names`` selects objects (None or empty: all found). Returns the sorted
    names imported or already present.
    """
    src = Path(src)
    raw_dir = Path(raw_dir)
    density = _check_density(density_kg_m3)
    if not src.is_dir():
        raise GeomprepError(f"{src} is not a directory: {_expected_layout(src)}")
    found, invalid = _discover(src)
    if isinstance(names, str):
        names = [names]  # one name, not a sequence of characters
    if not names:
        if invalid:
            raise GeomprepError(
                f"invalid object names in {src}: {', '.join(invalid)}: rename them to letters, "
                "digits, '_', '.', '-' (starting with a letter or digit)"
            )
        if not found:
            raise GeomprepError(f"no objects found in {src}: {_expected_layout(src)}")
        selected = sorted(found)
    else:
        selected = sorted({validate_name(name) for name in names})
        missing = [name for name in selected if name not in found]
        if missing:
            raise GeomprepError(
                f"object(s) {', '.join(missing)} not found in {src}: {_expected_layout(src)}"
            )
    if masses_csv is not None:
        masses: dict[str, float] | None = read_masses(Path(masses_csv))
    elif (src / "masses.csv").is_file():
        masses = read_masses(src / "masses.csv")
    else:
        masses = None
    origin = f"dir: {src.resolve()}"
    done = set(complete_objects(raw_dir))
    for name in selected:
        if name in done and not force:
            continue
        entry = found[name]
        populate = (
            _populate_from_ycb_dir(entry) if entry.is_dir() else _populate_from_file(entry, name)
        )
        mass_kg, density_field = _mass_fields(name, masses, density)
        _install(
            raw_dir, name, populate, mass_kg=mass_kg, density_kg_m3=density_field, origin=origin
        )
    return selected


# --------------------------------------------------------------------------------------------
# Download
# --------------------------------------------------------------------------------------------


class _RetryableError(Exception):
    """A download failure worth retrying (network, 5xx, truncation, checksum); message = why."""


class _RestartError(Exception):
    """The server cannot continue our ``.part`` (HTTP 416): start the file from byte 0."""


def _backoff_s(attempt: int) -> float:
    """Seconds to wait before retry number ``attempt`` (0-based): exponential, capped."""
    return min(RETRY_BACKOFF_S * (2**attempt), RETRY_BACKOFF_MAX_S)


def _parse_content_range(value: str | None) -> tuple[int, int | None] | None:
    """(first byte, total size or None) from a ``Content-Range`` header, None if unparsable."""
    match = _CONTENT_RANGE_RE.match((value or "").strip())
    if not match:
        return None
    total = None if match.group(3) == "*" else int(match.group(3))
    return int(match.group(1)), total


def _int_header(value: str | None) -> int | None:
    """A non-negative integer header value, or None if absent or malformed."""
    try:
        number = int((value or "").strip())
    except ValueError:
        return None
    return number if number >= 0 else None


def _open(url: str, have: int, timeout_s: float):
    """Open ``url`` asking for bytes from ``have`` on; classify failures as retryable or not."""
    headers = {"User-Agent": f"geomprep/{__version__}"}
    if have:
        headers["Range"] = f"bytes={have}-"
    request = urllib.request.Request(url, headers=headers)
    try:
        return urllib.request.urlopen(request, timeout=timeout_s)
    except urllib.error.HTTPError as exc:
        exc.close()
        status = f"HTTP {exc.code} {exc.reason}"
        if exc.code >= 500 or exc.code in (408, 429):
            raise _RetryableError(status) from None
        if exc.code == 416 and have:
            raise _RestartError(status) from None
        raise GeomprepError(
            f"download of {url} failed: {status}: check the object name and the base URL"
        ) from None
    except (urllib.error.URLError, HTTPException, OSError) as exc:
        reason = getattr(exc, "reason", exc)
        raise _RetryableError(f"connection error: {reason}") from None


def _byte_bar(total: int | None, initial: int, desc: str, enabled: bool) -> tqdm:
    """A tqdm progress bar counting bytes (on stderr); a no-op when not ``enabled``."""
    return tqdm(
        total=total,
        initial=initial,
        unit="B",
        unit_scale=True,
        unit_divisor=1024,
        desc=desc,
        disable=not enabled,
        leave=False,
    )


def _download_once(url: str, part: Path, *, timeout_s: float, progress: bool, desc: str) -> str:
    """One attempt to complete ``part`` (resuming it if it exists); returns the ETag ('' if none).

    Raises _RetryableError if the body is cut short, the server fails or the size is wrong.
    """
    have = part.stat().st_size if part.exists() else 0
    try:
        response = _open(url, have, timeout_s)
    except _RestartError:
        # 416: our .part is not a prefix the server can continue (e.g. it is longer): restart.
        part.unlink(missing_ok=True)
        have = 0
        response = _open(url, have, timeout_s)
    with response:
        if response.status == 206:
            content_range = _parse_content_range(response.headers.get("Content-Range"))
            if content_range is None or content_range[0] != have:
                part.unlink(missing_ok=True)
                raise _RetryableError("HTTP 206 with an unusable Content-Range; restarting")
            total = content_range[1]
            mode = "ab"
        elif response.status == 200:
            # The server ignored the Range (or we sent none): the body is the whole file.
            have = 0
            total = _int_header(response.headers.get("Content-Length"))
            mode = "wb"
        else:
            raise _RetryableError(f"unexpected HTTP {response.status} {response.reason}")
        status = f"HTTP {response.status}"
        etag = response.headers.get("ETag") or ""
        with open(part, mode) as out, _byte_bar(total, have, desc, progress) as bar:
            while True:
                try:
                    chunk = response.read(CHUNK_BYTES)
                except (HTTPException, OSError) as exc:  # IncompleteRead, reset, timeout
                    raise _RetryableError(
                        f"{status}, body cut off after {have} bytes ({type(exc).__name__})"
                    ) from None
                if not chunk:
                    break
                out.write(chunk)
                have += len(chunk)
                bar.update(len(chunk))
    if total is not None and have < total:
        # Kept on disk: the next attempt resumes from here with a Range request.
        raise _RetryableError(f"{status}, body cut off: got {have} of {total} bytes")
    if total is not None and have > total:
        part.unlink(missing_ok=True)
        raise _RetryableError(f"{status}, got {have} bytes but the file has {total}")
    return etag


def _md5(path: Path) -> str:
    """Hex MD5 of a file's bytes (to compare with an S3 ETag)."""
    digest = hashlib.md5(usedforsecurity=False)
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(CHUNK_BYTES), b""):
            digest.update(block)
    return digest.hexdigest()


def _download(
    url: str, dest: Path, *, retries: int, timeout_s: float, progress: bool, desc: str
) -> None:
    """Download ``url`` to ``dest`` via ``dest.part``, verified (size, MD5 ETag), with retries.

    ``dest`` appears only once the whole file is there and matches the server's checksum; an
    unverified ``.part`` stays behind for the next run to resume.
    """
    part = dest.with_name(dest.name + ".part")
    dest.parent.mkdir(parents=True, exist_ok=True)
    last_error = ""
    for attempt in range(retries + 1):
        if attempt:
            time.sleep(_backoff_s(attempt - 1))
        try:
            etag = _download_once(url, part, timeout_s=timeout_s, progress=progress, desc=desc)
            match = _MD5_ETAG_RE.match(etag.strip())
            if match and _md5(part) != match.group(1).lower():
                part.unlink(missing_ok=True)  # a corrupt prefix must not be resumed
                raise _RetryableError(f"MD5 of the download does not match the ETag {etag}")
        except _RetryableError as exc:
            last_error = str(exc)
            continue
        except OSError as exc:  # local disk trouble: retrying will not help
            raise GeomprepError(
                f"cannot write {part}: {exc}: check free disk space and permissions"
            ) from None
        os.replace(part, dest)
        return
    raise GeomprepError(
        f"download of {url} failed after {retries + 1} attempts ({last_error}): "
        "check the network connection and rerun (a partial download resumes)"
    )


# --------------------------------------------------------------------------------------------
# Safe extraction
# --------------------------------------------------------------------------------------------


def _check_members(archive: Path, members: Iterable[tarfile.TarInfo]) -> None:
    """Reject archive members that are links, devices or paths outside the extraction dir."""
    for member in members:
        path = PurePosixPath(member.name)
        if path.is_absolute() or ".." in path.parts or member.name.startswith("\\"):
            raise GeomprepError(
                f"unsafe path {member.name!r} in {archive}: refusing to extract; "
                "check the download source (--base-url)"
            )
        if not (member.isfile() or member.isdir()):
            raise GeomprepError(
                f"archive member {member.name!r} in {archive} is a link or special file: "
                "refusing to extract; check the download source (--base-url)"
            )


def _populate_from_archive(archive: Path, name: str) -> Callable[[Path], str]:
    """Populate step extracting a YCB ``*_google_16k.tgz`` and keeping ``google_16k/``."""

    def populate(stage: Path) -> str:
        unpack = stage / ".unpack"
        try:
            with tarfile.open(archive, "r:gz") as tar:
                members = tar.getmembers()
                _check_members(archive, members)
                # filter="data" is a second guard (absolute paths, links, device files, modes).
                tar.extractall(unpack, members=members, filter="data")
        except (tarfile.TarError, EOFError, zlib.error, OSError) as exc:
            raise GeomprepError(
                f"cannot extract {archive} ({exc}): check free disk space and rerun "
                "(the archive is downloaded again)"
            ) from None
        ycb_dir = unpack / name / "google_16k"
        if not (ycb_dir / "textured.obj").is_file():
            raise GeomprepError(
                f"{archive} does not hold {name}/google_16k/textured.obj: "
                "check the download source (--base-url)"
            )
        os.rename(ycb_dir, stage / "google_16k")
        shutil.rmtree(unpack)
        return YCB_MESH

    return populate


def fetch_ycb(
    raw_dir: Path,
    names: Sequence[str] | None = None,
    *,
    base_url: str = YCB_BASE_URL,
    masses_csv: Path | None = None,
    density_kg_m3: float = 500.0,
    retries: int = 3,
    timeout_s: float = 60.0,
    force: bool = False,
    progress: bool = True,
) -> list[str]:
    """Download YCB google_16k scans into the raw store; returns the sorted names now present.

    Each ``{base_url}{name}_google_16k.tgz`` goes to ``raw_dir/.downloads`` (resumable ``.part``,
    checked against Content-Length and an MD5 ETag), is extracted safely and moved into
    ``raw_dir/<name>/google_16k/``. ``retries`` is the number of extra attempts per file after
    the first; ``timeout_s`` the socket timeout in seconds. Masses (kg) come from
    ``masses_csv`` where listed, otherwise ``density_kg_m3`` (kg/m^3) is recorded. Complete
    objects are skipped unless ``force``. ``names`` None or empty means all YCB_OBJECTS.
    """
    raw_dir = Path(raw_dir)
    density = _check_density(density_kg_m3)
    if retries < 0:
        raise GeomprepError(f"invalid retries {retries}: pass 0 or more")
    if isinstance(names, str):
        names = [names]  # one name, not a sequence of characters
    if not names:
        selected = list(YCB_OBJECTS)
    else:
        selected = sorted(set(names))
        unknown = [name for name in selected if name not in YCB_OBJECTS]
        if unknown:
            raise GeomprepError(
                f"unknown YCB object(s) {', '.join(map(repr, unknown))}: "
                "run 'geomprep list --available' to see the valid names"
            )
    masses = read_masses(Path(masses_csv)) if masses_csv is not None else None
    if not base_url.endswith("/"):
        base_url += "/"
    downloads = raw_dir / DOWNLOADS_DIR
    done = set(complete_objects(raw_dir))
    for name in selected:
        if name in done and not force:
            continue
        file_name = f"{name}_google_16k.tgz"
        url = f"{base_url}{file_name}"
        archive = downloads / file_name
        # A leftover verified archive may predate a changed server copy; only trust fresh ones.
        archive.unlink(missing_ok=True)
        _download(url, archive, retries=retries, timeout_s=timeout_s, progress=progress, desc=name)
        mass_kg, density_field = _mass_fields(name, masses, density)
        try:
            _install(
                raw_dir,
                name,
                _populate_from_archive(archive, name),
                mass_kg=mass_kg,
                density_kg_m3=density_field,
                origin=f"ycb-server: {url}",
            )
        finally:
            # Installed objects do not need their archive; a bad one must be downloaded again.
            archive.unlink(missing_ok=True)
    return sorted(selected)
