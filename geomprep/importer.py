"""Import a local directory into the raw store: YCB-layout folders or plain mesh files.

``src/NAME/google_16k/textured.obj`` (with its mtl and textures) is a YCB object; ``src/NAME.obj``,
``.ply`` or ``.stl`` a plain one (an OBJ's mtl and texture files come along). Masses come from
``masses.csv`` rows, else a density (see geomprep.masses).
"""

from __future__ import annotations

import os
import posixpath
import re
import shutil
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path

from geomprep import builtin as builtin_objects
from geomprep import ycb
from geomprep.errors import GeomprepError
from geomprep.masses import check_density, mass_fields, read_masses
from geomprep.rawstore import (
    SOURCE_FILE,
    complete_objects,
    install_object,
    name_problem,
    validate_name,
)

MESH_SUFFIXES = (".obj", ".ply", ".stl")
# Mesh formats people have that import does not read: reported, not silently skipped, when no
# readable file of the same name stands beside them.
OTHER_MESH_SUFFIXES = frozenset({
    ".glb", ".gltf", ".off", ".dae", ".fbx", ".3ds", ".blend", ".3mf", ".amf", ".step", ".stp",
    ".iges", ".igs", ".usd", ".usda", ".usdc", ".usdz", ".x3d", ".wrl", ".vrml", ".dxf",
})  # fmt: skip
# The scan folders of a YCB object: a folder holding some of these but no google_16k/textured.obj
# is a YCB object downloaded in another variant (or copied halfway), not an unrelated folder.
YCB_VARIANTS = ("google_16k", "google_64k", "google_512k", "poisson", "tsdf")
# MTL statements that name a texture file (the file is the last token, options come first).
_MTL_MAP_KEYWORDS = frozenset({
    "map_ka", "map_kd", "map_ks", "map_ke", "map_ns", "map_d", "map_bump", "bump", "disp",
    "decal", "refl", "norm", "map_pr", "map_pm", "map_ps",
})  # fmt: skip


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
        return ycb.MESH

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


def _expected_layout(src: Path) -> str:
    """The one-line description of what import_directory looks for."""
    return (
        f"expected {src}/NAME/{ycb.MESH} (YCB layout) "
        f"or mesh files {src}/NAME{'|'.join(MESH_SUFFIXES)}"
    )


def _check_source_dir(src: Path) -> None:
    """Raise if ``src`` is not a directory of objects, naming the directory to pass instead."""
    if not src.exists():
        raise GeomprepError(
            f"{src} does not exist: pass the directory that holds the meshes "
            f"({_expected_layout(src)})"
        )
    if not src.is_dir():
        raise GeomprepError(
            f"{src} is a file, not a directory: pass the directory that holds it ({src.parent})"
        )
    # One object's own folder instead of the folder of objects: a natural slip with YCB copies.
    if (src / ycb.MESH).is_file():
        raise GeomprepError(
            f"{src} is one YCB object, not a directory of objects: pass its parent {src.parent}"
        )
    if src.name == "google_16k" and (src / "textured.obj").is_file():
        raise GeomprepError(
            f"{src} is inside one YCB object, not a directory of objects: pass {src.parent.parent}"
        )


def _scan(src: Path, builtin: bool = False) -> tuple[dict[str, Path], dict[str, str]]:
    """Objects in ``src``: ({name: YCB object dir or mesh file}, {name: problem with its fix}).

    Problems are entries a user meant as objects that cannot be imported (invalid or duplicate
    names, built-in objects' names unless ``builtin``, empty meshes, unreadable formats, partial
    YCB folders); a name with one is not imported.
    """
    try:
        entries = sorted(entry for entry in src.iterdir() if not entry.name.startswith("."))
    except OSError as exc:
        raise GeomprepError(f"cannot read {src}: {exc.strerror}: check its permissions") from None
    candidates: dict[str, list[tuple[Path, Path]]] = {}  # name -> [(entry, its mesh file)]
    problems: dict[str, str] = {}
    unreadable: dict[str, Path] = {}
    for entry in entries:
        if entry.is_dir():
            if (entry / ycb.MESH).is_file():
                candidates.setdefault(entry.name, []).append((entry, entry / ycb.MESH))
                continue
            variants = [v for v in YCB_VARIANTS if (entry / v).is_dir()]
            if variants:
                problems[entry.name] = (
                    f"{entry} has no {ycb.MESH} (only {'/, '.join(variants)}/): "
                    f"put the google_16k scan there or move the folder out of {src}"
                )
        elif entry.is_file() and entry.suffix.lower() in MESH_SUFFIXES:
            candidates.setdefault(entry.stem, []).append((entry, entry))
        elif entry.is_file() and entry.suffix.lower() in OTHER_MESH_SUFFIXES:
            unreadable[entry.stem] = entry
    for name, path in unreadable.items():
        if name not in candidates:
            problems[name] = (
                f"{path} is a {path.suffix} file, which import does not read: "
                f"convert it to {', '.join(MESH_SUFFIXES)}"
            )
    from geomprep.builtin import NAMES as BUILTIN_NAMES  # here: it imports trimesh

    found: dict[str, Path] = {}
    for name, group in candidates.items():
        entry, mesh_file = group[0]
        problem = name_problem(name)
        if problem is None and name in BUILTIN_NAMES and not builtin:
            # Imported, it would take the built-in object's place in every set and build.
            problem = "is the name of a built-in object (geomprep writes it from code)"
        if problem is not None:
            kind = "folder" if entry.is_dir() else "file"
            problems[name] = f"cannot import {entry}: its object name {problem}: rename the {kind}"
        elif len(group) > 1:
            problems[name] = (
                f"object '{name}' appears twice in {src} ({entry.name} and {group[1][0].name}): "
                "keep one of them"
            )
        elif mesh_file.stat().st_size == 0:
            problems[name] = f"mesh file {mesh_file} is empty (0 bytes): export or copy it again"
        else:
            found[name] = entry
    return found, problems


def _select(
    src: Path, found: dict[str, Path], problems: dict[str, str], names: Sequence[str] | None
) -> list[str]:
    """The sorted names to import: ``names``, or all found; raises for any that cannot be."""
    if not names:
        if problems:
            first = sorted(problems)[0]
            more = f" (and {len(problems) - 1} more problems in {src})" if len(problems) > 1 else ""
            raise GeomprepError(problems[first] + more)
        if not found:
            raise GeomprepError(f"no objects found in {src}: {_expected_layout(src)}")
        return sorted(found)
    fix = f"rename the file or folder in {src} and pass the new name"
    selected = sorted({validate_name(name, fix) for name in names})
    for name in selected:
        if name in problems:
            raise GeomprepError(problems[name])
    missing = [name for name in selected if name not in found]
    if missing:
        raise GeomprepError(
            f"object(s) {', '.join(missing)} not found in {src}: {_expected_layout(src)}"
        )
    return selected


def import_directory(
    src: Path,
    raw_dir: Path,
    names: Sequence[str] | None = None,
    *,
    density_kg_m3: float = 500.0,
    masses_csv: Path | None = None,
    force: bool = False,
    builtin: bool = False,
) -> list[str]:
    """Import objects from a local directory into the raw store.

    ``src`` holds objects in the YCB layout (``NAME/google_16k/textured.obj`` with its mtl and
    textures) and/or plain mesh files ``NAME.obj|.ply|.stl`` (an OBJ's mtl and texture files
    come along). Masses (kg) come from ``masses_csv``, else ``src/masses.csv`` if present;
    objects not listed there get ``density_kg_m3`` (kg/m^3) instead. Complete objects are kept
    unless ``force``. ``names`` selects objects (None or empty: all found, and then any entry
    that looks like an object but cannot be imported is an error). A built-in object's name
    is refused (it would replace that object) unless ``builtin``: ``src`` is where
    ``import_builtin`` wrote the built-in objects. Returns the sorted names imported or
    already present.
    """
    src = Path(src)
    raw_dir = Path(raw_dir)
    density = check_density(density_kg_m3)
    _check_source_dir(src)
    if isinstance(names, str):
        names = [names]  # one name, not a sequence of characters
    found, problems = _scan(src, builtin)
    selected = _select(src, found, problems, names)
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
        mass_kg, density_field = mass_fields(name, masses, density)
        install_object(
            raw_dir, name, populate, mass_kg=mass_kg, density_kg_m3=density_field, origin=origin
        )
    return selected


def import_builtin(raw_dir: Path, names: Sequence[str]) -> list[str]:
    """The build step that writes built-in objects into the raw store: each of ``names`` (built-in
    names) whose source is not there yet is written from code (``geomprep.builtin``, which needs
    the mesh stack) and imported through the ordinary import path. Returns the names written
    (none when all are present: then nothing is imported or loaded)."""
    raw_dir = Path(raw_dir)
    missing = [n for n in names if not (raw_dir / n / SOURCE_FILE).is_file()]
    if not missing:
        return []
    staging = raw_dir / f".builtin-{os.getpid()}"
    staging.mkdir(parents=True, exist_ok=True)
    try:
        rows = ["object,mass_kg"]
        for name in missing:
            _, mass = builtin_objects.write_source(name, staging)
            rows.append(f"{name},{mass}")
        (staging / "masses.csv").write_text("\n".join(rows) + "\n")
        import_directory(staging, raw_dir, missing, builtin=True)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return missing
