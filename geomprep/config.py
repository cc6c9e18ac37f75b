"""Every knob of the pipeline, as data: one frozen dataclass per stage.

Defaults live here; a TOML file (``geomprep.toml`` in the working directory, or ``--config``)
overrides any of them, section by stage name::

    [decompose]
    threshold = 0.05

A stage's parameters are part of its cache key, so changing one reruns that stage (and the stages
that read its output) and nothing else.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

from geomgrasp import config_schema, materials
from geomgrasp.config_schema import bounded, toml_value  # noqa: F401 (geomprep's configs use them)
from geomprep.contract import DataDirs
from geomprep.errors import GeomprepError

DEFAULT_CONFIG_NAME = "geomprep.toml"


class Checked(config_schema.Checked):
    """A geomprep config dataclass: out-of-range values raise ``GeomprepError``."""

    error: ClassVar[type[Exception]] = GeomprepError


def build_dataclass(
    cls: type, values: Mapping[str, Any], source: str | None,
    error: type[Exception] = GeomprepError, **kwargs: Any,
) -> Any:
    """``geomgrasp.config_schema.build_dataclass`` raising ``GeomprepError`` unless told."""
    return config_schema.build_dataclass(cls, values, source, error, **kwargs)


def read_toml(path: Path, error: type[Exception] = GeomprepError) -> dict[str, Any]:
    """``geomgrasp.config_schema.read_toml`` raising ``GeomprepError`` unless told."""
    return config_schema.read_toml(path, error)


@dataclass(frozen=True)
class MeshParams(Checked):
    """Stage ``mesh``: load, clean, check units, centre at the centre of mass."""

    density_kg_m3: float = bounded(500.0, gt=0)
    """Fallback density for objects with no mass of their own (kg/m^3)."""
    min_extent_m: float = bounded(0.005, gt=0)
    """A mesh smaller than this across (bounding-box diagonal) is rejected as not in metres."""
    max_extent_m: float = bounded(1.0, gt=0)
    """A mesh larger than this across is rejected (millimetres?): it must fit the SDF grid."""
    merge_tolerance_m: float = bounded(1e-7, ge=0)
    """Vertices closer than this are merged in the geometry mesh."""
    texture_size: int = bounded(1024, ge=1)
    """The visual texture is resized to at most this many pixels a side (YCB ships 4096)."""
    min_density_kg_m3: float = bounded(1.0, gt=0)
    """Mass / volume below this is refused as a unit mistake (nothing solid is lighter than air).
    The 78 YCB objects span 4.6 kg/m^3 (070-a_colored_wood_blocks: 10.8 g listed for a
    14 x 14 x 17 cm scan) to 12,900 (042_adjustable_wrench: a thin scan's voxel volume)."""
    max_density_kg_m3: float = bounded(25000.0, gt=0)
    """Mass / volume above this is refused as a unit mistake (grams in masses.csv); the densest
    element, osmium, is 22,590 kg/m^3."""
    min_thickness_m: float = bounded(1e-4, ge=0)
    """A mesh thinner than this across its thinnest direction is refused as flat (no volume)."""


@dataclass(frozen=True)
class DecomposeParams(Checked):
    """Stage ``decompose``: CoACD convex decomposition into MuJoCo collision hulls."""

    threshold: float = bounded(0.08, gt=0)
    """CoACD concavity threshold (lower: more, tighter hulls; slower)."""
    max_hulls: int = bounded(24, ge=1)
    max_hull_vertices: int = bounded(64, ge=4)
    """MuJoCo collides small hulls fastest; CoACD decimates each hull to this many vertices."""
    preprocess_resolution: int = bounded(30, ge=1)
    mcts_iterations: int = bounded(60, ge=1)
    mcts_depth: int = bounded(2, ge=1)
    mcts_nodes: int = bounded(10, ge=1)
    sample_resolution: int = bounded(1000, ge=1)
    convex_ratio: float = bounded(0.97, gt=0, le=1)
    """A mesh with at least this fraction of its hull's volume becomes one hull (no CoACD)."""
    seed: int = bounded(0, ge=0)
    max_faces: int = bounded(50_000, ge=1000)
    """Larger meshes are decomposed from a coarser copy of this many triangles (mesh.reduced)."""


@dataclass(frozen=True)
class MJCFParams(Checked):
    """Stage ``mjcf``: the per-object MuJoCo model.

    ``friction``, ``condim``, ``solref`` and ``solimp`` are the object's contact parameters
    everywhere: ``mjcf.py`` writes them on every collision hull geom of the MJCF, geomprep's
    settle check simulates that MJCF as written, and the trainer reads them from the MJCF and
    does not override them. Changing one here changes the object the trainer trains with.
    """

    # Defaults: the object material of ``geomgrasp.materials`` (shared with the trainer).
    friction: tuple[float, float, float] = bounded(materials.OBJECT.friction, ge=0)
    """Sliding, torsional, rolling friction of the collision hulls (MuJoCo ``geom/@friction``);
    the object's friction in the settle check and in the trainer."""
    condim: int = bounded(materials.OBJECT.condim, choices=(1, 3, 4, 6))
    """Contact dimensionality of the collision hulls (4: sliding plus torsional friction)."""
    solref: tuple[float, float] = materials.OBJECT.solref
    """Contact solver reference (time constant s, damping ratio) of the collision hulls."""
    solimp: tuple[float, float, float, float, float] = materials.OBJECT.solimp
    """Contact solver impedance (dmin, dmax, width m, midpoint, power) of the collision hulls."""
    settle_seconds: float = bounded(2.0, gt=0)
    """Simulated time for the settle check that validates the model."""

    def material(self) -> materials.ContactMaterial:
        """The object's contact material, as these fields set it."""
        return materials.ContactMaterial(
            friction=self.friction, condim=self.condim, solref=self.solref, solimp=self.solimp
        )


@dataclass(frozen=True)
class SDFParams(Checked):
    """Stage ``sdf``: the signed-distance grid (negative inside)."""

    resolution: int = bounded(200, ge=2)
    extent_m: float = bounded(0.5, gt=0)
    """The grid spans [-extent, extent]^3 around the object origin."""
    compression: str = bounded("gzip", choices=("gzip", "lzf"))


@dataclass(frozen=True)
class BBoxParams(Checked):
    """Stage ``bbox``: oriented bounding box along the principal axes."""

    max_faces: int = bounded(50_000, ge=1000)
    """Larger meshes run the min-volume axis search on a coarser copy of this many triangles
    (mesh.reduced); the covariance and the extents always use the full mesh."""


@dataclass(frozen=True)
class SQParams(Checked):
    """Stage ``sq``: superquadric fit by EMS plus the paper's surface term.

    The fields after ``n_points`` are ``superquadric.fit_superquadric``'s keyword arguments.
    """

    n_points: int = bounded(1500, ge=1)
    """Uniform surface samples the fit sees."""
    outlier_ratio: float = bounded(0.1, ge=0, le=1)
    """EMS's prior fraction of outlier points (uniform density)."""
    max_iters: int = bounded(30, ge=1)
    tol: float = bounded(1e-2, gt=0)
    """Convergence: relative parameter change below this ends the EM iterations."""
    max_switches: int = bounded(4, ge=0)
    switch_every: int = bounded(8, ge=1)
    m_step_nfev: int = bounded(15, ge=1)
    switch_nfev: int = bounded(12, ge=1)
    surface_weight: float = bounded(1.0, ge=0)
    """The paper's second loss term: weight of the distance of points sampled on the
    superquadric to the mesh surface (0 = EMS alone; keeps fits of bowls/mugs from bulging)."""
    surface_samples: int = bounded(200, ge=1)
    min_inlier_fraction: float = bounded(0.5, ge=0, le=1)
    """If the surface term leaves fewer inliers than this (the fit gave up on most of the
    object, e.g. a skillet lid), refit with ``surface_weight * fallback_weight_factor``."""
    fallback_weight_factor: float = bounded(0.3, ge=0)
    seed: int = bounded(0, ge=0)


@dataclass(frozen=True)
class PCParams(Checked):
    """Stage ``pc``: well-spread surface samples with normals."""

    sizes: tuple[int, ...] = bounded((32, 128, 512), ge=1)
    candidates: int = bounded(20000, ge=1)
    """Uniform area samples that farthest-point sampling picks from."""
    seed: int = bounded(0, ge=0)


@dataclass(frozen=True)
class BuildParams(Checked):
    """How builds run."""

    jobs: int = bounded(0, ge=0)
    """Parallel worker processes; 0 = all cores."""


@dataclass(frozen=True)
class Config(DataDirs):
    """The whole configuration: the data directory (``data_dir`` and its parts, from
    ``DataDirs``) and one section per stage."""

    mesh: MeshParams = field(default_factory=MeshParams)
    decompose: DecomposeParams = field(default_factory=DecomposeParams)
    mjcf: MJCFParams = field(default_factory=MJCFParams)
    sdf: SDFParams = field(default_factory=SDFParams)
    bbox: BBoxParams = field(default_factory=BBoxParams)
    sq: SQParams = field(default_factory=SQParams)
    pc: PCParams = field(default_factory=PCParams)
    build: BuildParams = field(default_factory=BuildParams)


def load_config(
    path: Path | None = None, data_dir: Path | None = None, sets: Sequence[str] = (),
) -> Config:
    """Defaults, overridden by the TOML file at ``path`` (or ./geomprep.toml if it exists), then
    by ``sets`` (``section.key=value`` as TOML reads the value, e.g. ``sdf.resolution=64``: the
    command line's ``--set``)."""
    values: dict[str, Any] = {}
    if path is None and Path(DEFAULT_CONFIG_NAME).is_file():
        path = Path(DEFAULT_CONFIG_NAME)
    if path is not None:
        values = read_toml(path)
    given: dict[str, Any] = {}
    names: dict[str, str] = {}
    for text in sets:
        key, value = config_schema.parse_assignment(
            text, "--set", "sdf.resolution=64 (docs/building.md lists the stages' keys)",
            GeomprepError,
        )
        given[key], names[key] = config_schema.parse_value(value), f"--set {key}={value}"
    values = config_schema.merge_tables(values, config_schema.nested_sets(given))
    source = str(path) if path is not None else None
    cfg = build_dataclass(Config, values, source, names=names) if values else Config()
    return cfg if data_dir is None else dataclasses.replace(cfg, data_dir=Path(data_dir))


def params_dict(params: Any) -> dict[str, Any]:
    """A stage's parameters as a JSON-able dict (tuples become lists)."""
    return {
        k: list(v) if isinstance(v, tuple) else v for k, v in dataclasses.asdict(params).items()
    }
