"""The stage graph, content-hash caching and the parallel build.

Stages and what they read::

    raw source ─ mesh ─┬─ decompose ─ mjcf (also reads mesh)
                       ├─ sdf
                       ├─ bbox
                       ├─ sq
                       └─ pc
    all seven ─ pack ─> processed/<name>.h5

A stage's cache key hashes its name, code version, parameters and the cache keys of its inputs
(the mesh stage: the source file's SHA-256 and its mass). Keys chain, so a changed source reruns
everything downstream and a changed SDF parameter reruns only ``sdf`` and ``pack``.

A stage is skipped only if its record (``interim/<name>/<stage>.record.json``, see ``cache``)
carries the expected key and every file it lists is still intact: the stage file, and for
``mjcf`` the model directory, for ``pack`` ``processed/<name>.h5``. A deleted, truncated or
rewritten output makes its stage ``invalid`` and it is rebuilt. The processed outputs of an
object whose build fails are removed unless they are still current, and
``contract.verify_processed`` (used by the trainer) refuses processed files that do not match
their record or whose source has changed since.
"""

from __future__ import annotations

import contextlib
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
from geomgrasp.files import atomic_path
from geomprep import (
    bbox,
    builtin,
    cache,
    contract,
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
    workers,
)
from geomprep.config import Config, params_dict
from geomprep.contract import (  # noqa: F401 (geomprep's commands and tests use them from here)
    identity,
    source_identity,
    verify_processed,
)
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
        return contract.processed_path(cfg, name)
    return cfg.interim_dir / name / f"{stage}.h5"


def stage_params(cfg: Config, stage: str) -> dict[str, Any]:
    return {} if stage == "pack" else params_dict(getattr(cfg, stage))


def _hash(payload: Any) -> str:
    return hashlib.sha256(json.dumps(payload, sort_keys=True).encode()).hexdigest()[:32]


def _rel(cfg: Config, path: Path) -> str:
    return cache.relative(cfg.data_dir, path)


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


def stage_outputs(cfg: Config, name: str, stage: str) -> list[Path]:
    """The files a finished stage has written, all of which its record covers."""
    outputs = [stage_path(cfg, name, stage)]
    if stage == "mjcf":
        model_dir = cfg.processed_dir / name
        outputs += sorted(p for p in model_dir.rglob("*") if p.is_file())
    return outputs


def check_stage(
    cfg: Config, name: str, stage: str, key: str, refresh: bool = False
) -> tuple[str, str | None]:
    """(status, why) of one stage's output, status one of

    - ``missing``: no output file;
    - ``stale``: made from other inputs or parameters, or not recorded (written by an older
      geomprep, or a build killed between writing the output and its record);
    - ``invalid``: recorded with this key, but a file changed since (``why`` names it);
    - ``done``: recorded with this key and every recorded file is intact.

    ``refresh``: save the new mtimes of files found intact by hashing (copied or restored
    data) in the stage's mtimes sidecar, so that the next check is one ``stat`` per file again.
    """
    if not stage_path(cfg, name, stage).is_file():
        return "missing", None
    record = cache.read_record(cfg.interim_dir, name, stage)
    if record is None or record.get("key") != key:
        return "stale", None
    seen = json.dumps(record, sort_keys=True)
    problem = cache.check_record(cfg.data_dir, record)
    if problem:
        return "invalid", problem
    source = record.get("source")
    if stage == "mesh" and isinstance(source, dict):
        # The key matched, so the source was hashed to the recorded bytes (or took the fast path).
        with contextlib.suppress(OSError):
            source["mtime_ns"] = (cfg.data_dir / source["path"]).stat().st_mtime_ns
    if refresh and json.dumps(record, sort_keys=True) != seen:
        cache.save_mtimes(cfg.interim_dir, name, stage, record)
    return "done", None


def stage_status(cfg: Config, name: str) -> dict[str, str]:
    """Per stage (and pack): 'done', 'stale', 'invalid' or 'missing' (see ``check_stage``)."""
    keys = expected_keys(cfg, name)
    return {stage: check_stage(cfg, name, stage, key)[0] for stage, key in keys.items()}


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
        contract.MESH_MASS: norm.mass_kg,
        "volume_m3": norm.volume_m3,
        "watertight": norm.watertight,
        "source_sha256": hashing.file_sha256(path),
        "com_offset": norm.com_offset.astype(np.float64),
        "com_method": norm.com_method,
        "mass_source": "masses.csv" if source.get("mass_kg") is not None else "density",
    }
    return {
        contract.GROUP_MESH: (
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
    return {contract.GROUP_DECOMPOSITION: (decompose.pack_hulls(hulls), attrs)}


def run_mjcf(cfg: Config, name: str) -> Groups:
    mesh_arrays, mesh_attrs = store.read_group(stage_path(cfg, name, "mesh"), "mesh")
    visual, _ = store.read_group(stage_path(cfg, name, "mesh"), "visual")
    hull_arrays, _ = store.read_group(stage_path(cfg, name, "decompose"), "decomposition")
    hulls = decompose.unpack_hulls(hull_arrays)
    final_dir = cfg.processed_dir / name
    with atomic_path(final_dir) as tmp_dir:
        tmp_dir.mkdir(parents=True)
        mjcf.write_model_dir(
            tmp_dir,
            name,
            float(mesh_attrs[contract.MESH_MASS]),
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
        contract.MJCF_XML: f"{name}/{name}.xml",
        "n_hulls": len(hulls),
        "settle_final_height_m": settle.final_height_m,
        "settle_lowest_point_m": settle.lowest_point_m,
        "settle_final_speed_m_s": settle.final_speed_m_s,
        "settle_start_height_m": settle.start_height_m,
        "settle_max_height_m": settle.max_height_m,
        "settled": settle.final_speed_m_s < 0.01
        and settle.max_height_m <= settle.start_height_m + 1e-3,
    }
    return {contract.GROUP_MJCF: ({}, attrs)}


def run_sdf(cfg: Config, name: str) -> Groups:
    vertices, faces = _load_mesh(cfg, name)
    grid = sdf.compute_sdf(vertices, faces, resolution=cfg.sdf.resolution, extent=cfg.sdf.extent_m)
    attrs = {
        contract.SDF_BOUNDS_MIN: grid.bounds_min.astype(np.float64),
        contract.SDF_BOUNDS_MAX: grid.bounds_max.astype(np.float64),
        contract.SDF_VOXEL_SIZE: float(grid.voxel_size),
        **grid.info,
    }
    return {contract.GROUP_SDF: ({contract.SDF_GRID: grid.grid}, attrs)}


def run_bbox(cfg: Config, name: str) -> Groups:
    vertices, faces = _load_mesh(cfg, name)
    center, rotation, extents = bbox.oriented_bbox(vertices, faces, cfg.bbox.max_faces)
    local = (vertices - center) @ rotation
    contained = np.all(np.abs(local) <= extents / 2 + 1e-6, axis=1)
    attrs = {"volume_m3": float(np.prod(extents)), "contained_fraction": float(contained.mean())}
    boxes = {
        contract.BBOX_CENTER: center,
        contract.BBOX_ROTATION: rotation,
        contract.BBOX_EXTENTS: extents,
    }
    return {contract.GROUP_BBOX: (boxes, attrs)}


def run_sq(cfg: Config, name: str) -> Groups:
    vertices, faces = _load_mesh(cfg, name)
    params, info = superquadric.fit_mesh(vertices, faces, cfg.sq)
    fitted = {contract.SQ_PARAMS: np.asarray(params, dtype=np.float64)}
    return {contract.GROUP_SUPERQUADRIC: (fitted, dict(info))}


def run_pc(cfg: Config, name: str) -> Groups:
    vertices, faces = _load_mesh(cfg, name)
    clouds = pointcloud.sample_pointclouds(
        vertices, faces, cfg.pc.sizes, cfg.pc.candidates, cfg.pc.seed
    )
    datasets: dict[str, np.ndarray] = {}
    for n, (points, normals) in clouds.items():
        datasets[contract.points_name(n)] = points
        datasets[contract.normals_name(n)] = normals
    return {contract.GROUP_POINTCLOUD: (datasets, {"sizes": list(cfg.pc.sizes)})}


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
    extra: dict[str, Any] = {}
    if stage == "mesh":
        source = rawstore.read_source(cfg.raw_dir, name)
        mesh_path = cfg.raw_dir / name / source["mesh"]
        if mesh_path.is_file():  # else run_mesh raises the user's error
            # Taken before the stage reads the source: if the file changes meanwhile, its mtime
            # no longer matches this entry and the next check hashes it again.
            entry = cache.file_entry(mesh_path)
            extra["source"] = {"path": _rel(cfg, mesh_path), **entry}
            extra["source_identity"] = identity(source, entry["sha256"])
    if stage == "pack":
        files = {s: stage_path(cfg, name, s) for s in STAGES}
        records = {s: cache.read_record(cfg.interim_dir, name, s) or {} for s in STAGES}
        extra["inputs"] = {s: records[s].get("key") for s in STAGES}
        extra["source_identity"] = records["mesh"].get("source_identity")
        store.pack(files, stage_path(cfg, name, "pack"), {**root, "contract": contract.CONTRACT})
    else:
        groups = RUNNERS[stage](cfg, name)
        compression = cfg.sdf.compression if stage == "sdf" else "gzip"
        store.write_stage(stage_path(cfg, name, stage), groups, root, compression=compression)
    cache.write_record(
        cfg.data_dir, cfg.interim_dir, name, stage, key, stage_outputs(cfg, name, stage), extra
    )
    return time.perf_counter() - start


# ---------------------------------------------------------------------------------------------
# Objects


def ensure_builtin(cfg: Config, names: Sequence[str]) -> None:
    """Write built-in objects into the raw store (once), through the ordinary import path
    (``importer.import_builtin``)."""
    importer.import_builtin(cfg.raw_dir, names)


def resolve_objects(cfg: Config, spec: str | Sequence[str] | None) -> list[str]:
    """The objects ``spec`` names (``contract.resolve_objects``: a comma list that may use the
    sets ``all``, ``builtin`` and ``ycb``), the built-in ones among them written into the raw
    store first if they are not there yet (``ensure_builtin``): what geomprep's commands build
    from."""
    names = contract.resolve_objects(cfg, spec)
    ensure_builtin(cfg, [n for n in names if n in builtin.NAMES])
    return names


# ---------------------------------------------------------------------------------------------
# Building


@dataclass
class BuildReport:
    """What a build did: per (object, stage) seconds for computed stages; skips; failures."""

    seconds: dict[tuple[str, str], float] = field(default_factory=dict)
    skipped: list[tuple[str, str]] = field(default_factory=list)
    failed: dict[str, str] = field(default_factory=dict)
    """object -> one-line error."""
    invalid: dict[tuple[str, str], str] = field(default_factory=dict)
    """(object, stage) -> which recorded output was damaged (the stage was rebuilt)."""
    removed: dict[str, list[Path]] = field(default_factory=dict)
    """failed object -> its out-of-date processed outputs, removed so nothing uses them."""


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
    all_keys: dict[str, dict[str, str]] = {}
    for name in names:
        try:
            keys = all_keys[name] = expected_keys(cfg, name)
        except GeomprepError as exc:
            report.failed[name] = str(exc)
            continue
        for stage in needed:
            status, problem = check_stage(cfg, name, stage, keys[stage], refresh=True)
            if problem is not None:
                report.invalid[(name, stage)] = problem
                log.warning("%s: %s: %s: rebuilding the stage", name, stage, problem)
            if status == "done" and not (force and stage in wanted):
                report.skipped.append((name, stage))
            else:
                todo[(name, stage)] = keys[stage]
    try:
        if todo:
            jobs = jobs if jobs else (cfg.build.jobs or os.cpu_count() or 1)
            _execute(cfg, todo, report, jobs, progress)
    finally:  # also after Ctrl-C: what failed must not be served as current
        for name in report.failed:
            removed = invalidate_processed(cfg, name, all_keys.get(name))
            if removed:
                report.removed[name] = removed
                log.info("%s: removed out-of-date %s", name, ", ".join(map(str, removed)))
    return report


def invalidate_processed(cfg: Config, name: str, keys: dict[str, str] | None) -> list[Path]:
    """Remove the processed outputs of ``name`` (``processed/<name>.h5``, the model directory)
    that were not made with ``keys`` (None: unknown, remove both), with their records; return
    what was removed. For an object whose build failed: its old outputs describe an old source
    or old parameters, and the trainer must not take them for current ones."""
    removed: list[Path] = []
    outputs = {"pack": stage_path(cfg, name, "pack"), "mjcf": cfg.processed_dir / name}
    for stage, path in outputs.items():
        record = cache.read_record(cfg.interim_dir, name, stage)
        if keys is not None and record is not None and record.get("key") == keys[stage]:
            continue
        # The record goes first: an output half removed by a crash is then unrecorded, and an
        # unrecorded output is never trusted.
        cache.remove_record(cfg.interim_dir, name, stage)
        if path.is_dir():
            shutil.rmtree(path)
            removed.append(path)
        elif path.exists():
            path.unlink()
            removed.append(path)
    return removed


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
            # The message itself is the caller's to print (the CLI's report), once.
            log.info("%s: %s failed", name, stage)
            if detail:
                log.info("%s", detail)
            for other in [i for i in pending if i[0] == name]:  # its later stages cannot run
                del pending[other]
                bar.update(1)

    if jobs <= 1:
        try:
            while pending:
                item = next(i for i in pending if ready(i))
                del pending[item]
                finish(item, *_guarded_run(cfg, item[0], item[1], todo[item]))
        finally:
            bar.close()
        return

    ctx = multiprocessing.get_context("spawn")
    with _single_threaded_children():
        # workers.init: the workers die with this process and leave Ctrl-C to it.
        pool = ProcessPoolExecutor(
            max_workers=jobs, mp_context=ctx, initializer=workers.init, initargs=(os.getpid(),)
        )
        try:
            while pending or running:
                for item in [i for i in pending if ready(i)]:
                    del pending[item]
                    with workers.sigint_blocked():  # a worker spawned here starts blocked
                        future = pool.submit(_guarded_run, cfg, item[0], item[1], todo[item])
                    running[future] = item
                done, _ = wait(running, return_when=FIRST_COMPLETED)
                for future in done:
                    finish(running.pop(future), *future.result())
        except BaseException:  # Ctrl-C (or a bug): stop the workers now, not after their stage
            workers.stop(pool)
            raise
        finally:
            pool.shutdown(wait=True, cancel_futures=True)
            bar.close()
