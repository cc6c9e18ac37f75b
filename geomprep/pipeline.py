"""The stage graph, content-hash caching and the parallel build.

Stages and what they read::

    raw source ─ mesh ─┬─ decompose ─ mjcf (also reads mesh)
                       ├─ sdf
                       ├─ bbox
                       ├─ sq
                       └─ pc
    all seven ─ pack ─> processed/<name>.h5

A stage's cache key hashes its name, code version, parameters and the cache keys of its inputs
(the mesh stage: the source file's SHA-256 and its mass). A stage whose output file carries the
expected key is skipped; anything else is recomputed. Keys chain, so a changed source reruns
everything downstream and a changed SDF parameter reruns only ``sdf`` and ``pack``.
"""

from __future__ import annotations

import hashlib
import json
import logging
import multiprocessing
import os
import shutil
import time
import traceback
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

import geomprep
from geomprep import (
    bbox,
    builtin,
    decompose,
    hashing,
    importer,
    mesh,
    mjcf,
    pointcloud,
    rawstore,
    sdf,
    store,
    superquadric,
    ycb,
)
from geomprep.config import Config, params_dict
from geomprep.errors import GeomprepError

log = logging.getLogger("geomprep")

THREAD_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")

STAGES: tuple[str, ...] = ("mesh", "decompose", "mjcf", "sdf", "bbox", "sq", "pc")
DEPS: dict[str, tuple[str, ...]] = {
    "mesh": (),
    "decompose": ("mesh",),
    "mjcf": ("mesh", "decompose"),
    "sdf": ("mesh",),
    "bbox": ("mesh",),
    "sq": ("mesh",),
    "pc": ("mesh",),
    "pack": STAGES,
}
VERSIONS: dict[str, int] = {
    "mesh": mesh.VERSION,
    "decompose": decompose.VERSION,
    "mjcf": mjcf.VERSION,
    "sdf": sdf.VERSION,
    "bbox": bbox.VERSION,
    "sq": superquadric.VERSION,
    "pc": pointcloud.VERSION,
    "pack": 1,
}


# ---------------------------------------------------------------------------------------------
# Paths and keys


def stage_path(cfg: Config, name: str, stage: str) -> Path:
    """Where a stage's output lives; ``pack`` writes the contract's per-object file."""
    if stage == "pack":
        return cfg.processed_dir / f"{name}.h5"
    return cfg.interim_dir / name / f"{stage}.h5"


def stage_params(cfg: Config, stage: str) -> dict[str, Any]:
    return {} if stage == "pack" else params_dict(getattr(cfg, stage))


def _hash(payload: Any) -> str:
    return hashlib.sha256(json.dumps(payload, sort_keys=True).encode()).hexdigest()[:32]


def source_identity(cfg: Config, name: str) -> dict[str, Any]:
    """What the mesh stage's output depends on: the source file's bytes and the mass rule."""
    source = rawstore.read_source(cfg.raw_dir, name)
    mesh_path = cfg.raw_dir / name / source["mesh"]
    return {
        "mesh_sha256": hashing.file_sha256(mesh_path) if mesh_path.is_file() else "missing",
        "mass_kg": source.get("mass_kg"),
        "density_kg_m3": source.get("density_kg_m3"),
    }


def expected_keys(cfg: Config, name: str) -> dict[str, str]:
    """The cache key every stage of ``name`` must carry to count as up to date."""
    keys: dict[str, str] = {}
    for stage in (*STAGES, "pack"):
        inputs: dict[str, Any] = {dep: keys[dep] for dep in DEPS[stage]}
        if stage == "mesh":
            inputs["source"] = source_identity(cfg, name)
        keys[stage] = _hash(
            {
                "stage": stage,
                "version": VERSIONS[stage],
                "params": stage_params(cfg, stage),
                "inputs": inputs,
            }
        )
    return keys


def stage_status(cfg: Config, name: str) -> dict[str, str]:
    """Per stage (and pack): 'done', 'stale' (output from other inputs/params) or 'missing'."""
    keys = expected_keys(cfg, name)
    status = {}
    for stage, key in keys.items():
        attrs = store.read_root_attrs(stage_path(cfg, name, stage))
        status[stage] = (
            "missing" if attrs is None else "done" if attrs.get("cache_key") == key else "stale"
        )
    return status


# ---------------------------------------------------------------------------------------------
# Stage bodies: each reads its inputs from disk and returns the groups to write.

Groups = dict[str, tuple[dict[str, np.ndarray], dict[str, Any]]]


def _load_mesh(cfg: Config, name: str) -> tuple[np.ndarray, np.ndarray]:
    arrays, _ = store.read_group(stage_path(cfg, name, "mesh"), "mesh")
    return arrays["vertices"].astype(np.float64), arrays["faces"].astype(np.int64)


def run_mesh(cfg: Config, name: str) -> Groups:
    source = rawstore.read_source(cfg.raw_dir, name)
    path = cfg.raw_dir / name / source["mesh"]
    loaded = mesh.load_source(path)
    norm = mesh.normalize_mesh(
        loaded,
        cfg.mesh,
        source.get("mass_kg"),
        source.get("density_kg_m3"),
        label=f"object '{name}'",
    )
    visual: dict[str, np.ndarray] = {"vertices": norm.visual_vertices, "faces": norm.visual_faces}
    if norm.visual_uv is not None and norm.texture is not None:
        texture = norm.texture.copy()
        texture.thumbnail((cfg.mesh.texture_size, cfg.mesh.texture_size))
        visual["uv"] = norm.visual_uv
        visual["texture"] = np.asarray(texture, dtype=np.uint8)
    attrs = {
        "mass_kg": norm.mass_kg,
        "volume_m3": norm.volume_m3,
        "watertight": norm.watertight,
        "source_sha256": hashing.file_sha256(path),
        "com_offset": norm.com_offset.astype(np.float64),
        "com_method": norm.com_method,
        "mass_source": "masses.csv" if source.get("mass_kg") is not None else "density",
    }
    return {
        "mesh": (
            {"vertices": norm.vertices, "faces": norm.faces, "inertia": norm.inertia_kg_m2},
            attrs,
        ),
        "visual": (visual, {}),
    }


def run_decompose(cfg: Config, name: str) -> Groups:
    vertices, faces = _load_mesh(cfg, name)
    hulls = decompose.decompose(vertices, faces, cfg.decompose)
    outside = decompose.distance_outside_hulls(vertices, hulls)
    attrs = {
        "n_hulls": len(hulls),
        "max_hull_vertices": max(len(v) for v, _ in hulls),
        "covered_fraction_1mm": float(np.mean(outside <= 1e-3)),
        "max_outside_m": float(outside.max()),
    }
    return {"decomposition": (decompose.pack_hulls(hulls), attrs)}


def run_mjcf(cfg: Config, name: str) -> Groups:
    mesh_arrays, mesh_attrs = store.read_group(stage_path(cfg, name, "mesh"), "mesh")
    visual, _ = store.read_group(stage_path(cfg, name, "mesh"), "visual")
    hull_arrays, _ = store.read_group(stage_path(cfg, name, "decompose"), "decomposition")
    hulls = decompose.unpack_hulls(hull_arrays)
    final_dir = cfg.processed_dir / name
    with store.atomic_path(final_dir) as tmp_dir:
        tmp_dir.mkdir(parents=True)
        mjcf.write_model_dir(
            tmp_dir,
            name,
            float(mesh_attrs["mass_kg"]),
            mesh_arrays["inertia"].astype(np.float64),
            hulls,
            (visual["vertices"], visual["faces"], visual.get("uv")),
            visual.get("texture"),
            cfg.mjcf,
        )
        settle = mjcf.settle_on_plane(tmp_dir / f"{name}.xml", seconds=cfg.mjcf.settle_seconds)
        if final_dir.exists():  # os.replace cannot replace a non-empty directory
            shutil.rmtree(final_dir)
    attrs = {
        "xml": f"{name}/{name}.xml",
        "n_hulls": len(hulls),
        "settle_final_height_m": settle.final_height_m,
        "settle_lowest_point_m": settle.lowest_point_m,
        "settle_final_speed_m_s": settle.final_speed_m_s,
        "settle_start_height_m": settle.start_height_m,
        "settle_max_height_m": settle.max_height_m,
        "settled": settle.final_speed_m_s < 0.01
        and settle.max_height_m <= settle.start_height_m + 1e-3,
    }
    return {"mjcf": ({}, attrs)}


def run_sdf(cfg: Config, name: str) -> Groups:
    vertices, faces = _load_mesh(cfg, name)
    grid = sdf.compute_sdf(vertices, faces, resolution=cfg.sdf.resolution, extent=cfg.sdf.extent_m)
    attrs = {
        "bounds_min": grid.bounds_min.astype(np.float64),
        "bounds_max": grid.bounds_max.astype(np.float64),
        "voxel_size": float(grid.voxel_size),
        **grid.info,
    }
    return {"sdf": ({"grid": grid.grid}, attrs)}


def run_bbox(cfg: Config, name: str) -> Groups:
    vertices, faces = _load_mesh(cfg, name)
    center, rotation, extents = bbox.oriented_bbox(vertices, faces)
    local = (vertices - center) @ rotation
    contained = np.all(np.abs(local) <= extents / 2 + 1e-6, axis=1)
    attrs = {"volume_m3": float(np.prod(extents)), "contained_fraction": float(contained.mean())}
    return {"bbox": ({"center": center, "rotation": rotation, "extents": extents}, attrs)}


def run_sq(cfg: Config, name: str) -> Groups:
    vertices, faces = _load_mesh(cfg, name)
    params, info = superquadric.fit_mesh(vertices, faces, cfg.sq)
    return {"superquadric": ({"params": np.asarray(params, dtype=np.float64)}, dict(info))}


def run_pc(cfg: Config, name: str) -> Groups:
    vertices, faces = _load_mesh(cfg, name)
    clouds = pointcloud.sample_pointclouds(
        vertices, faces, cfg.pc.sizes, cfg.pc.candidates, cfg.pc.seed
    )
    datasets: dict[str, np.ndarray] = {}
    for n, (points, normals) in clouds.items():
        datasets[f"pc{n}"] = points
        datasets[f"normals_{n}"] = normals
    return {"pointcloud": (datasets, {"sizes": list(cfg.pc.sizes)})}


RUNNERS: dict[str, Callable[[Config, str], Groups]] = {
    "mesh": run_mesh,
    "decompose": run_decompose,
    "mjcf": run_mjcf,
    "sdf": run_sdf,
    "bbox": run_bbox,
    "sq": run_sq,
    "pc": run_pc,
}


def run_stage(cfg: Config, name: str, stage: str, key: str) -> float:
    """Run one stage of one object and write its output; return the seconds it took."""
    start = time.perf_counter()
    root = {
        "cache_key": key,
        "stage": stage,
        "object": name,
        "code_version": f"geomprep {geomprep.__version__}, {stage} v{VERSIONS[stage]}",
        "params": stage_params(cfg, stage),
    }
    if stage == "pack":
        files = {s: stage_path(cfg, name, s) for s in STAGES}
        store.pack(files, stage_path(cfg, name, "pack"), {**root, "contract": "geomprep/1"})
    else:
        groups = RUNNERS[stage](cfg, name)
        compression = cfg.sdf.compression if stage == "sdf" else "gzip"
        store.write_stage(stage_path(cfg, name, stage), groups, root, compression=compression)
    return time.perf_counter() - start


# ---------------------------------------------------------------------------------------------
# Objects


def resolve_objects(cfg: Config, spec: str | Sequence[str] | None) -> list[str]:
    """Object names from a comma list that may use the sets ``all``, ``builtin`` and ``ycb``.

    ``all`` (the default) is every imported object plus the built-in set. Built-in objects are
    written into the raw store on first use. Unknown names raise GeomprepError.
    """
    if spec is None:
        spec = "all"
    items = [s.strip() for s in (spec.split(",") if isinstance(spec, str) else spec) if s.strip()]
    imported = rawstore.complete_objects(cfg.raw_dir)
    names: list[str] = []
    for item in items:
        if item == "all":
            names += [*builtin.NAMES, *imported]
        elif item == "builtin":
            names += list(builtin.NAMES)
        elif item == "ycb":
            names += [n for n in imported if n in ycb.OBJECTS]
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
    names = list(dict.fromkeys(names))
    ensure_builtin(cfg, [n for n in names if n in builtin.NAMES])
    return names


def ensure_builtin(cfg: Config, names: Sequence[str]) -> None:
    """Write built-in objects into the raw store (once), through the ordinary import path."""
    missing = [n for n in names if not (cfg.raw_dir / n / "source.json").is_file()]
    if not missing:
        return
    staging = cfg.raw_dir / f".builtin-{os.getpid()}"
    staging.mkdir(parents=True, exist_ok=True)
    try:
        rows = ["object,mass_kg"]
        for name in missing:
            _, mass = builtin.write_source(name, staging)
            rows.append(f"{name},{mass}")
        (staging / "masses.csv").write_text("\n".join(rows) + "\n")
        importer.import_directory(staging, cfg.raw_dir, missing)
    finally:
        shutil.rmtree(staging, ignore_errors=True)


# ---------------------------------------------------------------------------------------------
# Building


@dataclass
class BuildReport:
    """What a build did: per (object, stage) seconds for computed stages; skips; failures."""

    seconds: dict[tuple[str, str], float] = field(default_factory=dict)
    skipped: list[tuple[str, str]] = field(default_factory=list)
    failed: dict[str, str] = field(default_factory=dict)
    """object -> one-line error."""


@contextmanager
def _single_threaded_children() -> Iterator[None]:
    """Environment for worker processes: each is one of --jobs parallel processes, so inner
    thread pools (OpenMP, BLAS) would oversubscribe the cores. Set before the workers start,
    because the libraries read it when they are imported."""
    saved = {var: os.environ.get(var) for var in THREAD_VARS}
    os.environ.update({var: "1" for var in THREAD_VARS})
    try:
        yield
    finally:
        for var, value in saved.items():
            if value is None:
                os.environ.pop(var, None)
            else:
                os.environ[var] = value


def _guarded_run(
    cfg: Config, name: str, stage: str, key: str
) -> tuple[float, str | None, str | None]:
    """run_stage, with any failure turned into (0, one-line message, traceback or None):
    a worker must not die, and the user sees one line per failed object."""
    logging.getLogger("trimesh").setLevel(logging.ERROR)
    try:
        return run_stage(cfg, name, stage, key), None, None
    except GeomprepError as exc:
        return 0.0, str(exc), None
    except Exception as exc:  # a bug or an unforeseen input: keep the traceback for -v
        return 0.0, f"{stage} failed: {type(exc).__name__}: {exc}", traceback.format_exc()


def build(
    cfg: Config,
    names: Sequence[str],
    stages: Sequence[str] | None = None,
    jobs: int | None = None,
    force: bool = False,
    progress: bool = True,
) -> BuildReport:
    """Bring the requested stages of the requested objects up to date (with their inputs).

    ``stages`` defaults to every stage and ``pack``. Independent stages of one object and all
    objects run in parallel on ``jobs`` processes (0 or None: the config's value, 0 = all cores).
    ``force`` recomputes the requested stages even when their cache key matches. Stages are
    deterministic, so a recomputed stage with an unchanged key leaves its dependents valid.
    """
    wanted = list(stages) if stages else [*STAGES, "pack"]
    report = BuildReport()
    needed = _with_dependencies(wanted)
    todo: dict[tuple[str, str], str] = {}  # (object, stage) -> key, for stages that must run
    for name in names:
        try:
            keys = expected_keys(cfg, name)
        except GeomprepError as exc:
            report.failed[name] = str(exc)
            continue
        for stage in needed:
            attrs = store.read_root_attrs(stage_path(cfg, name, stage))
            up_to_date = attrs is not None and attrs.get("cache_key") == keys[stage]
            if up_to_date and not (force and stage in wanted):
                report.skipped.append((name, stage))
            else:
                todo[(name, stage)] = keys[stage]
    if todo:
        _execute(
            cfg, todo, report, jobs if jobs else (cfg.build.jobs or os.cpu_count() or 1), progress
        )
    return report


def _with_dependencies(stages: Sequence[str]) -> list[str]:
    needed: list[str] = []

    def visit(stage: str) -> None:
        for dep in DEPS[stage]:
            visit(dep)
        if stage not in needed:
            needed.append(stage)

    for stage in stages:
        visit(stage)
    return needed


def _execute(
    cfg: Config, todo: dict[tuple[str, str], str], report: BuildReport, jobs: int, progress: bool
) -> None:
    """Run ``todo`` respecting dependencies, ``jobs`` at a time, with a progress bar."""
    from tqdm import tqdm

    pending = dict(todo)
    running: dict[Future, tuple[str, str]] = {}
    bar = tqdm(
        total=len(todo), desc="geomprep", unit="stage", disable=not progress, dynamic_ncols=True
    )

    def ready(item: tuple[str, str]) -> bool:
        name, stage = item
        return (
            name not in report.failed
            and all((name, dep) not in pending for dep in DEPS[stage])
            and all(
                running_item != (name, dep)
                for running_item in running.values()
                for dep in DEPS[stage]
            )
        )

    def finish(
        item: tuple[str, str], seconds: float, error: str | None, detail: str | None
    ) -> None:
        name, stage = item
        bar.update(1)
        if error is None:
            report.seconds[item] = seconds
            bar.set_postfix_str(f"{name} {stage} {seconds:.1f}s")
            log.info("%s: %s done in %.1f s", name, stage, seconds)
        else:
            report.failed[name] = error
            log.error("%s: %s", name, error)
            if detail:
                log.info("%s", detail)
            for other in [i for i in pending if i[0] == name]:  # its later stages cannot run
                del pending[other]
                bar.update(1)

    if jobs <= 1:
        while pending:
            item = next(i for i in pending if ready(i))
            del pending[item]
            finish(item, *_guarded_run(cfg, item[0], item[1], todo[item]))
        bar.close()
        return

    ctx = multiprocessing.get_context("spawn")
    with (
        _single_threaded_children(),
        ProcessPoolExecutor(max_workers=jobs, mp_context=ctx) as pool,
    ):
        while pending or running:
            for item in [i for i in pending if ready(i)]:
                del pending[item]
                running[pool.submit(_guarded_run, cfg, item[0], item[1], todo[item])] = item
            done, _ = wait(running, return_when=FIRST_COMPLETED)
            for future in done:
                finish(running.pop(future), *future.result())
    bar.close()
