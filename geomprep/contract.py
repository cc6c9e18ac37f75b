"""The data contract between geomprep and its readers: where a processed object lies, the names
inside its HDF5 file, a typed reader of it, and the checks that it is current.

geomprep writes ``data/processed/<name>.h5`` (``pack``: one group per stage, see
``STAGE_GROUPS``) and the MuJoCo model directory ``data/processed/<name>/``; the trainer reads
them through this module alone. It imports the standard library, numpy, h5py and geomprep's
record and raw-store modules, never the mesh stack (trimesh, CoACD, Open3D): reading a processed
object must not load the libraries that made it (``tests/test_contract.py`` checks this), and
h5py is imported by the readers only (``geomprep.config`` uses ``DataDirs``, and ``geomprep``'s
command line starts without h5py).

It only reads: writing the built-in objects' sources into the raw store is a build step of its
own (``geomprep.importer.import_builtin``), which the callers that need the sources run
(``geomprep.pipeline.resolve_objects``, ``trainer.objects.resolve_names``).

Quantities are in the object frame (origin at the centre of mass, the frame of the MJCF free
body and of the SDF grid), metres, kilograms; arrays are stored as float32.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from geomprep import builtin, cache, rawstore, ycb
from geomprep.errors import GeomprepError

CONTRACT = "geomprep/1"
"""The root attribute ``contract`` of every processed file: the layout below."""

# --- the layout of processed/<name>.h5 ---------------------------------------------------------
GROUP_MESH = "mesh"
GROUP_DECOMPOSITION = "decomposition"
GROUP_MJCF = "mjcf"
GROUP_SDF = "sdf"
GROUP_BBOX = "bbox"
GROUP_SUPERQUADRIC = "superquadric"
GROUP_POINTCLOUD = "pointcloud"

STAGE_GROUPS: dict[str, str] = {
    "mesh": GROUP_MESH,
    "decompose": GROUP_DECOMPOSITION,
    "mjcf": GROUP_MJCF,
    "sdf": GROUP_SDF,
    "bbox": GROUP_BBOX,
    "sq": GROUP_SUPERQUADRIC,
    "pc": GROUP_POINTCLOUD,
}
"""Which group of the processed file each stage fills."""

STAGE_ATTR_PREFIX = "stage_"
"""``pack`` copies each stage file's root attributes onto its group with this prefix."""

# Names inside the groups (datasets unless marked attr).
MESH_MASS = "mass_kg"  # attr of GROUP_MESH: kg
MJCF_XML = "xml"  # attr of GROUP_MJCF: the model's path relative to processed/
MJCF_CACHE_KEY = STAGE_ATTR_PREFIX + "cache_key"  # attr of GROUP_MJCF: the mjcf stage's key
SDF_GRID = "grid"  # (R, R, R) signed distance at the voxel centres, m, negative inside
SDF_BOUNDS_MIN = "bounds_min"  # attr: (3,) the grid cube's lower corner, m
SDF_BOUNDS_MAX = "bounds_max"  # attr: (3,) its upper corner, m
SDF_VOXEL_SIZE = "voxel_size"  # attr: m
BBOX_CENTER = "center"  # (3,) m
BBOX_ROTATION = "rotation"  # (3, 3) the box axes as columns
BBOX_EXTENTS = "extents"  # (3,) full edge lengths, m
SQ_PARAMS = "params"  # (11,) eps1, eps2, a1, a2, a3, extrinsic xyz Euler (rad), translation (m)
POINTS_READ = 512
"""The point cloud the reader loads: its first 32 / 128 points are the smaller clouds."""


def points_name(n: int) -> str:
    """Dataset of GROUP_POINTCLOUD holding the (n, 3) farthest-point surface samples, m."""
    return f"pc{n}"


def normals_name(n: int) -> str:
    """Dataset of GROUP_POINTCLOUD holding the (n, 3) unit normals of ``points_name(n)``."""
    return f"normals_{n}"


# --- the data directory ------------------------------------------------------------------------
@dataclass(frozen=True)
class DataDirs:
    """The data directory and its three parts (geomprep's ``Config`` is one)."""

    data_dir: Path = Path("data")

    def __post_init__(self) -> None:
        object.__setattr__(self, "data_dir", Path(self.data_dir))  # a str given is a Path

    @property
    def raw_dir(self) -> Path:
        """Imported sources, ``raw/<name>/`` (see ``geomprep.rawstore``)."""
        return self.data_dir / "raw"

    @property
    def interim_dir(self) -> Path:
        """Stage outputs and their build records, ``interim/<name>/``."""
        return self.data_dir / "interim"

    @property
    def processed_dir(self) -> Path:
        """What readers use: ``processed/<name>.h5`` and the model ``processed/<name>/``."""
        return self.data_dir / "processed"


def processed_path(dirs: DataDirs, name: str) -> Path:
    """``processed/<name>.h5``, the packed file of one object."""
    return dirs.processed_dir / f"{name}.h5"


# --- the reader --------------------------------------------------------------------------------
@dataclass(frozen=True)
class ProcessedObject:
    """One processed object as the trainer uses it (object frame, metres; float32 arrays)."""

    name: str
    h5_path: Path
    xml_path: Path
    """The MuJoCo model (its meshes beside it)."""
    mjcf_key: str
    """The mjcf stage's cache key: a new model invalidates what was derived from the old one."""
    mass_kg: float
    bbox_center: np.ndarray
    """(3,) oriented box centre."""
    bbox_rotation: np.ndarray
    """(3, 3) box axes as columns."""
    bbox_extents: np.ndarray
    """(3,) full edge lengths."""
    sq_params: np.ndarray
    """(11,) superquadric: eps1, eps2, a1, a2, a3, extrinsic xyz Euler (rad), translation."""
    points: np.ndarray
    """(POINTS_READ, 3) farthest-point surface samples; the first 32 / 128 are the smaller
    sets."""
    sdf_bounds_min: np.ndarray
    """(3,) the SDF grid cube's lower corner."""
    sdf_voxel_size: float

    def sdf_grid(self) -> np.ndarray:
        """(R, R, R) the signed-distance grid (read now: grids are large)."""
        return read_sdf_grid(self.h5_path)


def read_object(dirs: DataDirs, name: str) -> ProcessedObject:
    """Read ``processed/<name>.h5`` (without its SDF grid); a file missing a part raises a
    one-line GeomprepError naming the rebuild. Does not check that the file is current
    (``verify_processed`` does)."""
    import h5py  # here: geomprep's config imports this module for DataDirs, its CLI no h5py

    path = processed_path(dirs, name)
    try:
        with h5py.File(path, "r") as f:
            bbox, sdf, mjcf = f[GROUP_BBOX], f[GROUP_SDF], f[GROUP_MJCF]
            return ProcessedObject(
                name=name,
                h5_path=path,
                xml_path=dirs.processed_dir / str(mjcf.attrs[MJCF_XML]),
                mjcf_key=str(mjcf.attrs[MJCF_CACHE_KEY]),
                mass_kg=float(f[GROUP_MESH].attrs[MESH_MASS]),
                bbox_center=bbox[BBOX_CENTER][:],
                bbox_rotation=bbox[BBOX_ROTATION][:],
                bbox_extents=bbox[BBOX_EXTENTS][:],
                sq_params=f[GROUP_SUPERQUADRIC][SQ_PARAMS][:],
                points=f[GROUP_POINTCLOUD][points_name(POINTS_READ)][:],
                sdf_bounds_min=np.asarray(sdf.attrs[SDF_BOUNDS_MIN], dtype=np.float32),
                sdf_voxel_size=float(sdf.attrs[SDF_VOXEL_SIZE]),
            )
    except (KeyError, OSError) as exc:
        raise GeomprepError(
            f"{path} is incomplete ({exc}): rebuild it with `geomprep build-all --objects "
            f"{name}`"
        ) from None


def read_sdf_frame(path: str | Path) -> tuple[np.ndarray, float]:
    """(bounds_min (3,) float32 m, voxel size m) of the SDF grid in an HDF5 file with an ``sdf``
    group (a processed file or the sdf stage's)."""
    return _read_sdf(
        path,
        lambda g: (
            np.asarray(g.attrs[SDF_BOUNDS_MIN], dtype=np.float32),
            float(g.attrs[SDF_VOXEL_SIZE]),
        ),
    )


def read_sdf_grid(path: str | Path) -> np.ndarray:
    """(R, R, R) float32 signed distances (m, negative inside) of the SDF grid in ``path``."""
    return _read_sdf(path, lambda g: np.asarray(g[SDF_GRID][()], dtype=np.float32))


def _read_sdf(path: str | Path, read: Any) -> Any:
    import h5py  # see read_object

    try:
        with h5py.File(path, "r") as f:
            return read(f[GROUP_SDF])
    except (OSError, KeyError) as err:
        raise GeomprepError(
            f"cannot read an SDF grid from {path} ({err}): build it with `geomprep sdf`"
        ) from err


# --- is it current? ----------------------------------------------------------------------------
def _rel(dirs: DataDirs, path: Path) -> str:
    return cache.relative(dirs.data_dir, path)


def source_identity(dirs: DataDirs, name: str) -> dict[str, Any]:
    """What the mesh stage's output depends on: the source file's bytes and the mass rule.

    The file is hashed again only if its size or mtime differ from what the mesh stage's record
    saw (a rerun need not read every raw mesh)."""
    source = rawstore.read_source(dirs.raw_dir, name)
    mesh_path = dirs.raw_dir / name / source["mesh"]
    seen = (cache.read_record(dirs.interim_dir, name, "mesh") or {}).get("source")
    if not isinstance(seen, dict) or seen.get("path") != _rel(dirs, mesh_path):
        seen = None
    return identity(
        source, cache.current_sha256(mesh_path, seen) if mesh_path.is_file() else "missing"
    )


def identity(source: dict[str, Any], mesh_sha256: str) -> dict[str, Any]:
    """The source identity of a raw store entry (``source.json``) whose mesh hashes to
    ``mesh_sha256``."""
    return {
        "mesh_sha256": mesh_sha256,
        "mass_kg": source.get("mass_kg"),
        "density_kg_m3": source.get("density_kg_m3"),
    }


def verify_processed(dirs: DataDirs, name: str) -> str | None:
    """None if ``processed/<name>.h5`` and the model directory are what geomprep last built for
    the current source, else why not (one phrase). Parameters are not compared (a reader may not
    know the config the build used); content and source are: a file changed since it was
    written, a model directory from another build than the packed file, or a source that
    changed since (re-imported, edited) all make the processed files out of date."""
    h5 = processed_path(dirs, name)
    if not h5.is_file():
        return f"{h5} does not exist"
    packed = cache.read_record(dirs.interim_dir, name, "pack")
    if packed is None:
        return f"{h5} has no build record (made by an older geomprep, or its build was cut short)"
    problem = cache.check_record(dirs.data_dir, packed)
    if problem:
        return problem
    model = cache.read_record(dirs.interim_dir, name, "mjcf")
    if model is None or model.get("key") != packed.get("inputs", {}).get("mjcf"):
        return f"the model in {dirs.processed_dir / name} is not the one {h5} was packed with"
    problem = cache.check_record(dirs.data_dir, model, prefix=_rel(dirs, dirs.processed_dir) + "/")
    if problem:
        return problem
    try:
        current = source_identity(dirs, name)
    except GeomprepError:
        return f"the source of '{name}' is gone from {dirs.raw_dir}"
    if current != packed.get("source_identity"):
        return f"the source of '{name}' in {dirs.raw_dir} changed after {h5} was built"
    return None


# --- which objects -----------------------------------------------------------------------------
def resolve_objects(dirs: DataDirs, spec: str | Sequence[str] | None) -> list[str]:
    """Object names from a comma list that may use the sets ``all``, ``builtin`` and ``ycb``.

    ``all`` (the default) is every imported object plus the built-in set. Nothing is written:
    the built-in objects' sources are written into the raw store by a build step
    (``geomprep.importer.import_builtin``), which the caller runs. Unknown names, and ``ycb``
    with no YCB object imported, raise GeomprepError.
    """
    if spec is None:
        spec = "all"
    items = [s.strip() for s in (spec.split(",") if isinstance(spec, str) else spec) if s.strip()]
    if not items:
        raise GeomprepError(
            f"no object names in {spec!r}: give names or a set (all, builtin, ycb), comma-separated"
        )
    imported = rawstore.complete_objects(dirs.raw_dir)
    names: list[str] = []
    for item in items:
        if item == "all":
            names += [*builtin.NAMES, *imported]
        elif item == "builtin":
            names += list(builtin.NAMES)
        elif item == "ycb":
            ycb_names = [n for n in imported if n in ycb.OBJECTS]
            if not ycb_names:  # not a silent 'nothing to do'
                raise GeomprepError(
                    f"the object set 'ycb' is empty: no YCB object is imported in {dirs.raw_dir}: "
                    "download them with 'geomprep fetch' or import a copy with "
                    "'geomprep fetch --from DIR'"
                )
            names += ycb_names
        elif item in builtin.NAMES or item in imported:
            names.append(item)
        else:
            hint = (
                " (a YCB object: import it first with 'geomprep fetch')"
                if item in ycb.OBJECTS
                else ""
            )
            raise GeomprepError(
                f"unknown object '{item}'{hint}: run 'geomprep list' to see the available names"
            )
    return list(dict.fromkeys(names))

