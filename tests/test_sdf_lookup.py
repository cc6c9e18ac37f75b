"""Tests for geomprep.sdf_lookup: exactness near the surface against open3d and an analytic box,
object poses (rotation + translation), the out-of-grid rule, mixed object ids in one batch, the
float16 error bound and the HDF5 loader; both query kernels (the C kernel of sdf_lookup_cpu and
torch ops) against the naive reference, eager and under torch.compile."""

from __future__ import annotations

import os
from pathlib import Path

import h5py
import numpy as np
import open3d as o3d
import pytest
import torch
import trimesh
from scipy.spatial.transform import Rotation

from geomgrasp.rotations import quat_to_matrix
from geomprep import sdf_lookup_cpu
from geomprep.errors import GeomprepError
from geomprep.sdf import SDFGrid, compute_sdf, voxel_centers
from geomprep.sdf_lookup import (
    FLOAT16_RELATIVE_ERROR,
    SDFLookup,
    bricks_per_axis,
    naive_query,
)

YCB_DIR = Path(
    os.environ.get("GEOMPREP_YCB_DIR", Path(__file__).resolve().parents[2] / "shared" / "ycb")
)
REQUIRED_ERROR_M = 1e-3
BOX_HALF = np.array([0.08, 0.05, 0.02])


KERNELS = ["auto", "torch"]  # the C kernel on this CPU, and torch ops (the GPU path)


def _lookup(*sdfs: SDFGrid, dtype: torch.dtype = torch.float32, kernel: str = "auto") -> SDFLookup:
    lookup = SDFLookup(
        np.stack([s.grid for s in sdfs]),
        np.stack([s.bounds_min for s in sdfs]),
        [s.voxel_size for s in sdfs],
        dtype=dtype,
        kernel=kernel,
    )
    assert lookup.use_cpu_kernel == (kernel == "auto")
    return lookup


def _pose(seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A random pose: (3, 3) rotation, (3,) position (m), (4,) quaternion (w, x, y, z)."""
    rot = Rotation.random(random_state=seed)
    xyzw = rot.as_quat()
    pos = np.random.default_rng(seed).uniform(-0.5, 0.5, 3)
    return rot.as_matrix(), pos, np.r_[xyzw[3], xyzw[:3]]


def _query_world(
    lookup: SDFLookup, world: np.ndarray, pos: np.ndarray, quat: np.ndarray, obj: int = 0
) -> np.ndarray:
    """Query (K, 3) world points of one env holding object obj: (K,) float64."""
    got = lookup.query(
        torch.tensor(world[None], dtype=torch.float32),
        torch.tensor(pos[None], dtype=torch.float32),
        torch.tensor(quat[None], dtype=torch.float32),
        torch.tensor([obj]),
    )
    return got[0].double().numpy()


def _box_truth(local: np.ndarray) -> np.ndarray:
    q = np.abs(local) - BOX_HALF
    return np.linalg.norm(np.maximum(q, 0), axis=-1) + np.minimum(q.max(axis=-1), 0)


@pytest.fixture(scope="module")
def box() -> SDFGrid:
    # 5 mm voxels like the full grid, on a smaller cube for speed.
    mesh = trimesh.creation.box(extents=2 * BOX_HALF)
    return compute_sdf(mesh.vertices, mesh.faces, resolution=80, extent=0.2)


@pytest.fixture(scope="module")
def sphere() -> SDFGrid:
    mesh = trimesh.creation.icosphere(subdivisions=5, radius=0.06)
    return compute_sdf(mesh.vertices, mesh.faces, resolution=60, extent=0.15)


def test_cpu_kernel_builds() -> None:
    # The tests of kernel "auto" below would silently test the torch path without it.
    assert sdf_lookup_cpu.kernel() is not None, "no C compiler: install gcc (see README)"


@pytest.mark.parametrize("kernel", KERNELS)
def test_box_rotated_translated_matches_analytic(box: SDFGrid, kernel: str) -> None:
    lookup = _lookup(box, kernel=kernel)
    rot, pos, quat = _pose(1)
    rng = np.random.default_rng(0)
    # Points within 3 cm of the box, inside and out, placed in the world by the pose.
    local = rng.uniform(-(BOX_HALF + 0.03), BOX_HALF + 0.03, size=(20000, 3))
    truth = _box_truth(local)
    got = _query_world(lookup, local @ rot.T + pos, pos, quat)
    err = np.abs(got - truth)
    # 5 mm voxels cannot resolve a sharp edge: within a voxel or two of one (and of the medial
    # creases inside) trilinear interpolation is off by up to ~2.5 mm.  Away from the edges,
    # off a face, the field is linear and only the grid's own error remains.
    margin = 2 * box.voxel_size
    gap = np.sort(BOX_HALF - np.abs(local), axis=1)  # distances to the 3 nearest face planes
    flat_out = (gap[:, 0] < 0) & (gap[:, 1] > margin)
    flat_in = (gap[:, 0] > 0) & (gap[:, 1] - gap[:, 0] > 2 * margin)
    off_face = (np.abs(truth) < 0.01) & (flat_out | flat_in)
    assert off_face.sum() > 1000
    assert np.max(err[off_face]) <= 5e-4
    # Outside, 5 mm or more from the box, the curvature 1/d keeps the error under 1 mm.
    away = truth >= 0.005
    assert np.max(err[away]) <= REQUIRED_ERROR_M


def test_ycb_rotated_matches_open3d() -> None:
    # A smooth solid object: near thin walls (mug, plate) 5 mm voxels put both sides of the wall
    # in one cell and trilinear values are off by up to ~2.5 mm there (the grid is flagged thin).
    path = YCB_DIR / "017_orange" / "google_16k" / "textured.obj"
    if not path.exists():
        pytest.skip(f"YCB mesh {path} not found: set GEOMPREP_YCB_DIR to the YCB folder")
    loaded = trimesh.load(path, force="mesh")
    mesh = trimesh.Trimesh(loaded.vertices, loaded.faces)
    mesh.apply_translation(-mesh.center_mass)
    sdf = compute_sdf(mesh.vertices, mesh.faces)
    rot, pos, quat = _pose(2)
    world_mesh = mesh.copy()
    world_mesh.apply_transform(np.block([[rot, pos[:, None]], [np.zeros((1, 3)), np.ones((1, 1))]]))
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(
        o3d.core.Tensor(np.asarray(world_mesh.vertices, dtype=np.float32)),
        o3d.core.Tensor(np.asarray(world_mesh.faces, dtype=np.uint32)),
    )
    # Points 2-20 mm off the surface along the normal, both sides, in the world frame.
    samples, face = trimesh.sample.sample_surface(world_mesh, 20000, seed=0)
    offset = np.random.default_rng(0).uniform(-0.02, 0.02, (len(samples), 1))
    world = samples + offset * world_mesh.face_normals[face]
    exact = scene.compute_signed_distance(
        o3d.core.Tensor(world.astype(np.float32)), nsamples=7
    ).numpy()
    keep = np.abs(exact) > 0.002
    err = np.abs(_query_world(_lookup(sdf), world[keep], pos, quat) - exact[keep])
    assert np.max(err[exact[keep] > 0]) <= REQUIRED_ERROR_M
    # Inside, the interior's creases (medial axis) cost a little more at a few points.
    assert np.quantile(err, 0.99) <= REQUIRED_ERROR_M
    assert np.max(err) <= 2 * REQUIRED_ERROR_M


@pytest.mark.parametrize("kernel", KERNELS)
def test_out_of_grid_returns_closest_voxel(sphere: SDFGrid, kernel: str) -> None:
    lookup = _lookup(sphere, kernel=kernel)
    r, extent = sphere.grid.shape[0], float(sphere.bounds_max[0])
    c = voxel_centers(r, extent)
    local = np.array([[2.0, 0.001, -0.031], [-0.5, 0.5, 0.4], [0.001, c[7] + 0.001, 0.151]])
    ident = np.array([1.0, 0, 0, 0])
    got = _query_world(lookup, local, np.zeros(3), ident)
    expect = [
        sphere.grid[r - 1, np.argmin(np.abs(c - 0.001)), np.argmin(np.abs(c + 0.031))],
        sphere.grid[0, r - 1, r - 1],
        sphere.grid[np.argmin(np.abs(c - 0.001)), 7, r - 1],
    ]
    np.testing.assert_allclose(got, expect, atol=1e-7)
    # Just inside the cube, beyond the outermost centres: the coordinate is clamped.
    edge = np.array([[extent - 1e-4, c[10], c[20]]])
    np.testing.assert_allclose(
        _query_world(lookup, edge, np.zeros(3), ident), [sphere.grid[r - 1, 10, 20]], atol=1e-7
    )


@pytest.mark.parametrize("kernel", KERNELS)
def test_batched_mixed_ids_match_naive(box: SDFGrid, kernel: str) -> None:
    # One stack needs one resolution: a second object on the box's grid.
    mesh = trimesh.creation.icosphere(subdivisions=4, radius=0.05)
    small = compute_sdf(mesh.vertices, mesh.faces, resolution=80, extent=0.2)
    lookup = _lookup(box, small, kernel=kernel)
    rng = np.random.default_rng(0)
    n_env, k = 64, 5
    ids = rng.integers(0, 2, n_env)
    quats = Rotation.random(n_env, random_state=0).as_quat()[:, [3, 0, 1, 2]]
    pos = rng.uniform(-1, 1, (n_env, 3))
    local = rng.uniform(-0.25, 0.25, (n_env, k, 3))  # includes out-of-grid points
    rots = quat_to_matrix(torch.tensor(quats)).numpy()
    world = np.einsum("eij,ekj->eki", rots, local) + pos[:, None, :]
    got = lookup.query(
        torch.tensor(world, dtype=torch.float32),
        torch.tensor(pos, dtype=torch.float32),
        torch.tensor(quats, dtype=torch.float32),
        torch.tensor(ids),
    )
    assert got.shape == (n_env, k) and got.dtype == torch.float32
    grids = np.stack([box.grid, small.grid])
    expect = naive_query(
        grids, np.stack([box.bounds_min] * 2), np.full(2, box.voxel_size), local, ids
    )
    # float32 pose arithmetic moves points by ~1e-7 m; the field is 1-Lipschitz.
    np.testing.assert_allclose(got.numpy(), expect, atol=2e-6)


@pytest.mark.parametrize("kernel", KERNELS)
def test_float16_error_bound(box: SDFGrid, kernel: str) -> None:
    full, half = _lookup(box, kernel=kernel), _lookup(box, dtype=torch.float16, kernel=kernel)
    assert half.nbytes() * 2 == full.nbytes()
    rng = np.random.default_rng(1)
    local = torch.tensor(rng.uniform(-0.2, 0.2, (1, 50000, 3)), dtype=torch.float32)
    ids = torch.tensor([0])
    a, b = full.query_local(local, ids), half.query_local(local, ids)
    # The largest corner is at most one cell diagonal (field slope ~1) above the value.
    bound = FLOAT16_RELATIVE_ERROR * (a.abs() + np.sqrt(3) * box.voxel_size) + 1e-7
    assert torch.all((a - b).abs() <= bound)
    assert float((a - b).abs().max()) <= 0.43e-3


def test_from_hdf5_roundtrip(tmp_path: Path, box: SDFGrid) -> None:
    paths = []
    for name, sdf in (("a_box", box), ("b_box", box)):
        path = tmp_path / f"{name}.h5"
        with h5py.File(path, "w") as f:
            g = f.create_group("sdf")
            g.create_dataset("grid", data=sdf.grid, chunks=(16, 16, 16), compression="gzip")
            g.attrs["bounds_min"] = sdf.bounds_min.astype(np.float64)
            g.attrs["bounds_max"] = sdf.bounds_max.astype(np.float64)
            g.attrs["voxel_size"] = sdf.voxel_size
        paths.append(path)
    lookup = SDFLookup.from_hdf5(paths, dtype=torch.float16)
    assert lookup.names == ["a_box", "b_box"] and lookup.dtype == torch.float16
    assert lookup.resolution == 80 and lookup.grid(1).shape == (80, 80, 80)
    np.testing.assert_allclose(lookup.grid(1).float().numpy(), box.grid, rtol=2**-11, atol=1e-7)
    np.testing.assert_allclose(lookup.inv_voxel.numpy(), 1 / box.voxel_size, rtol=1e-6)


@pytest.mark.parametrize("kernel", KERNELS)
def test_query_input_layouts_and_dtypes(box: SDFGrid, kernel: str) -> None:
    # float64, non-contiguous and int32 inputs give the float32 result; inputs are not modified.
    lookup = _lookup(box, kernel=kernel)
    rng = np.random.default_rng(2)
    n_env, k = 33, 4
    quats = torch.tensor(Rotation.random(n_env, random_state=2).as_quat()[:, [3, 0, 1, 2]])
    pos = torch.tensor(rng.uniform(-1, 1, (n_env, 3)))
    local = rng.uniform(-0.15, 0.15, (n_env, k, 3))
    world = torch.einsum("eij,ekj->eki", quat_to_matrix(quats), torch.tensor(local)) + pos[:, None]
    ids = torch.zeros(n_env, dtype=torch.long)
    ref = lookup.query(world.float(), pos.float(), quats.float(), ids)
    assert ref.shape == (n_env, k) and ref.dtype == torch.float32 and ref.is_contiguous()
    # Non-contiguous views of the same values: every other row of a doubled batch.
    world2 = world.repeat_interleave(2, dim=0)[::2]
    before = world2.clone()
    got = lookup.query(world2, pos.repeat_interleave(2, 0)[::2], 2.0 * quats, ids.int())
    assert got.dtype == torch.float32 and torch.equal(world2, before)
    np.testing.assert_allclose(got.numpy(), ref.numpy(), atol=1e-6)
    local_t = torch.tensor(local)
    np.testing.assert_allclose(
        lookup.query_local(local_t.transpose(0, 1).contiguous().transpose(0, 1), ids).numpy(),
        lookup.query_local(local_t.float(), ids).numpy(),
        atol=1e-7,
    )
    expect = naive_query(box.grid[None], box.bounds_min[None], [box.voxel_size], local, ids)
    np.testing.assert_allclose(ref.numpy(), expect, atol=2e-6)


@pytest.mark.parametrize("kernel", KERNELS)
@pytest.mark.parametrize("r", [2, 9, 10, 12, 13])
def test_bricks_hold_the_grid(r: int, kernel: str) -> None:
    # R - 1 cells a multiple of the brick size (9, 13) or not (the last brick is padded); the
    # dense grid comes back exactly, and every cell's lookup matches the naive one on it.
    rng = np.random.default_rng(r)
    grids = rng.normal(size=(2, r, r, r)).astype(np.float32)
    lookup = SDFLookup((g for g in grids), np.full((2, 3), -0.5), [1.0 / r] * 2, kernel=kernel)
    assert lookup.bricks.shape == (2, *(bricks_per_axis(r),) * 3, 128)
    for n in range(2):
        np.testing.assert_array_equal(lookup.grid(n).numpy(), grids[n])
    local = rng.uniform(-0.5, 0.5, (40, 6, 3))
    ids = rng.integers(0, 2, 40)
    got = lookup.query_local(torch.tensor(local, dtype=torch.float32), torch.tensor(ids))
    expect = naive_query(grids, np.full((2, 3), -0.5), np.full(2, 1.0 / r), local, ids)
    np.testing.assert_allclose(got.numpy(), expect, atol=1e-5)


def test_bad_grids_are_refused() -> None:
    cube = np.zeros((8, 8, 8), dtype=np.float32)
    bounds, voxel = np.zeros((2, 3)), [0.01, 0.01]
    with pytest.raises(GeomprepError, match="need \\(R, R, R\\)"):
        SDFLookup([cube, np.zeros((8, 8, 7))], bounds, voxel)
    with pytest.raises(GeomprepError, match="one SDF resolution"):
        SDFLookup([cube, np.zeros((9, 9, 9))], bounds, voxel)
    with pytest.raises(GeomprepError, match="1 SDF grids for 2 bounds"):
        SDFLookup([cube], bounds, voxel)


@pytest.mark.parametrize("kernel", KERNELS)
@pytest.mark.parametrize("n_env, k", [(1, 1), (3, 5), (129, 1), (300, 5), (70, 200)])
def test_partial_blocks_and_outer_centres_match_naive(
    sphere: SDFGrid, n_env: int, k: int, kernel: str
) -> None:
    # Batches that are not whole blocks or parallel tasks of the C kernel (128 points, 64 envs;
    # 200 points per env overflow a block within an env), with exact outer voxel centres (the
    # upper one needs the clamped cell) among interior points.
    lookup = _lookup(sphere, kernel=kernel)
    r = sphere.grid.shape[0]
    c = voxel_centers(r, float(sphere.bounds_max[0]))
    rng = np.random.default_rng(n_env * 10 + k)
    local = rng.uniform(c[0], c[-1], (n_env, k, 3))
    local.reshape(-1, 3)[0] = [c[-1], c[0], c[-1]]
    got = lookup.query_local(torch.tensor(local, dtype=torch.float32), torch.zeros(n_env))
    assert got.shape == (n_env, k) and got.is_contiguous()
    expect = naive_query(
        sphere.grid[None], sphere.bounds_min[None], [sphere.voxel_size], local, np.zeros(n_env)
    )
    np.testing.assert_allclose(got.numpy(), expect, atol=2e-6)
    assert abs(float(got[0, 0]) - float(sphere.grid[r - 1, 0, r - 1])) <= 2e-6


@pytest.mark.parametrize("kernel", KERNELS)
def test_nan_points_give_nan(sphere: SDFGrid, kernel: str) -> None:
    # A diverged simulation's NaN fingertip must not read a wrong voxel (or out of the stack).
    lookup = _lookup(sphere, kernel=kernel)
    local = torch.full((3, 2, 3), 0.03)
    local[1, 0, 2] = float("nan")
    got = lookup.query_local(local, torch.zeros(3, dtype=torch.long))
    assert torch.isnan(got[1, 0]) and torch.isnan(got).sum() == 1
    expect = naive_query(
        sphere.grid[None], sphere.bounds_min[None], [sphere.voxel_size], np.full((1, 1, 3), 0.03),
        np.zeros(1),
    )  # fmt: skip
    np.testing.assert_allclose(got[0].numpy(), np.full(2, expect[0, 0]), atol=2e-6)


def test_cpu_kernel_refuses_unknown_object_ids(sphere: SDFGrid) -> None:
    lookup = _lookup(sphere)
    with pytest.raises(GeomprepError, match="object id outside 0..0"):
        lookup.query_local(torch.zeros(4, 5, 3), torch.tensor([0, 1, 0, -1]))


@pytest.mark.parametrize("kernel", KERNELS)
def test_compiled_query_matches_eager(box: SDFGrid, kernel: str) -> None:
    # The trainer calls the lookup inside its torch.compile'd step: the C kernel is a custom op
    # (no graph break: fullgraph), the torch path is traced and fused.
    lookup = _lookup(box, kernel=kernel)
    rng = np.random.default_rng(5)
    n_env = 40
    quats = torch.tensor(Rotation.random(n_env, random_state=5).as_quat()[:, [3, 0, 1, 2]])
    world = torch.tensor(rng.uniform(-0.2, 0.2, (n_env, 5, 3)))
    pos = torch.tensor(rng.uniform(-0.1, 0.1, (n_env, 3)))
    args = (world.float(), pos.float(), quats.float(), torch.tensor(rng.integers(0, 1, n_env)))
    compiled = torch.compile(lookup.query, fullgraph=True, dynamic=False)
    np.testing.assert_allclose(compiled(*args).numpy(), lookup.query(*args).numpy(), atol=1e-6)


def test_missing_compiler_falls_back_to_torch(
    box: SDFGrid, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    monkeypatch.setenv("CC", str(tmp_path / "no-such-cc"))
    sdf_lookup_cpu.kernel.cache_clear()
    try:
        with pytest.warns(UserWarning, match="cannot build the SDF lookup's CPU kernel"):
            lookup = SDFLookup(box.grid[None], box.bounds_min[None], [box.voxel_size])
        assert not lookup.use_cpu_kernel and not list(tmp_path.rglob("*.so"))
        local = np.array([[[0.01, 0.02, 0.03]]])
        got = lookup.query_local(torch.tensor(local, dtype=torch.float32), torch.zeros(1))
        expect = naive_query(box.grid[None], box.bounds_min[None], [box.voxel_size], local, [0])
        np.testing.assert_allclose(got.numpy(), expect, atol=2e-6)
    finally:
        sdf_lookup_cpu.kernel.cache_clear()


def test_empty_batch(sphere: SDFGrid) -> None:
    lookup = _lookup(sphere)
    got = lookup.query(
        torch.zeros(0, 5, 3), torch.zeros(0, 3), torch.zeros(0, 4), torch.zeros(0, dtype=torch.long)
    )
    assert got.shape == (0, 5) and got.dtype == torch.float32


def test_from_hdf5_names_a_file_without_a_grid(tmp_path: Path) -> None:
    path = tmp_path / "no_sdf.h5"
    with h5py.File(path, "w") as f:
        f.create_group("mesh")
    with pytest.raises(GeomprepError, match="no_sdf.h5.*geomprep sdf") as err:
        SDFLookup.from_hdf5([path])
    assert "\n" not in str(err.value)
