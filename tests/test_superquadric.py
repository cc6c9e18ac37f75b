"""Tests for geomprep.superquadric: geometry helpers, sampling, and EMS recovery."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from geomprep.errors import GeomprepError
from geomprep.superquadric import (
    MeshOracle,
    fit_quality,
    fit_superquadric,
    implicit,
    make_params,
    radial_distance,
    rotation_matrix,
    sample_surface,
    sample_surface_dense,
    to_canonical,
    volume_iou,
)
from geomprep.superquadric.fit import _SurfaceOracle
from geomprep.superquadric.geometry import _radial_canonical, _radial_with_grad
from tests.conftest import ycb_mesh


def _surface_error(true: np.ndarray, fitted: np.ndarray) -> float:
    """Symmetric mean radial distance between two superquadric surfaces / max semi-axis."""
    a = sample_surface(true, 800, seed=5)
    b = sample_surface(fitted, 800, seed=6)
    sym = 0.5 * (radial_distance(fitted, a).mean() + radial_distance(true, b).mean())
    return float(sym / true[2:5].max())


# ------------------------------------------------------------------------------------------
# Geometry
# ------------------------------------------------------------------------------------------


@pytest.mark.parametrize("eps", [(0.1, 0.1), (0.1, 2.0), (1.0, 1.0), (2.0, 0.1)])
def test_implicit_and_radial_finite_everywhere(eps: tuple[float, float]) -> None:
    p = make_params(eps, [0.05, 0.03, 0.02])
    pts = np.array(
        [
            [0.0, 0.0, 0.0],  # centre
            [0.05, 0.0, 0.0],  # on the axes, on the surface
            [0.0, 0.03, 0.0],
            [0.0, 0.0, 0.02],
            [0.0, 0.0, -0.5],  # far out on an axis
            [1e-12, 0.0, 0.0],  # next to the centre
            [3.0, 3.0, 3.0],  # far away: (60)^20 would overflow a naive float32 evaluation
            [1e3, 0.0, 1e3],
        ]
    )
    f = implicit(p, pts)
    d = radial_distance(p, pts)
    assert np.all(np.isfinite(f)) and np.all(np.isfinite(d))
    assert f[0] == 0.0
    np.testing.assert_allclose(f[1:4], 1.0, rtol=1e-12)
    np.testing.assert_allclose(d[1:4], 0.0, atol=1e-12)
    assert d[4] == pytest.approx(0.48)
    assert d[5] == pytest.approx(0.05, rel=1e-6)  # distance to the surface along +x
    assert d[0] == pytest.approx(0.02)  # documented: the smallest semi-axis at the centre


def test_implicit_matches_direct_formula() -> None:
    rng = np.random.default_rng(0)
    e1, e2, a = 0.7, 1.3, np.array([0.05, 0.04, 0.03])
    rot = Rotation.from_euler("xyz", [0.3, -0.2, 1.0]).as_matrix()
    t = np.array([0.1, -0.2, 0.05])
    p = make_params((e1, e2), a, rot, t)
    pts = rng.normal(size=(200, 3)) * 0.05 + t
    x = (pts - t) @ rot
    f = (np.abs(x[:, 0] / a[0]) ** (2 / e2) + np.abs(x[:, 1] / a[1]) ** (2 / e2)) ** (
        e2 / e1
    ) + np.abs(x[:, 2] / a[2]) ** (2 / e1)
    np.testing.assert_allclose(implicit(p, pts), f, rtol=1e-10)
    r = np.linalg.norm(x, axis=1) * np.abs(1 - f ** (-e1 / 2))
    np.testing.assert_allclose(radial_distance(p, pts), r, rtol=1e-9, atol=1e-15)


def test_params_convention() -> None:
    rot = Rotation.from_euler("xyz", [0.4, 0.1, -0.3]).as_matrix()
    p = make_params((0.5, 0.5), [0.05, 0.04, 0.03], rot, [1.0, 2.0, 3.0])
    assert p.shape == (11,)
    np.testing.assert_allclose(p[5:8], [0.4, 0.1, -0.3])
    np.testing.assert_allclose(rotation_matrix(p), rot, atol=1e-12)
    # A canonical point c maps to R c + t.
    c = np.array([[0.05, 0.0, 0.0]])
    np.testing.assert_allclose(to_canonical(p, c @ rot.T + p[8:11]), c, atol=1e-12)
    assert implicit(p, c @ rot.T + p[8:11])[0] == pytest.approx(1.0)


@pytest.mark.parametrize("eps", [(0.3, 0.7), (1.0, 1.0), (0.1, 1.9), (1.8, 0.2)])
def test_radial_gradient_matches_finite_differences(eps: tuple[float, float]) -> None:
    rng = np.random.default_rng(1)
    x = rng.normal(size=(40, 3)) * 0.05
    x[0] = [0.03, 0.0, 0.0]  # on axes / coordinate planes
    x[1] = [0.0, 0.01, 0.01]
    a = np.array([0.05, 0.04, 0.03])
    e1, e2 = eps
    d, dd_de, dd_da, dd_dx = _radial_with_grad(x, e1, e2, a)
    np.testing.assert_allclose(d, _radial_canonical(x, e1, e2, a), atol=1e-14)
    h = 1e-7

    def fd(fn) -> np.ndarray:  # type: ignore[no-untyped-def]
        return (fn(h) - fn(-h)) / (2 * h)

    for i in range(3):
        unit = np.eye(3)[i]
        np.testing.assert_allclose(
            dd_dx[:, i], fd(lambda s, u=unit: _radial_canonical(x + s * u, e1, e2, a)), atol=1e-6
        )
        np.testing.assert_allclose(
            dd_da[:, i], fd(lambda s, u=unit: _radial_canonical(x, e1, e2, a + s * u)), atol=1e-6
        )
    np.testing.assert_allclose(
        dd_de[:, 0], fd(lambda s: _radial_canonical(x, e1 + s, e2, a)), atol=1e-6
    )
    np.testing.assert_allclose(
        dd_de[:, 1], fd(lambda s: _radial_canonical(x, e1, e2 + s, a)), atol=1e-6
    )


def test_bad_params_raise() -> None:
    pts = np.zeros((3, 3))
    with pytest.raises(GeomprepError):
        implicit(np.zeros(10), pts)
    with pytest.raises(GeomprepError):
        implicit(make_params((1, 1), [0.1, -0.1, 0.1]), pts)
    with pytest.raises(GeomprepError):
        radial_distance(np.full(11, np.nan), pts)


# ------------------------------------------------------------------------------------------
# Sampling
# ------------------------------------------------------------------------------------------


@pytest.mark.parametrize("eps", [(0.1, 0.1), (0.1, 1.0), (1.0, 1.0), (1.8, 1.8), (2.0, 0.1)])
def test_sample_surface_on_surface_and_spread(eps: tuple[float, float]) -> None:
    rot = Rotation.from_euler("xyz", [0.5, -0.4, 0.9]).as_matrix()
    p = make_params(eps, [0.05, 0.03, 0.02], rot, [0.1, 0.0, -0.2])
    s = sample_surface(p, 800, seed=3)
    assert s.shape == (800, 3)
    np.testing.assert_allclose(implicit(p, s), 1.0, rtol=1e-9)
    nn = cKDTree(s).query(s, k=2)[0][:, 1]
    # Evenly spread: nearest-neighbour spacing varies little and no point is isolated.
    assert nn.std() / nn.mean() < 0.25
    assert nn.max() < 2.5 * nn.mean()
    np.testing.assert_array_equal(s, sample_surface(p, 800, seed=3))


def test_sample_surface_area_uniform_on_sphere() -> None:
    # A spherical cap of height r/2 holds exactly 1/4 of the sphere's area; the (eta, omega)
    # parameterisation without area weighting would put far more there (pole clustering).
    p = make_params((1.0, 1.0), [0.04, 0.04, 0.04])
    s = sample_surface(p, 2000, seed=0)
    for axis in range(3):
        assert np.mean(s[:, axis] > 0.02) == pytest.approx(0.25, abs=0.03)


# ------------------------------------------------------------------------------------------
# Fitting
# ------------------------------------------------------------------------------------------

SHAPES = {
    "cube": ((0.1, 0.1), (0.05, 0.04, 0.03)),
    "cylinder": ((0.1, 1.0), (0.03, 0.03, 0.08)),
    "ellipsoid": ((1.0, 1.0), (0.06, 0.04, 0.03)),
    "pinched": ((1.8, 1.8), (0.05, 0.04, 0.05)),
}


def _closest_on_samples(params: np.ndarray, n: int = 20000):  # type: ignore[no-untyped-def]
    """Closest-point function (K, 3) -> (K, 3) onto n dense samples of a superquadric: the
    'exact' surface for the regularised fits of known shapes (spacing ~1 mm at these sizes)."""
    samples = sample_surface_dense(params, n, seed=99)
    tree = cKDTree(samples)
    return lambda q: samples[tree.query(q)[1]]


@pytest.mark.parametrize("regularized", [False, True], ids=["ems", "ems+surface"])
@pytest.mark.parametrize("outliers", [False, True], ids=["clean", "outliers20"])
@pytest.mark.parametrize("shape", list(SHAPES))
def test_fit_recovers_known_superquadric(shape: str, outliers: bool, regularized: bool) -> None:
    eps, axes = SHAPES[shape]
    seed = sorted(SHAPES).index(shape)
    rng = np.random.default_rng(seed)
    rot = Rotation.random(random_state=seed + 10).as_matrix()
    true = make_params(eps, axes, rot, rng.uniform(-0.2, 0.2, size=3))
    n_in = 1600
    pts = sample_surface(true, n_in, seed=seed) + rng.normal(0.0, 0.0005, size=(n_in, 3))
    if outliers:
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        pts = np.vstack([pts, rng.uniform(lo, hi, size=(n_in // 4, 3))])  # 20 % of all points
        pts = pts[rng.permutation(len(pts))]
    surface = {}
    if regularized:
        surface = {"surface_closest_fn": _closest_on_samples(true), "surface_weight": 1.0}
    fitted, diag = fit_superquadric(pts, outlier_ratio=0.2 if outliers else 0.1, **surface)
    assert fitted.shape == (11,) and fitted.dtype == np.float64
    assert 0.1 <= fitted[0] <= 2.0 and 0.1 <= fitted[1] <= 2.0
    assert _surface_error(true, fitted) < 0.02
    assert all(isinstance(v, float) for v in diag.values())
    if outliers:
        assert diag["inlier_fraction"] == pytest.approx(0.8, abs=0.05)
    if regularized:
        assert diag["surface_mean_m"] < 0.02 * max(axes)


def test_fit_cube_reported_with_small_exponents() -> None:
    # A sharp cube fits exactly as a 45-degree diamond (eps2 = 2) too; the fit must report
    # the conventional square section so all boxes look alike to a policy.
    mesh = trimesh.creation.box(extents=(0.016, 0.016, 0.016))
    mesh.apply_transform(trimesh.transformations.euler_matrix(0.2, -0.4, 0.7))
    pts, _ = trimesh.sample.sample_surface(mesh, 2000, seed=0)
    params, _ = fit_superquadric(pts)
    assert params[0] < 0.3 and params[1] < 0.3
    np.testing.assert_allclose(params[2:5], 0.008, atol=0.0005)


def test_fit_is_deterministic() -> None:
    true = make_params((0.5, 0.8), [0.05, 0.04, 0.03])
    pts = sample_surface(true, 3000, seed=0)
    p1, _ = fit_superquadric(pts, seed=4)
    p2, _ = fit_superquadric(pts, seed=4)
    np.testing.assert_array_equal(p1, p2)


@pytest.mark.parametrize(
    "points",
    [
        np.zeros((0, 3)),
        np.zeros((9, 3)),
        np.full((50, 3), np.nan),
        np.zeros((50, 2)),
        np.zeros((50, 3)),
    ],
    ids=["empty", "too-few", "nan", "2d", "all-identical"],
)
def test_fit_bad_input_raises(points: np.ndarray) -> None:
    with pytest.raises(GeomprepError):
        fit_superquadric(points)


def test_fit_bad_options_raise() -> None:
    pts = sample_surface(make_params((1, 1), [0.05, 0.04, 0.03]), 100)
    with pytest.raises(GeomprepError):
        fit_superquadric(pts, outlier_ratio=1.0)
    with pytest.raises(GeomprepError):
        fit_superquadric(pts, surface_weight=-1.0)
    with pytest.raises(GeomprepError):
        fit_superquadric(pts, normals=np.zeros((3, 3)))
    for bad in ({"max_iters": 0}, {"tol": 0.0}, {"max_switches": -1}, {"surface_samples": 0}):
        with pytest.raises(GeomprepError):
            fit_superquadric(pts, **bad)  # type: ignore[arg-type]


def test_fit_reports_convergence() -> None:
    pts = sample_surface(make_params((0.6, 0.9), [0.05, 0.04, 0.03]), 1500)
    _, diag = fit_superquadric(pts)
    assert diag["converged"] == 1.0 and diag["iters"] < 30
    _, diag = fit_superquadric(pts, max_iters=1, tol=1e-12)
    assert diag["converged"] == 0.0 and diag["iters"] == 1.0


def _hemisphere_shell(radius: float, n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    v = rng.normal(size=(n, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    v[:, 2] = -np.abs(v[:, 2])  # lower half: a bowl opening upward
    return radius * v


def _hemisphere_distance(radius: float):  # type: ignore[no-untyped-def]
    def dist(q: np.ndarray) -> np.ndarray:
        rho = np.linalg.norm(q[:, :2], axis=1)
        to_sphere = np.abs(np.linalg.norm(q, axis=1) - radius)
        to_rim = np.hypot(rho - radius, q[:, 2])
        return np.where(q[:, 2] <= 0.0, to_sphere, to_rim)

    return dist


@pytest.mark.parametrize("oracle", ["distance", "closest"])
def test_surface_term_shrinks_bowl_fit_toward_object(oracle: str) -> None:
    # Points on a hemisphere fit a full sphere perfectly, so plain EMS bulges a whole
    # hemisphere past the bowl's rim (z > 0); the surface term must pull it onto the bowl.
    radius = 0.06
    pts = _hemisphere_shell(radius, 2000, seed=0)
    dist = _hemisphere_distance(radius)
    plain, _ = fit_superquadric(pts)
    if oracle == "distance":
        surface = {"surface_distance_fn": dist}
    else:
        shell = _hemisphere_shell(radius, 40000, seed=1)
        tree = cKDTree(shell)
        surface = {"surface_closest_fn": lambda q: shell[tree.query(q)[1]]}
    reg, diag = fit_superquadric(pts, surface_weight=1.0, **surface)
    plain_s, reg_s = sample_surface(plain, 1000), sample_surface(reg, 1000)
    # Measured: top at 1.0 r -> 0.18 r, mean gap 0.28 r -> 0.16 r, p95 gap 1.06 r -> 0.62 r.
    assert plain_s[:, 2].max() > 0.9 * radius  # the unregularised fit really does bulge
    assert reg_s[:, 2].max() < 0.4 * radius
    assert dist(reg_s).mean() < 0.7 * dist(plain_s).mean()
    assert np.percentile(dist(reg_s), 95) < 0.7 * np.percentile(dist(plain_s), 95)
    assert diag["surface_mean_m"] == pytest.approx(dist(reg_s).mean(), rel=0.3)
    # The data term still holds the superquadric near the points.
    assert radial_distance(reg, pts).mean() < 0.1 * radius


def test_surface_term_leaves_box_fit_alone() -> None:
    # A box is within the superquadrics' scope: the surface term must not move its fit.
    mesh = trimesh.creation.box(extents=(0.12, 0.08, 0.05))
    mesh.apply_transform(trimesh.transformations.euler_matrix(0.3, 0.2, -0.5))
    pts, _ = trimesh.sample.sample_surface(mesh, 2000, seed=0)
    oracle = MeshOracle(mesh.vertices, mesh.faces)
    plain, _ = fit_superquadric(pts)
    reg, _ = fit_superquadric(pts, surface_closest_fn=oracle.closest, surface_weight=1.0)
    q_plain = fit_quality(plain, pts, oracle)
    q_reg = fit_quality(reg, pts, oracle)
    assert q_reg["mesh_to_sq_mean_m"] < 1.1 * q_plain["mesh_to_sq_mean_m"] + 1e-4
    assert q_reg["volume_iou"] > 0.95 and q_plain["volume_iou"] > 0.95
    np.testing.assert_allclose(np.sort(reg[2:5]), [0.025, 0.04, 0.06], atol=0.002)


def test_surface_oracle_gradients_agree() -> None:
    # Distance to a sphere of radius 0.05: the gradient is the radial unit vector, from the
    # closest-point path exactly and from the distance-only path by forward differences.
    rng = np.random.default_rng(0)
    p = rng.normal(size=(50, 3)) * 0.05
    radius = 0.05

    def closest(q: np.ndarray) -> np.ndarray:
        return radius * q / np.linalg.norm(q, axis=1, keepdims=True)

    def distance(q: np.ndarray) -> np.ndarray:
        return np.abs(np.linalg.norm(q, axis=1) - radius)

    d1, g1 = _SurfaceOracle(None, closest, 0.05).distance_and_gradient(p)
    d2, g2 = _SurfaceOracle(distance, None, 0.05).distance_and_gradient(p)
    np.testing.assert_allclose(d1, distance(p), atol=1e-12)
    np.testing.assert_allclose(d2, distance(p), atol=1e-12)
    np.testing.assert_allclose(g1, g2, atol=1e-3)
    outside = np.linalg.norm(p, axis=1) > radius
    unit = p / np.linalg.norm(p, axis=1, keepdims=True)
    np.testing.assert_allclose(g1[outside], unit[outside], atol=1e-9)


# ------------------------------------------------------------------------------------------
# Quality measures
# ------------------------------------------------------------------------------------------


def test_volume_iou_sphere_in_cube() -> None:
    # A ball of radius r in the cube of side 2r: IoU = (4/3 pi r^3) / (2r)^3 = pi / 6.
    r = 0.05
    cube = trimesh.creation.box(extents=(2 * r, 2 * r, 2 * r))
    oracle = MeshOracle(cube.vertices, cube.faces)
    ball = make_params((1.0, 1.0), [r, r, r])
    assert volume_iou(ball, oracle.inside, oracle.bounds, voxel=0.002) == pytest.approx(
        np.pi / 6, abs=0.02
    )
    box = make_params((0.1, 0.1), [r, r, r])
    assert volume_iou(box, oracle.inside, oracle.bounds, voxel=0.002) > 0.97
    far = make_params((1.0, 1.0), [r, r, r], translation=[1.0, 0.0, 0.0])
    assert volume_iou(far, oracle.inside, oracle.bounds) == 0.0


def test_mesh_inside_robust_on_open_scan() -> None:
    # A box with a hole in its top (a 2 x 2 cm patch missing), like a scan with a gap: a
    # single ray through the hole would call the point outside; the majority vote does not.
    cube = trimesh.creation.box(extents=(0.1, 0.1, 0.1))
    for _ in range(4):
        cube = cube.subdivide()
    c = cube.triangles_center
    hole = (c[:, 2] > 0.049) & (np.abs(c[:, 0]) < 0.01) & (np.abs(c[:, 1]) < 0.01)
    assert hole.any()
    open_box = trimesh.Trimesh(cube.vertices, cube.faces[~hole], process=False)
    oracle = MeshOracle(open_box.vertices, open_box.faces)
    box = make_params((0.1, 0.1), [0.05, 0.05, 0.05])
    assert volume_iou(box, oracle.inside, oracle.bounds, voxel=0.0025) > 0.97


def test_fit_quality_of_exact_fit_is_small() -> None:
    mesh = trimesh.creation.icosphere(subdivisions=5, radius=0.04)
    oracle = MeshOracle(mesh.vertices, mesh.faces)
    pts, _ = trimesh.sample.sample_surface(mesh, 3000, seed=0)
    q = fit_quality(make_params((1.0, 1.0), [0.04, 0.04, 0.04]), pts, oracle)
    assert set(q) == {
        "mesh_to_sq_mean_m",
        "mesh_to_sq_p95_m",
        "sq_to_mesh_mean_m",
        "sq_to_mesh_p95_m",
        "volume_iou",
    }
    # The icosphere's flat facets sit up to ~0.1 mm inside the true sphere.
    assert q["mesh_to_sq_p95_m"] < 2e-4 and q["sq_to_mesh_p95_m"] < 2e-4
    assert q["volume_iou"] > 0.95


# ------------------------------------------------------------------------------------------
# Real object
# ------------------------------------------------------------------------------------------


def test_fit_ycb_cracker_box() -> None:
    mesh = ycb_mesh("003_cracker_box")
    pts, _ = trimesh.sample.sample_surface(mesh, 20000, seed=0)
    params, diag = fit_superquadric(pts)  # ~0.3 s; bench/sq.py times the fits
    assert params[0] < 0.3 and params[1] < 0.3, "a box has small exponents"
    # Full extents of the fitted box match the mesh's extents along the fitted axes.
    local = to_canonical(params, mesh.vertices)
    mesh_extent = local.max(axis=0) - local.min(axis=0)
    np.testing.assert_allclose(2.0 * params[2:5], mesh_extent, atol=0.01)
    assert np.sort(2.0 * params[2:5]) == pytest.approx([0.07, 0.164, 0.214], abs=0.01)
    assert diag["inlier_mean_radial_m"] < 0.002
    assert np.median(radial_distance(params, pts)) < 0.002


def test_show_prints_quality_in_mm() -> None:
    from geomprep.preview import _sq_quality_line

    attrs = {
        "mesh_to_sq_mean_m": 0.0012,
        "mesh_to_sq_p95_m": 0.0031,
        "sq_to_mesh_mean_m": 0.0045,
        "sq_to_mesh_p95_m": 0.0102,
        "volume_iou": 0.874,
    }
    line = _sq_quality_line(attrs)
    assert "mesh->sq 1.2 mm mean / 3.1 p95" in line
    assert "sq->mesh 4.5 / 10.2" in line and "volume IoU 0.87" in line
    assert "rebuild" in _sq_quality_line({})
