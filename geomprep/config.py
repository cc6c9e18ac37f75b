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
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from geomprep.errors import GeomprepError

DEFAULT_CONFIG_NAME = "geomprep.toml"


@dataclass(frozen=True)
class MeshParams:
    """Stage ``mesh``: load, clean, check units, centre at the centre of mass."""

    density_kg_m3: float = 500.0
    """Fallback density for objects with no mass of their own (kg/m^3)."""
    min_extent_m: float = 0.005
    """A mesh smaller than this across (bounding-box diagonal) is rejected as not in metres."""
    max_extent_m: float = 1.0
    """A mesh larger than this across is rejected (millimetres?): it must fit the SDF grid."""
    merge_tolerance_m: float = 1e-7
    """Vertices closer than this are merged in the geometry mesh."""
    texture_size: int = 1024
    """The visual texture is resized to at most this many pixels a side (YCB ships 4096)."""


@dataclass(frozen=True)
class DecomposeParams:
    """Stage ``decompose``: CoACD convex decomposition into MuJoCo collision hulls."""

    threshold: float = 0.08
    """CoACD concavity threshold (lower: more, tighter hulls; slower)."""
    max_hulls: int = 24
    max_hull_vertices: int = 64
    """MuJoCo collides small hulls fastest; CoACD decimates each hull to this many vertices."""
    preprocess_resolution: int = 30
    mcts_iterations: int = 60
    mcts_depth: int = 2
    mcts_nodes: int = 10
    sample_resolution: int = 1000
    convex_ratio: float = 0.97
    """A mesh with at least this fraction of its hull's volume becomes one hull (no CoACD)."""
    seed: int = 0


@dataclass(frozen=True)
class MJCFParams:
    """Stage ``mjcf``: the per-object MuJoCo model."""

    friction: tuple[float, float, float] = (1.0, 0.005, 0.0001)
    """Sliding, torsional, rolling friction of the collision hulls."""
    condim: int = 4
    solref: tuple[float, float] = (0.01, 1.0)
    settle_seconds: float = 2.0
    """Simulated time for the settle check that validates the model."""


@dataclass(frozen=True)
class SDFParams:
    """Stage ``sdf``: the signed-distance grid (negative inside)."""

    resolution: int = 200
    extent_m: float = 0.5
    """The grid spans [-extent, extent]^3 around the object origin."""
    compression: str = "gzip"


@dataclass(frozen=True)
class BBoxParams:
    """Stage ``bbox``: oriented bounding box along the principal axes (no knobs yet)."""


@dataclass(frozen=True)
class SQParams:
    """Stage ``sq``: superquadric fit by EMS plus the paper's surface term.

    The fields after ``n_points`` are ``superquadric.fit_superquadric``'s keyword arguments.
    """

    n_points: int = 1500
    """Uniform surface samples the fit sees."""
    outlier_ratio: float = 0.1
    """EMS's prior fraction of outlier points (uniform density)."""
    max_iters: int = 30
    tol: float = 1e-2
    """Convergence: relative parameter change below this ends the EM iterations."""
    max_switches: int = 4
    switch_every: int = 8
    m_step_nfev: int = 15
    switch_nfev: int = 12
    surface_weight: float = 1.0
    """The paper's second loss term: weight of the distance of points sampled on the
    superquadric to the mesh surface (0 = EMS alone; keeps fits of bowls/mugs from bulging)."""
    surface_samples: int = 200
    min_inlier_fraction: float = 0.5
    """If the surface term leaves fewer inliers than this (the fit gave up on most of the
    object, e.g. a skillet lid), refit with ``surface_weight * fallback_weight_factor``."""
    fallback_weight_factor: float = 0.3
    seed: int = 0


@dataclass(frozen=True)
class PCParams:
    """Stage ``pc``: well-spread surface samples with normals."""

    sizes: tuple[int, ...] = (32, 128, 512)
    candidates: int = 20000
    """Uniform area samples that farthest-point sampling picks from."""
    seed: int = 0


@dataclass(frozen=True)
class BuildParams:
    """How builds run."""

    jobs: int = 0
    """Parallel worker processes; 0 = all cores."""


@dataclass(frozen=True)
class Config:
    """The whole configuration: the data directory and one section per stage."""

    data_dir: Path = Path("data")
    mesh: MeshParams = field(default_factory=MeshParams)
    decompose: DecomposeParams = field(default_factory=DecomposeParams)
    mjcf: MJCFParams = field(default_factory=MJCFParams)
    sdf: SDFParams = field(default_factory=SDFParams)
    bbox: BBoxParams = field(default_factory=BBoxParams)
    sq: SQParams = field(default_factory=SQParams)
    pc: PCParams = field(default_factory=PCParams)
    build: BuildParams = field(default_factory=BuildParams)

    @property
    def raw_dir(self) -> Path:
        return self.data_dir / "raw"

    @property
    def interim_dir(self) -> Path:
        return self.data_dir / "interim"

    @property
    def processed_dir(self) -> Path:
        return self.data_dir / "processed"


def _section(cls: type, values: dict[str, Any], where: str) -> Any:
    known = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(values) - set(known))
    if unknown:
        raise GeomprepError(
            f"{where}: unknown key(s) {', '.join(unknown)}: "
            f"valid keys are {', '.join(known) or 'none'}"
        )
    converted = {}
    for key, value in values.items():
        default = known[key].default
        converted[key] = tuple(value) if isinstance(default, tuple) else value
    return cls(**converted)


def read_toml(path: Path, error: type[Exception] = GeomprepError) -> dict[str, Any]:
    """The TOML file at ``path`` as a dict; a missing or malformed file raises ``error`` with a
    one-line message (the trainer passes its own error type)."""
    try:
        return tomllib.loads(Path(path).read_text())
    except FileNotFoundError:
        raise error(f"config file not found: {path}: check the --config path") from None
    except tomllib.TOMLDecodeError as exc:
        raise error(f"config file {path} is not valid TOML: {exc}") from None


def load_config(path: Path | None = None, data_dir: Path | None = None) -> Config:
    """Defaults, overridden by the TOML file at ``path`` (or ./geomprep.toml if it exists)."""
    values: dict[str, Any] = {}
    if path is None and Path(DEFAULT_CONFIG_NAME).is_file():
        path = Path(DEFAULT_CONFIG_NAME)
    if path is not None:
        values = read_toml(path)
    sections = {f.name: f for f in dataclasses.fields(Config)}
    kwargs: dict[str, Any] = {}
    for key, value in values.items():
        if key not in sections:
            raise GeomprepError(
                f"{path}: unknown section [{key}]: valid sections are {', '.join(sections)}"
            )
        if key == "data_dir":
            kwargs[key] = Path(value)
        else:
            kwargs[key] = _section(sections[key].default_factory, value, f"{path} [{key}]")
    if data_dir is not None:
        kwargs["data_dir"] = Path(data_dir)
    return Config(**kwargs)


def params_dict(params: Any) -> dict[str, Any]:
    """A stage's parameters as a JSON-able dict (tuples become lists)."""
    return {
        k: list(v) if isinstance(v, tuple) else v for k, v in dataclasses.asdict(params).items()
    }
