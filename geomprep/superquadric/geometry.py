"""Superquadric geometry: parameters, inside-outside function, radial distance, surface samples.

Data contract: ``params`` is an (11,) float array

    [eps1, eps2, a1, a2, a3, rx, ry, rz, tx, ty, tz]

with shape exponents ``eps1`` (latitude / z profile) and ``eps2`` (longitude / xy profile) in
[0.1, 2], semi-axes ``a1, a2, a3`` in metres (> 0), the rotation ``R`` as extrinsic xyz Euler
angles in radians (``scipy Rotation.from_euler("xyz", [rx, ry, rz])``) and the translation ``t``
in metres. A canonical point ``p`` maps to the object frame as ``R @ p + t``. The canonical
inside-outside function is

    F(x) = (|x/a1|^(2/eps2) + |y/a2|^(2/eps2))^(eps2/eps1) + |z/a3|^(2/eps1),

with the surface at F = 1, inside F < 1. All power laws are evaluated in log space so that
exponents up to 2/0.1 = 20 neither overflow nor produce NaN at the centre or on the axes.

The underscored canonical-frame helpers are shared with :mod:`.fit` and :mod:`.quality` (the
fit needs their gradients), not part of the package's public API.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from geomprep.errors import GeomprepError
from geomprep.pointcloud import farthest_point_indices

EPS_MIN = 0.1
EPS_MAX = 2.0
# exp() of anything above this overflows float64; clip so implicit() stays finite far away.
_LOG_MAX = 700.0


# --------------------------------------------------------------------------------------------
# Parameter handling
# --------------------------------------------------------------------------------------------


def _check_params(params: np.ndarray) -> np.ndarray:
    p = np.asarray(params, dtype=np.float64).reshape(-1)
    if p.shape != (11,) or not np.all(np.isfinite(p)):
        raise GeomprepError(
            "superquadric params must be 11 finite numbers "
            "(eps1, eps2, a1, a2, a3, euler xyz, t): check the stored parameters"
        )
    if np.any(p[2:5] <= 0) or np.any(p[:2] <= 0):
        raise GeomprepError(
            "superquadric exponents and semi-axes must be positive: check the stored parameters"
        )
    return p


def _check_points(points: np.ndarray, what: str = "points") -> np.ndarray:
    x = np.asarray(points, dtype=np.float64)
    if x.ndim != 2 or x.shape[1] != 3:
        raise GeomprepError(f"{what} must have shape (N, 3), got {x.shape}: pass an (N, 3) array")
    if not np.all(np.isfinite(x)):
        raise GeomprepError(f"{what} contain NaN or inf: drop or repair them before fitting")
    return x


def make_params(
    eps: tuple[float, float] | np.ndarray,
    axes: tuple[float, float, float] | np.ndarray,
    rotation: np.ndarray | None = None,
    translation: np.ndarray | None = None,
) -> np.ndarray:
    """Assemble (11,) params from exponents (2,), semi-axes (3,) m, rotation (3, 3), t (3,) m."""
    rot = np.eye(3) if rotation is None else np.asarray(rotation, dtype=np.float64)
    t = np.zeros(3) if translation is None else np.asarray(translation, dtype=np.float64)
    euler = Rotation.from_matrix(rot).as_euler("xyz")
    return np.concatenate([np.asarray(eps, float), np.asarray(axes, float), euler, t])


def rotation_matrix(params: np.ndarray) -> np.ndarray:
    """Rotation (3, 3) of ``params`` (columns = canonical axes in the object frame)."""
    return Rotation.from_euler("xyz", np.asarray(params, dtype=np.float64)[5:8]).as_matrix()


def to_canonical(params: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Object-frame points (N, 3) m -> canonical frame (N, 3) m: R^T (p - t)."""
    p = np.asarray(params, dtype=np.float64)
    return (np.asarray(points, dtype=np.float64) - p[8:11]) @ rotation_matrix(p)


# --------------------------------------------------------------------------------------------
# Canonical-frame geometry (log space)
# --------------------------------------------------------------------------------------------


def _log_f(x: np.ndarray, e1: float, e2: float, a: np.ndarray) -> np.ndarray:
    """log F for canonical points (N, 3); -inf at the centre, never NaN."""
    with np.errstate(divide="ignore"):
        la = np.log(np.abs(x) / a)  # -inf exactly on a coordinate plane
    lxy = np.logaddexp((2.0 / e2) * la[:, 0], (2.0 / e2) * la[:, 1]) * (e2 / e1)
    return np.logaddexp(lxy, (2.0 / e1) * la[:, 2])


def _surface_radius(x: np.ndarray, e1: float, e2: float, a: np.ndarray) -> tuple[np.ndarray, ...]:
    """|x| and the distance (N,) from the centre to the surface along the ray through x.

    F is homogeneous of degree 2/eps1, so on the unit direction u the surface radius is
    F(u)^(-eps1/2); evaluating F on u (not on x) keeps the exponent bounded, so the radial
    distance is well defined arbitrarily close to the centre. At the exact centre the ray is
    undefined; the smallest semi-axis is used.
    """
    r = np.linalg.norm(x, axis=1)
    ok = r > 0
    u = np.where(ok[:, None], x / np.where(ok, r, 1.0)[:, None], 0.0)
    rs = np.exp(-0.5 * e1 * _log_f(u, e1, e2, a))
    rs = np.where(ok, rs, a.min())
    return r, rs


def _radial_canonical(x: np.ndarray, e1: float, e2: float, a: np.ndarray) -> np.ndarray:
    r, rs = _surface_radius(x, e1, e2, a)
    return np.abs(r - rs)


# Floor for |u_i| inside logs: log stays finite (so 0 * log never makes NaN) while the softmax
# weights of such coordinates underflow to exactly 0, which is their true limit.
_U_FLOOR = 1e-150


def _radial_with_grad(
    x: np.ndarray, e1: float, e2: float, a: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Radial distance (N,) and its exact derivatives for canonical points x (N, 3).

    Returns d, dd/d(eps1, eps2) (N, 2), dd/d(a1, a2, a3) (N, 3), dd/dx (N, 3). Works on the unit
    direction u = x/|x| (F is homogeneous), with log F written as nested log-sum-exps whose
    softmax weights give the chain rule; see the module docstring for F.
    """
    r = np.linalg.norm(x, axis=1)
    ok = r > 0
    u = x / np.where(ok, r, 1.0)[:, None]
    u[~ok] = (0.0, 0.0, 1.0)  # arbitrary ray at the exact centre; gradients zeroed below
    sign_u = np.where(u >= 0, 1.0, -1.0)
    au = np.maximum(np.abs(u), _U_FLOOR)
    lg = np.log(au / a)  # (N, 3)
    p2, p1 = 2.0 / e2, 2.0 / e1
    big_a, big_b, big_c = p2 * lg[:, 0], p2 * lg[:, 1], p1 * lg[:, 2]
    s_xy = np.logaddexp(big_a, big_b)
    w_a, w_b = np.exp(big_a - s_xy), np.exp(big_b - s_xy)
    h = (e2 / e1) * s_xy
    g = np.logaddexp(h, big_c)  # log F(u)
    w_h, w_c = np.exp(h - g), np.exp(big_c - g)
    rs = np.exp(-0.5 * e1 * g)  # surface radius along the ray
    diff = r - rs
    sgn = np.where(diff >= 0, 1.0, -1.0)
    d = np.abs(diff)

    g_l = p1 * np.stack([w_h * w_a, w_h * w_b, w_c], axis=1)  # d log F / d log|x_i / a_i|
    dg_de1 = -(w_h * h + w_c * big_c) / e1
    dg_de2 = w_h * (s_xy / e1 - (2.0 / (e1 * e2)) * (w_a * lg[:, 0] + w_b * lg[:, 1]))
    drs_de = np.stack([rs * (-0.5 * g - 0.5 * e1 * dg_de1), rs * (-0.5 * e1 * dg_de2)], axis=1)
    drs_da = (rs * 0.5 * e1)[:, None] * g_l / a
    # rs = |x| F(x)^(-eps1/2) and d log F / dx_i = g_l_i / x_i.
    with np.errstate(divide="ignore", invalid="ignore"):
        drs_dx = (rs / r)[:, None] * (u - 0.5 * e1 * g_l / (sign_u * au))
    dd_dx = sgn[:, None] * (u - drs_dx)
    dd_de = -sgn[:, None] * drs_de
    dd_da = -sgn[:, None] * drs_da
    if not ok.all():
        d[~ok] = a.min()
        dd_dx[~ok] = 0.0
        dd_de[~ok] = 0.0
        dd_da[~ok] = 0.0
    return d, dd_de, dd_da, dd_dx


def _project_to_surface(q: np.ndarray, e1: float, e2: float, a: np.ndarray) -> np.ndarray:
    """Radially project canonical points (N, 3) (none at the centre) onto the surface."""
    return q * np.exp(-0.5 * e1 * _log_f(q, e1, e2, a))[:, None]


def _surface_canonical(dirs: np.ndarray, e: np.ndarray, a: np.ndarray) -> np.ndarray:
    """Canonical surface points (K, 3): fixed box directions ``dirs`` (K, 3) scaled by the
    semi-axes and projected radially; smooth in (e, a), unlike a fresh random sample."""
    return _project_to_surface(dirs * a, e[0], e[1], a)


def _surface_canonical_with_grad(
    dirs: np.ndarray, e: np.ndarray, a: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_surface_canonical` (K, 3) and its derivative (K, 3, 5) w.r.t. (e1, e2, a1..a3).

    Central differences: the projection is closed-form and costs microseconds for K = 200,
    while the distance queries (the expensive part) are done once per Jacobian regardless.
    """
    sc = _surface_canonical(dirs, e, a)
    theta = np.r_[e, a]
    steps = np.r_[1e-6, 1e-6, 1e-6 * a]
    grad = np.empty((len(dirs), 3, 5))
    for i, h in enumerate(steps):
        up, dn = theta.copy(), theta.copy()
        up[i] += h
        dn[i] -= h
        diff = _surface_canonical(dirs, up[:2], up[2:]) - _surface_canonical(dirs, dn[:2], dn[2:])
        grad[:, :, i] = diff / (2.0 * h)
    return sc, grad


# --------------------------------------------------------------------------------------------
# Public geometry
# --------------------------------------------------------------------------------------------


def implicit(params: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Inside-outside function F (N,) of object-frame points (N, 3) in metres.

    F < 1 inside, F = 1 on the surface, F > 1 outside; 0 at the centre. Finite everywhere
    (values beyond e^700 are clipped) for any exponent in [0.1, 2].
    """
    p = _check_params(params)
    x = to_canonical(p, _check_points(points))
    return np.exp(np.minimum(_log_f(x, p[0], p[1], p[2:5]), _LOG_MAX))


def radial_distance(params: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Radial Euclidean distance (N,) m of points (N, 3) m to the superquadric surface.

    Equals |x| * |1 - F(x)^(-eps1/2)| (x in the canonical frame): the distance from x to the
    surface point on the ray from the centre through x. At the exact centre: the smallest
    semi-axis. Finite everywhere.
    """
    p = _check_params(params)
    x = to_canonical(p, _check_points(points))
    return _radial_canonical(x, p[0], p[1], p[2:5])


def _box_surface_points(a: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """n points (n, 3) uniform by area on the surface of the box [-a, a]."""
    face_area = np.array([a[1] * a[2], a[0] * a[2], a[0] * a[1]])
    face_axis = rng.choice(3, size=n, p=face_area / face_area.sum())
    q = rng.uniform(-1.0, 1.0, size=(n, 3))
    q[np.arange(n), face_axis] = rng.choice([-1.0, 1.0], size=n)
    return q * a


def sample_surface(params: np.ndarray, n: int, seed: int = 0, oversample: int = 8) -> np.ndarray:
    """n points (n, 3) m on the superquadric surface, spread roughly uniformly, object frame.

    The (eta, omega) parameterisation concentrates almost all samples at edges and corners for
    small exponents (cos^0.1 is ~1 almost everywhere), so instead candidates are drawn
    uniformly by area on the canonical box [-a, a] and projected radially onto the surface (a
    bounded distortion for every exponent in [0.1, 2]); ``oversample * n`` candidates are then
    thinned by farthest-point sampling, which evens out the remaining density variation.
    Deterministic for a given ``seed``.
    """
    p = _check_params(params)
    if n <= 0:
        return np.zeros((0, 3))
    rng = np.random.default_rng(seed)
    a = p[2:5]
    q = _box_surface_points(a, max(oversample * n, 2000), rng)
    cand = _project_to_surface(q, p[0], p[1], a)
    idx = farthest_point_indices(cand, min(n, len(cand)), start=int(rng.integers(len(cand))))
    return cand[idx] @ rotation_matrix(p).T + p[8:11]


def sample_surface_dense(params: np.ndarray, n: int, seed: int = 0) -> np.ndarray:
    """n points (n, 3) m on the surface, object frame, without thinning (fast for large n).

    Uniform on the canonical box, projected radially: density varies by a bounded factor, so
    use it where only coverage matters (nearest-neighbour queries), not for statistics.
    """
    p = _check_params(params)
    rng = np.random.default_rng(seed)
    q = _box_surface_points(p[2:5], n, rng)
    return _project_to_surface(q, p[0], p[1], p[2:5]) @ rotation_matrix(p).T + p[8:11]


def _bounds_of(params: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned bounds (3,), (3,) m of the superquadric (of its canonical box, rotated)."""
    p = _check_params(params)
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]) * p[2:5]
    world = corners @ rotation_matrix(p).T + p[8:11]
    return world.min(axis=0), world.max(axis=0)
