"""Tests for geomprep.sdf: exactness against independent distance queries, sign robustness on
meshes with holes, the thin-object diagnosis and input errors."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import open3d as o3d
import pytest
import trimesh

from geomprep.errors import GeomprepError
from geomprep.sdf import SDFGrid, compute_sdf, voxel_centers

YCB_DIR = Path(
    os.environ.get("GEOMPREP_YCB_DIR", Path(__file__).resolve().parents[2] / "shared" / "ycb")
)
REQUIRED_ERROR_M = 5e-4


def _ycb(name: str) -> trimesh.Trimesh:
    """A YCB mesh moved so its centre of mass is the origin (metres); skip if absent."""
    path = YCB_DIR / name / "google_16k" / "textured.obj"
    if not path.exists():
        pytest.skip(f"YCB mesh {path} not found: set GEOMPREP_YCB_DIR to the YCB folder")
    loaded = trimesh.load(path, force="mesh")
    # Rebuild without the texture so vertices split at UV seams merge and watertightness shows.
    mesh = trimesh.Trimesh(loaded.vertices, loaded.faces)
    mesh.apply_translation(-mesh.center_mass)
    return mesh


def _scene(mesh: trimesh.Trimesh) -> o3d.t.geometry.RaycastingScene:
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(
        o3d.core.Tensor(np.asarray(mesh.vertices, dtype=np.float32)),
        o3d.core.Tensor(np.asarray(mesh.faces, dtype=np.uint32)),
    )
    return scene


def _sample_voxels(sdf: SDFGrid, n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Half near the surface (|d| < 2 cm), half uniform: (n, 3) int indices, (n, 3) centres."""
    rng = np.random.default_rng(seed)
    near = np.argwhere(np.abs(sdf.grid) < 0.02)
    pick_near = near[rng.choice(len(near), min(n // 2, len(near)), replace=False)]
    pick_any = rng.integers(0, sdf.grid.shape[0], size=(n - len(pick_near), 3))
    idx = np.concatenate([pick_near, pick_any])
    centers = voxel_centers(sdf.grid.shape[0], float(sdf.bounds_max[0]))
    return idx, centers[idx]


def _max_unsigned_error(mesh: trimesh.Trimesh, sdf: SDFGrid, n: int = 40000) -> float:
    idx, points = _sample_voxels(sdf, n)
    truth = _scene(mesh).compute_distance(o3d.core.Tensor(points.astype(np.float32))).numpy()
    got = np.abs(sdf.grid[idx[:, 0], idx[:, 1], idx[:, 2]])
    return float(np.max(np.abs(got - truth)))


@pytest.fixture(scope="module")
def mug() -> tuple[trimesh.Trimesh, SDFGrid]:
    mesh = _ycb("025_mug")
    return mesh, compute_sdf(mesh.vertices, mesh.faces)


@pytest.fixture(scope="module")
def knife() -> tuple[trimesh.Trimesh, SDFGrid]:
    mesh = _ycb("032_knife")
    return mesh, compute_sdf(mesh.vertices, mesh.faces)


def test_layout_and_voxel_centres(mug: tuple[trimesh.Trimesh, SDFGrid]) -> None:
    _, sdf = mug
    assert sdf.grid.shape == (200, 200, 200) and sdf.grid.dtype == np.float32
    assert sdf.voxel_size == pytest.approx(0.005)
    np.testing.assert_allclose(sdf.bounds_min, [-0.5] * 3)
    np.testing.assert_allclose(sdf.bounds_max, [0.5] * 3)
    centers = voxel_centers()
    assert centers[0] == pytest.approx(-0.4975) and centers[-1] == pytest.approx(0.4975)
    assert all(isinstance(v, (float, int, bool, str)) for v in sdf.info.values())
    # The coarse levels must settle most of the grid, or the build is no faster than open3d.
    assert sdf.info["n_exact_queries"] < 0.1 * 200**3


@pytest.mark.parametrize("fixture", ["mug", "knife"])
def test_ycb_exact_at_full_resolution(fixture: str, request: pytest.FixtureRequest) -> None:
    mesh, sdf = request.getfixturevalue(fixture)
    assert _max_unsigned_error(mesh, sdf) <= REQUIRED_ERROR_M


@pytest.mark.parametrize("name", ["062_dice", "029_plate"])
def test_ycb_exact_at_coarser_resolution(name: str) -> None:
    # 100^3 keeps the test fast; the bounds are the same code path at a different cell size.
    mesh = _ycb(name)
    sdf = compute_sdf(mesh.vertices, mesh.faces, resolution=100)
    assert _max_unsigned_error(mesh, sdf) <= REQUIRED_ERROR_M


def test_exact_against_trimesh_proximity(mug: tuple[trimesh.Trimesh, SDFGrid]) -> None:
    # An implementation independent of open3d, on a small set because it is slow.
    mesh, sdf = mug
    idx, points = _sample_voxels(sdf, 400, seed=1)
    _, truth, _ = trimesh.proximity.closest_point(mesh, points)
    got = np.abs(sdf.grid[idx[:, 0], idx[:, 1], idx[:, 2]])
    assert np.max(np.abs(got - truth)) <= REQUIRED_ERROR_M


def test_analytic_sphere() -> None:
    radius = 0.1
    sphere = trimesh.creation.icosphere(subdivisions=5, radius=radius)
    sdf = compute_sdf(sphere.vertices, sphere.faces, resolution=80)
    c = voxel_centers(80)
    r = np.sqrt(c[:, None, None] ** 2 + c[None, :, None] ** 2 + c[None, None, :] ** 2)
    # The icosphere's facets sit at most this far inside the true sphere.
    sag = radius * (1 - np.cos(np.max(sphere.edges_unique_length) / radius))
    assert np.max(np.abs(sdf.grid - (r - radius))) <= sag + REQUIRED_ERROR_M
    assert (
        np.all((sdf.grid < 0) == (r < radius - sag))
        or np.mean((sdf.grid < 0) == (r < radius)) > 0.9999
    )


def test_analytic_box() -> None:
    half = np.array([0.08, 0.05, 0.02])
    box = trimesh.creation.box(extents=2 * half)
    sdf = compute_sdf(box.vertices, box.faces, resolution=64)
    c = voxel_centers(64)
    p = np.stack(np.meshgrid(c, c, c, indexing="ij"), axis=-1)
    q = np.abs(p) - half
    truth = np.linalg.norm(np.maximum(q, 0), axis=-1) + np.minimum(q.max(axis=-1), 0)
    assert np.max(np.abs(sdf.grid - truth)) <= REQUIRED_ERROR_M
    assert sdf.info["thin"] is False and sdf.info["n_inside_voxels"] > 0


@pytest.mark.parametrize("resolution", [50, 61])
def test_resolution_not_a_multiple_of_the_strides(resolution: int) -> None:
    # The coarse lattices are padded past the grid; the padding must not leak into the values.
    half = np.array([0.08, 0.05, 0.02])
    box = trimesh.creation.box(extents=2 * half)
    sdf = compute_sdf(box.vertices, box.faces, resolution=resolution, extent=0.2)
    c = voxel_centers(resolution, 0.2)
    p = np.stack(np.meshgrid(c, c, c, indexing="ij"), axis=-1)
    q = np.abs(p) - half
    truth = np.linalg.norm(np.maximum(q, 0), axis=-1) + np.minimum(q.max(axis=-1), 0)
    assert sdf.grid.shape == (resolution,) * 3
    assert np.max(np.abs(sdf.grid - truth)) <= REQUIRED_ERROR_M


def test_sign_survives_holes() -> None:
    mesh = _ycb("077_rubiks_cube")
    assert mesh.is_watertight
    full = compute_sdf(mesh.vertices, mesh.faces, resolution=100)
    rng = np.random.default_rng(0)
    keep = np.ones(len(mesh.faces), dtype=bool)
    keep[rng.choice(len(mesh.faces), 20, replace=False)] = False
    holed = compute_sdf(mesh.vertices, mesh.faces[keep], resolution=100)
    # Compare inside the bounding box, where the sign test runs, so the ratio is meaningful.
    lo, hi = np.searchsorted(voxel_centers(100), [mesh.bounds[0], mesh.bounds[1]])
    box = tuple(slice(a - 1, b + 1) for a, b in zip(lo, hi, strict=True))
    agree = np.mean((full.grid[box] < 0) == (holed.grid[box] < 0))
    assert full.info["n_inside_voxels"] > 100
    assert agree >= 0.999


def test_sign_matches_watertight_truth() -> None:
    mesh = _ycb("077_rubiks_cube")
    sdf = compute_sdf(mesh.vertices, mesh.faces, resolution=100)
    idx, points = _sample_voxels(sdf, 20000)
    truth = (
        _scene(mesh)
        .compute_signed_distance(o3d.core.Tensor(points.astype(np.float32)), nsamples=7)
        .numpy()
    )
    got = sdf.grid[idx[:, 0], idx[:, 1], idx[:, 2]]
    assert np.max(np.abs(got - truth)) <= REQUIRED_ERROR_M


def test_thin_knife_is_flagged(knife: tuple[trimesh.Trimesh, SDFGrid]) -> None:
    _, sdf = knife
    info = sdf.info
    assert info["thin"] is True
    assert 0 < info["min_thickness_m"] < sdf.voxel_size
    # Still the exact distance: the surface is within a voxel of some centre.
    assert float(np.abs(sdf.grid).min()) < sdf.voxel_size


@pytest.mark.parametrize(
    ("vertices", "faces", "words"),
    [
        (np.zeros((0, 3)), np.zeros((0, 3), dtype=int), "empty"),
        (np.array([[0, 0, 0], [np.nan, 0, 0], [0, 0, 0.01]]), np.array([[0, 1, 2]]), "NaN"),
        (np.array([[0, 0, 0], [0.9, 0, 0], [0, 0, 0.01]]), np.array([[0, 1, 2]]), "extent"),
    ],
)
def test_bad_input_raises(vertices: np.ndarray, faces: np.ndarray, words: str) -> None:
    with pytest.raises(GeomprepError, match=words):
        compute_sdf(vertices, faces)


def _box_sdf(points: np.ndarray, half: np.ndarray) -> np.ndarray:
    """Exact signed distance, metres, of points (..., 3) to an origin-centred box."""
    q = np.abs(points) - half
    return np.linalg.norm(np.maximum(q, 0), axis=-1) + np.minimum(q.max(axis=-1), 0)


def _grid_points(resolution: int, extent: float) -> np.ndarray:
    c = voxel_centers(resolution, extent)
    return np.stack(np.meshgrid(c, c, c, indexing="ij"), axis=-1)


def _two_cubes(hole: bool = False) -> trimesh.Trimesh:
    """Two 5 cm cubes overlapping by half along x, not unioned: together a 7.5 x 5 x 5 cm box
    centred at the origin.  ``hole``: the second cube misses a face."""
    a = trimesh.creation.box(extents=(0.05,) * 3)
    a.apply_translation((-0.0125, 0, 0))
    b = trimesh.creation.box(extents=(0.05,) * 3)
    b.apply_translation((0.0125, 0, 0))
    if hole:
        b.update_faces(np.arange(len(b.faces)) != 0)
    return trimesh.util.concatenate([a, b])


def test_overlapping_closed_parts_are_one_solid() -> None:
    # Before: +12.5 mm at the solid's centre (parity counts the overlap as outside) and
    # distances to the interior faces.  Now the union's exact SDF.
    parts = _two_cubes()
    sdf = compute_sdf(parts.vertices, parts.faces, resolution=64, extent=0.1)
    truth = _box_sdf(_grid_points(64, 0.1), np.array([0.0375, 0.025, 0.025]))
    assert np.max(np.abs(sdf.grid - truth)) <= REQUIRED_ERROR_M
    assert sdf.info["n_parts_unioned"] == 2


def test_cavity_is_outside() -> None:
    inner = trimesh.creation.box(extents=(0.03,) * 3)
    inner.invert()  # wound inwards: a cavity
    hollow = trimesh.util.concatenate([trimesh.creation.box(extents=(0.06,) * 3), inner])
    sdf = compute_sdf(hollow.vertices, hollow.faces, resolution=64, extent=0.1)
    p = _grid_points(64, 0.1)
    truth = np.maximum(_box_sdf(p, np.full(3, 0.03)), -_box_sdf(p, np.full(3, 0.015)))
    assert np.max(np.abs(sdf.grid - truth)) <= REQUIRED_ERROR_M


def test_overlapping_parts_with_a_hole_are_refused() -> None:
    parts = _two_cubes(hole=True)
    with pytest.raises(GeomprepError, match="overlap.*ambiguous.*enclosed twice"):
        compute_sdf(parts.vertices, parts.faces, resolution=64, extent=0.1)
