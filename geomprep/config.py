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
import difflib
import functools
import json
import math
import os
import tomllib
import types
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar, Literal, Union, get_args, get_origin, get_type_hints

from geomprep.errors import GeomprepError

DEFAULT_CONFIG_NAME = "geomprep.toml"


# ---- dataclasses from TOML: the one loader of both configs (the trainer's too) ---------------


def bounded(
    default: Any,
    *,
    ge: float | None = None,
    gt: float | None = None,
    le: float | None = None,
    choices: tuple[Any, ...] | None = None,
) -> Any:
    """A dataclass field with a default and the values it accepts (for a tuple, every element),
    enforced by ``Checked.__post_init__`` however the dataclass is made (TOML, command line,
    config.json, ``dataclasses.replace``): ``substeps: int = bounded(10, ge=1)``."""
    limits = {"ge": ge, "gt": gt, "le": le, "choices": choices}
    return field(
        default=default, metadata={"limits": {k: v for k, v in limits.items() if v is not None}}
    )


def _within(value: Any, limits: dict[str, Any]) -> bool:
    try:
        return (
            ("choices" not in limits or value in limits["choices"])
            and ("ge" not in limits or value >= limits["ge"])
            and ("gt" not in limits or value > limits["gt"])
            and ("le" not in limits or value <= limits["le"])
        )
    except TypeError:  # a value of the wrong type, passed from code
        return False


def _limits_text(limits: dict[str, Any]) -> str:
    if "choices" in limits:
        return "one of " + ", ".join(toml_value(c) for c in limits["choices"])
    words = {"ge": ">=", "gt": ">", "le": "<="}
    return " and ".join(f"{words[k]} {v}" for k, v in limits.items())


def field_error(
    error: type[Exception], name: str, value: Any, problem: str
) -> Exception:
    """``error`` saying field ``name`` (holding ``value``) has ``problem``; the loader re-words it
    with where the value came from (file, section, key or command-line option)."""
    exc = error(f"{name} = {toml_value(value)}: {problem}")
    exc.config_field = name  # type: ignore[attr-defined]
    exc.config_problem = problem  # type: ignore[attr-defined]
    return exc


class Checked:
    """Base of a config dataclass: ``__post_init__`` enforces its fields' ``bounded`` limits,
    raising ``error`` (subclasses of other packages set their own)."""

    error: ClassVar[type[Exception]] = GeomprepError

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):  # type: ignore[arg-type]
            limits = f.metadata.get("limits")
            value = getattr(self, f.name)
            if not limits:
                continue
            if isinstance(value, tuple):
                if not all(_within(v, limits) for v in value):
                    text = f"each element must be {_limits_text(limits)}"
                    raise field_error(self.error, f.name, value, text)
            elif not _within(value, limits):
                raise field_error(self.error, f.name, value, f"must be {_limits_text(limits)}")


def toml_value(value: Any) -> str:
    """``value`` as it would be written in TOML (how messages quote what the user gave)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str | Path):
        return json.dumps(str(value))
    if isinstance(value, list | tuple):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    if isinstance(value, Mapping):
        return "{" + ", ".join(f"{k} = {toml_value(v)}" for k, v in value.items()) + "}"
    return repr(value)


class _WrongType(Exception):
    """A value that does not fit its annotation (the loader says where and what was expected,
    or the problem given as the exception's message)."""


def _convert(value: Any, tp: Any) -> Any:
    """``value`` as annotation ``tp`` wants it (lists become tuples, strings paths, integers
    floats), or ``_WrongType``. A bool is not an integer here, although Python says it is, and
    a float is finite (TOML's inf and nan would pass every limit or silently poison a run)."""
    origin, args = get_origin(tp), get_args(tp)
    if tp is Any:
        return value
    if origin is Literal:
        if any(value == a and type(value) is type(a) for a in args):
            return value
    elif origin is Union or origin is types.UnionType:
        for arg in args:
            if arg is type(None):
                if value is None:
                    return None
                continue
            try:
                return _convert(value, arg)
            except _WrongType:
                pass
    elif origin is tuple:
        if isinstance(value, list | tuple):
            if len(args) == 2 and args[1] is Ellipsis:
                return tuple(_convert(v, args[0]) for v in value)
            if len(value) == len(args):
                return tuple(_convert(v, a) for v, a in zip(value, args, strict=True))
    elif tp is bool:
        if isinstance(value, bool):
            return value
    elif tp is int:
        if isinstance(value, int) and not isinstance(value, bool):
            return value
    elif tp is float:
        if isinstance(value, int | float) and not isinstance(value, bool):
            try:
                number = float(value)
            except OverflowError:  # a TOML integer beyond any float
                raise _WrongType("is too large for a number") from None
            if not math.isfinite(number):
                raise _WrongType("must be a finite number (not inf or nan)")
            return number
    elif tp is str:
        if isinstance(value, str):
            return value
    elif tp is Path:
        if isinstance(value, str | os.PathLike):
            return Path(value)
    elif isinstance(tp, type) and isinstance(value, tp):
        return value
    raise _WrongType


_PLURALS = {bool: "booleans", int: "integers", float: "numbers", str: "strings", Path: "paths"}


def _describe(tp: Any) -> str:
    """Annotation ``tp`` in words, for "expected ..." messages."""
    origin, args = get_origin(tp), get_args(tp)
    if origin is Literal:
        return "one of " + ", ".join(toml_value(a) for a in args)
    if origin is Union or origin is types.UnionType:
        return " or ".join(_describe(a) for a in args if a is not type(None))
    if origin is tuple:
        if len(args) == 2 and args[1] is Ellipsis:
            return f"a list of {_PLURALS.get(args[0], _describe(args[0]))}"
        if len(set(args)) == 1 and args[0] in _PLURALS:
            return f"a list of {len(args)} {_PLURALS[args[0]]}"
        return f"a list of {len(args)} values ({', '.join(_describe(a) for a in args)})"
    if dataclasses.is_dataclass(tp):
        return "a table (a [section])"
    words = {
        bool: "true or false", int: "an integer", float: "a number", str: "a string",
        Path: "a path (a string)",
    }
    return words.get(tp, getattr(tp, "__name__", str(tp)))


@functools.cache
def _hints(cls: type) -> dict[str, Any]:
    return get_type_hints(cls)


def build_dataclass(
    cls: type,
    values: Mapping[str, Any],
    source: str | None,
    error: type[Exception] = GeomprepError,
    *,
    section: str = "",
    base: Any = None,
    names: Mapping[str, str] | None = None,
) -> Any:
    """Dataclass ``cls`` from ``values`` (a TOML table, a JSON object or overrides), each value
    checked against the field's annotation and converted (see ``_convert``); a value that is a
    table fills a nested dataclass field. Fields not in ``values`` keep their defaults, or their
    values in ``base`` if given (overrides of a loaded config).

    A bad value raises ``error`` with one line naming where it came from: ``source`` (the file;
    None for overrides from the command line or code), the ``section`` (dotted), the key, the
    value, what was expected and the default as an example. ``names`` maps a key (dotted from
    ``section``) to the command-line option that set it, named instead: ``--seed -1: ...``.
    """
    place = " ".join(p for p in (source, f"[{section}]" if section else "") if p)
    if not isinstance(values, Mapping):
        raise error(
            f"{' '.join(p for p in (source, section) if p)} = {toml_value(values)}: expected a "
            f"table: write it as a [{section}] section"
        )
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}

    def label(key: str, value: Any) -> str:
        path = f"{section}.{key}" if section else key
        if names and path in names:
            return f"{names[path]} {value}"
        return f"{place} {key} = {toml_value(value)}".strip()

    def example(key: str) -> str:
        default = fields[key].default
        if source is None or default is dataclasses.MISSING:
            return ""
        return f" (the default: {key} = {toml_value(default)})"

    kwargs: dict[str, Any] = {}
    for key, value in values.items():
        if key not in fields:
            what = f"section [{key}]" if isinstance(value, Mapping) else f"key {key!r}"
            close = difflib.get_close_matches(key, fields, n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            raise error(
                f"{place + ': ' if place else ''}unknown {what}{hint}: "
                f"valid keys are {', '.join(fields) or 'none'}"
            )
        tp = _hints(cls)[key]
        if dataclasses.is_dataclass(tp) and isinstance(value, Mapping):
            kwargs[key] = build_dataclass(
                tp, value, source, error, section=f"{section}.{key}" if section else key,
                base=None if base is None else getattr(base, key), names=names,
            )
            continue
        try:
            kwargs[key] = _convert(value, tp)
        except _WrongType as exc:
            problem = str(exc) or f"expected {_describe(tp)}"
            raise error(f"{label(key, value)}: {problem}{example(key)}") from None
    try:
        return dataclasses.replace(base, **kwargs) if base is not None else cls(**kwargs)
    except error as exc:
        # A limit of __post_init__: say where the value came from (the field is in ``values``
        # unless a check spans fields).
        key = getattr(exc, "config_field", None)
        if key in values:
            problem = exc.config_problem  # type: ignore[attr-defined]
            raise error(f"{label(key, values[key])}: {problem}{example(key)}") from None
        if place and getattr(exc, "config_field", None):
            raise error(f"{place}: {exc}") from None
        raise


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

    friction: tuple[float, float, float] = bounded((1.0, 0.01, 0.0001), ge=0)
    """Sliding, torsional, rolling friction of the collision hulls (MuJoCo ``geom/@friction``);
    the object's friction in the settle check and in the trainer."""
    condim: int = bounded(4, choices=(1, 3, 4, 6))
    """Contact dimensionality of the collision hulls (4: sliding plus torsional friction)."""
    solref: tuple[float, float] = (0.01, 1.0)
    """Contact solver reference (time constant s, damping ratio) of the collision hulls."""
    solimp: tuple[float, float, float, float, float] = (0.9, 0.95, 0.001, 0.5, 2.0)
    """Contact solver impedance (dmin, dmax, width m, midpoint, power) of the collision hulls."""
    settle_seconds: float = bounded(2.0, gt=0)
    """Simulated time for the settle check that validates the model."""


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


def read_toml(path: Path, error: type[Exception] = GeomprepError) -> dict[str, Any]:
    """The TOML file at ``path`` as a dict; a missing or malformed file raises ``error`` with a
    one-line message (the trainer passes its own error type)."""
    try:
        return tomllib.loads(Path(path).read_text(encoding="utf-8"))  # TOML is UTF-8
    except FileNotFoundError:
        raise error(f"config file not found: {path}: check the --config path") from None
    except UnicodeDecodeError as exc:
        raise error(
            f"config file {path} is not UTF-8 text (byte {exc.start} cannot be read): save it "
            "as UTF-8"
        ) from None
    except OSError as exc:
        raise error(f"cannot read config file {path}: {exc.strerror or exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise error(f"config file {path} is not valid TOML: {exc}") from None


def load_config(path: Path | None = None, data_dir: Path | None = None) -> Config:
    """Defaults, overridden by the TOML file at ``path`` (or ./geomprep.toml if it exists)."""
    values: dict[str, Any] = {}
    if path is None and Path(DEFAULT_CONFIG_NAME).is_file():
        path = Path(DEFAULT_CONFIG_NAME)
    if path is not None:
        values = read_toml(path)
    cfg = build_dataclass(Config, values, str(path)) if values else Config()
    return cfg if data_dir is None else dataclasses.replace(cfg, data_dir=Path(data_dir))


def params_dict(params: Any) -> dict[str, Any]:
    """A stage's parameters as a JSON-able dict (tuples become lists)."""
    return {
        k: list(v) if isinstance(v, tuple) else v for k, v in dataclasses.asdict(params).items()
    }
