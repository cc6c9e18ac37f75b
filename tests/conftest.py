"""Shared fixtures: the YCB directory, and data directories built once per test session."""

from __future__ import annotations

import os

# MuJoCo chooses its OpenGL backend at first import; the rendering tests need EGL (no display).
os.environ.setdefault("MUJOCO_GL", "egl")
# Each test worker (README: 2 on 2 cores) gets its share of the cores for its OpenMP and BLAS
# thread pools, as each of geomprep's build processes gets one thread (pipeline.THREAD_VARS):
# torch's pool spinning on both cores for its tiny tensors took the other worker's turn (the
# same tests used 30 % more CPU time). Read when torch and numpy load, so set before them; a
# value given in the environment stays, and a run without workers keeps the libraries' own.
if "PYTEST_XDIST_WORKER_COUNT" in os.environ:
    _share = max(1, (os.cpu_count() or 1) // int(os.environ["PYTEST_XDIST_WORKER_COUNT"]))
    for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(_var, str(_share))

import fcntl  # noqa: E402
import hashlib  # noqa: E402
import shutil  # noqa: E402
from collections.abc import Iterator, Sequence  # noqa: E402
from importlib import metadata  # noqa: E402
from pathlib import Path  # noqa: E402

import pytest  # noqa: E402
import trimesh  # noqa: E402

from geomprep import builtin, importer, mesh, pipeline  # noqa: E402
from geomprep.config import Config  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def _find_ycb() -> Path:
    """$GEOMPREP_YCB_DIR, else a ``shared/ycb`` beside the checkout or inside it."""
    if "GEOMPREP_YCB_DIR" in os.environ:
        return Path(os.environ["GEOMPREP_YCB_DIR"])
    candidates = (ROOT.parent / "shared" / "ycb", ROOT / "shared" / "ycb")
    return next((c for c in candidates if c.is_dir()), candidates[0])


YCB_DIR = _find_ycb()
YCB_TEST_OBJECTS = ("032_knife", "062_dice", "025_mug", "029_plate")
GRASP_TEST_OBJECTS = ("077_rubiks_cube", "013_apple", "005_tomato_soup_can")
"""The objects the scripted grasp is held to (>= 8 of 10 lifted each)."""


def require_ycb() -> Path:
    if not (YCB_DIR / "032_knife" / "google_16k" / "textured.obj").is_file():
        pytest.skip(f"YCB models not found at {YCB_DIR} (set GEOMPREP_YCB_DIR)")
    return YCB_DIR


def ycb_mesh(name: str) -> trimesh.Trimesh:
    """A YCB object's cleaned geometry mesh in its object frame (origin at the COM), as the
    mesh stage makes it; skips the test if the YCB models are absent."""
    source = mesh.load_source(require_ycb() / name / "google_16k" / "textured.obj")
    norm = mesh.normalize_mesh(source, Config().mesh, None, 500.0, label=name)
    return trimesh.Trimesh(norm.vertices, norm.faces, process=False)


ONE_WORKER_MODULES = ("tests/test_warp.py",)
"""Test modules whose tests all run on one test worker, one after the other. MuJoCo Warp
compiles its kernels on a backend's first step and keeps them on disk: two workers that each
began with a Warp test compiled the same kernels side by side (45 s of a core each on a fresh
machine); on one worker the later tests load them."""


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_make_scheduler(config: pytest.Config, log: object) -> object:
    """With workers (README: ``-n 2``) and xdist's default ``load``: the tests of each of
    ``ONE_WORKER_MODULES`` as one unit of work, every other test a unit of its own (xdist's
    ``loadscope`` with these scopes). xdist's own ``loadgroup`` would do it with a mark, but
    with pytest 9 its workers no longer tag the test ids (they set ``_nodeid``, which pytest 9's
    ``nodeid`` does not read), so it ran the group's tests on both workers."""
    if config.getvalue("dist") != "load":
        return None  # another --dist: xdist's own scheduler
    from xdist.scheduler import LoadScopeScheduling

    class ModulesOnOneWorker(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            module = nodeid.partition("::")[0]
            return module if module in ONE_WORKER_MODULES else nodeid

    return ModulesOnOneWorker(config, log)


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """The tests marked ``slow`` run first (otherwise in their order): with workers (README:
    ``-n 2``) the longest ones then start early instead of one ending the run alone while the
    other worker has nothing left."""
    items.sort(key=lambda item: item.get_closest_marker("slow") is None)


TEST_SHADOW_SIZE = 256
"""Shadow map size (pixels a side) of the offscreen renders in the tests."""


@pytest.fixture(scope="session", autouse=True)
def small_shadow_maps() -> Iterator[None]:
    """Offscreen renderers get a 256² shadow map instead of the scene's 4096²: without a GPU
    (EGL's software rasterizer) drawing the 4096² map took ~95 % of a frame (0.1 s a tile even
    at 160x120). Shadows are still drawn, so the render path is the videos' own, and no test
    looks at a shadow; the model is only given a smaller ``vis.quality.shadowsize``."""
    import mujoco

    original = mujoco.Renderer.__init__

    def init(self, model: mujoco.MjModel, *args: object, **kwargs: object) -> None:
        model.vis.quality.shadowsize = min(model.vis.quality.shadowsize, TEST_SHADOW_SIZE)
        original(self, model, *args, **kwargs)

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(mujoco.Renderer, "__init__", init)
        yield


SDF_GRIDS_KEPT = 8
"""Dense SDF grids a test worker keeps in memory (32 MB each at 200^3)."""
SDF_LOOKUPS_KEPT_BYTES = 512 * 2**20
"""Bytes of built ``SDFLookup``s a test worker keeps (64 MB of bricks per object at 200^3)."""


@pytest.fixture(scope="session", autouse=True)
def sdf_read_once() -> Iterator[None]:
    """Every env builds an ``SDFLookup.from_hdf5`` of its objects' SDF grids, and reading and
    bricking 200^3 grids was about 90 % of an env's build: a third to a half of the time of the
    tests that build envs went into reading the same few files again. Here a test worker reads
    each file's grid once, and keeps the lookups it built: a file is known by its name, size
    and modification time (the copies of the built data directories keep those), so a changed
    or rebuilt file is read afresh. Each reader gets its own copy (of the grid, of the lookup),
    built by ``SDFLookup`` itself the first time; least recently used entries go first."""
    import copy
    import inspect
    from collections import OrderedDict

    import numpy as np

    from geomprep import sdf_lookup, sdf_lookup_cpu

    def file_key(path: str | Path) -> tuple[str, int, int]:
        stat = Path(path).stat()
        return Path(path).name, stat.st_size, stat.st_mtime_ns

    read_grid = sdf_lookup.read_sdf_grid
    grids: OrderedDict[tuple, np.ndarray] = OrderedDict()

    def read_grid_once(path: str | Path) -> np.ndarray:
        key = file_key(path)
        if key in grids:
            grids.move_to_end(key)
        else:
            grids[key] = read_grid(path)
            if len(grids) > SDF_GRIDS_KEPT:
                grids.popitem(last=False)
        return grids[key].copy()

    from_hdf5 = sdf_lookup.SDFLookup.from_hdf5.__func__
    signature = inspect.signature(from_hdf5)
    lookups: OrderedDict[tuple, sdf_lookup.SDFLookup] = OrderedDict()

    def from_hdf5_once(*args: object, **kwargs: object) -> sdf_lookup.SDFLookup:
        call = signature.bind(*args, **kwargs)
        call.apply_defaults()
        options = {k: v for k, v in call.arguments.items() if k not in ("cls", "paths")}
        try:
            files = tuple(file_key(p) for p in call.arguments["paths"])
        except OSError:  # a missing file: from_hdf5's own error
            return from_hdf5(*args, **kwargs)
        key = (call.arguments["cls"], files, *(str(v) for v in options.values()),
               sdf_lookup_cpu.kernel() is not None)
        if key in lookups:
            lookups.move_to_end(key)
            return copy.deepcopy(lookups[key])
        lookup = from_hdf5(*args, **kwargs)
        if lookup.nbytes() <= SDF_LOOKUPS_KEPT_BYTES:
            lookups[key] = copy.deepcopy(lookup)
            while sum(kept.nbytes() for kept in lookups.values()) > SDF_LOOKUPS_KEPT_BYTES:
                lookups.popitem(last=False)
        return lookup

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(sdf_lookup, "read_sdf_grid", read_grid_once)
        patch.setattr(sdf_lookup.SDFLookup, "from_hdf5", classmethod(from_hdf5_once))
        yield


# ---------------------------------------------------------------------------------------------
# Built data directories, cached across test sessions by content

PREBUILT_ENV = "GEOMGRASP_TEST_PREBUILT"
"""A folder of fixture data built elsewhere, ``<label>/data`` each (e.g. copied to a GPU machine
that lacks coacd and open3d): used as-is, without a content check, where present."""
CACHE_ENV = "GEOMGRASP_TEST_CACHE"
"""Where built fixture data is kept between sessions (default ~/.cache/geomgrasp/test-data);
``0`` or ``off`` builds everything afresh in every session."""
_KEY_PACKAGES = ("numpy", "scipy", "trimesh", "coacd", "open3d", "mujoco", "h5py", "manifold3d")


def _prebuilt(label: str) -> Path | None:
    """``$GEOMGRASP_TEST_PREBUILT/<label>/data`` where it exists."""
    path = Path(os.environ.get(PREBUILT_ENV, "")) / label / "data"
    return path if PREBUILT_ENV in os.environ and path.is_dir() else None


def _cache_root() -> Path | None:
    value = os.environ.get(CACHE_ENV, "")
    if value.lower() in ("0", "off", "no", "false"):
        return None
    return Path(value) if value else Path.home() / ".cache" / "geomgrasp" / "test-data"


def _content_key(names: Sequence[str], source_dir: Path | None) -> str:
    """Hash of everything a build's output depends on: geomprep's code, the versions of the
    libraries it calls, the object names and (for imported objects) their source files. Any
    change to one of these builds afresh, so a cached directory is what a build would make."""
    digest = hashlib.sha256()
    code = sorted(p for p in (ROOT / "geomprep").rglob("*") if p.suffix in (".py", ".c"))
    for path in code:
        digest.update(str(path.relative_to(ROOT)).encode() + b"\0" + path.read_bytes())
    for package in _KEY_PACKAGES:
        try:
            digest.update(f"{package}={metadata.version(package)}".encode())
        except metadata.PackageNotFoundError:
            digest.update(f"{package}=none".encode())
    digest.update(",".join(names).encode())
    if source_dir is not None:
        files = [source_dir / "masses.csv"] if (source_dir / "masses.csv").is_file() else []
        for name in names:
            files += sorted(p for p in (source_dir / name).rglob("*") if p.is_file())
        for path in files:
            digest.update(str(path.relative_to(source_dir)).encode() + b"\0" + path.read_bytes())
    return digest.hexdigest()[:20]


def build_fixture(cfg: Config, names: Sequence[str], source_dir: Path | None) -> None:
    """Build ``names`` into ``cfg.data_dir``, imported from ``source_dir`` first unless they
    are built-in (also scripts/prebuilt_fixtures.py, with a coarser SDF grid)."""
    if source_dir is not None:
        importer.import_directory(source_dir, cfg.raw_dir, list(names))
    resolved = pipeline.resolve_objects(cfg, list(names))
    report = pipeline.build(cfg, resolved, jobs=2, progress=False)
    assert not report.failed, report.failed


def built_data(
    tmp_path_factory: pytest.TempPathFactory,
    label: str,
    names: Sequence[str],
    source_dir: Path | None = None,
) -> Config:
    """A fresh data directory (a copy the test may change) with ``names`` built: imported from
    ``source_dir`` first unless they are built-in. The build is cached by content (see
    ``_content_key``) under ``$GEOMGRASP_TEST_CACHE``: a later session with the same code,
    libraries and sources copies it instead of building (a build of the YCB test objects takes
    about a minute on 2 cores, a copy a second)."""
    dest = tmp_path_factory.mktemp(label) / "data"
    prebuilt = _prebuilt(label)
    if prebuilt is not None:
        shutil.copytree(prebuilt, dest)
        return Config(data_dir=dest)
    root = _cache_root()
    if root is None:
        build_fixture(Config(data_dir=dest), names, source_dir)
        return Config(data_dir=dest)
    root.mkdir(parents=True, exist_ok=True)
    entry = root / f"{label}-{_content_key(names, source_dir)}"
    with open(root / f"{label}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # two sessions at once: one builds, the other waits
        if not (entry / "complete").is_file():
            staging = root / f".{entry.name}.tmp-{os.getpid()}"
            shutil.rmtree(staging, ignore_errors=True)
            build_fixture(Config(data_dir=staging / "data"), names, source_dir)
            (staging / "complete").write_text("built\n")
            for old in root.glob(f"{label}-*"):  # an older build of the same fixture
                shutil.rmtree(old, ignore_errors=True)
            os.replace(staging, entry)
    shutil.copytree(entry / "data", dest)  # copy2 keeps modification times
    return Config(data_dir=dest)


@pytest.fixture(scope="session")
def builtin_data(tmp_path_factory: pytest.TempPathFactory) -> Config:
    """A data directory with the whole built-in set built (all stages, packed)."""
    return built_data(tmp_path_factory, "builtin", builtin.NAMES)


def build_ycb(
    tmp_path_factory: pytest.TempPathFactory, label: str, names: tuple[str, ...]
) -> Config:
    """A data directory with ``names`` imported from YCB_DIR and built (skips the test if the
    YCB models are absent and no prebuilt copy is given)."""
    if _prebuilt(label) is not None:
        return built_data(tmp_path_factory, label, names)
    return built_data(tmp_path_factory, label, names, require_ycb())


@pytest.fixture(scope="session")
def ycb_data(tmp_path_factory: pytest.TempPathFactory) -> Config:
    """A data directory with the four test YCB objects imported from YCB_DIR and built."""
    return build_ycb(tmp_path_factory, "ycb", YCB_TEST_OBJECTS)


@pytest.fixture(params=["builtin", "ycb"])
def built(request: pytest.FixtureRequest) -> tuple[Config, list[str]]:
    """Both built data sets in turn, with their object names."""
    if request.param == "builtin":
        cfg = request.getfixturevalue("builtin_data")
        return cfg, list(builtin.NAMES)
    return request.getfixturevalue("ycb_data"), list(YCB_TEST_OBJECTS)
