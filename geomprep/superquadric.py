"""Superquadric representation and robust recovery from surface points (EMS).

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

Fitting follows the idea of EMS (Liu et al., CVPR 2022): maximum likelihood of the points under
a Gaussian on the radial distance to the surface mixed with a uniform outlier density, solved by
EM with a bounded least-squares M-step, plus a "switching" step that jumps between parameter
sets describing the same or similar shapes to escape local minima. The implementation here is
written from the paper's description, not from the reference code.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation
from threadpoolctl import threadpool_limits

from geomprep.errors import GeomprepError

# Bump when the output for the same input changes (the pipeline's cache key uses it).
VERSION = 1

EPS_MIN = 0.1
EPS_MAX = 2.0
MIN_POINTS = 10
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


def _farthest_point_subset(pts: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """Indices (n,) of a farthest-point subset: spreads points evenly over the candidates."""
    idx = np.empty(n, dtype=np.int64)
    idx[0] = rng.integers(len(pts))
    d2 = np.sum((pts - pts[idx[0]]) ** 2, axis=1)
    for i in range(1, n):
        idx[i] = int(np.argmax(d2))
        d2 = np.minimum(d2, np.sum((pts - pts[idx[i]]) ** 2, axis=1))
    return idx


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
    idx = _farthest_point_subset(cand, min(n, len(cand)), rng)
    return cand[idx] @ rotation_matrix(p).T + p[8:11]


# --------------------------------------------------------------------------------------------
# EMS fitting
# --------------------------------------------------------------------------------------------


@contextmanager
def _single_thread_blas() -> Iterator[None]:
    """Run BLAS/LAPACK single-threaded: the fit's matrices are tiny (1500 x 11), and OpenBLAS
    worker threads made it 10-20x slower on a busy 2-core machine."""
    with threadpool_limits(limits=1, user_api="blas"):
        yield


class _State:
    """Current estimate: exponents (2,), semi-axes (3,) m, rotation (3, 3), translation (3,) m."""

    def __init__(self, e: np.ndarray, a: np.ndarray, rot: np.ndarray, t: np.ndarray) -> None:
        self.e = np.clip(np.asarray(e, float), EPS_MIN, EPS_MAX)
        self.a = np.asarray(a, float)
        self.rot = np.asarray(rot, float)
        self.t = np.asarray(t, float)

    def params(self) -> np.ndarray:
        return make_params(self.e, self.a, self.rot, self.t)

    def radial(self, pts: np.ndarray) -> np.ndarray:
        return _radial_canonical((pts - self.t) @ self.rot, self.e[0], self.e[1], self.a)


def _rotvec_matrix(w: np.ndarray) -> np.ndarray:
    """Rodrigues' formula (faster than building a scipy Rotation inside the residual)."""
    theta = float(np.linalg.norm(w))
    if theta < 1e-12:
        return np.eye(3)
    k = w / theta
    kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + np.sin(theta) * kx + (1.0 - np.cos(theta)) * (kx @ kx)


def _right_jacobian(w: np.ndarray) -> np.ndarray:
    """Right Jacobian (3, 3) of SO(3): exp([w + dw]) ~ exp([w]) exp([J_r(w) dw])."""
    theta = float(np.linalg.norm(w))
    kx = np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])
    if theta < 1e-8:
        return np.eye(3) - 0.5 * kx
    return (
        np.eye(3)
        - ((1.0 - np.cos(theta)) / theta**2) * kx
        + ((theta - np.sin(theta)) / theta**3) * (kx @ kx)
    )


def _initial_state(pts: np.ndarray) -> tuple[_State, float]:
    """Ellipsoid (eps = 1) on the points' principal axes; returns the state and the volume (m^3)
    of the principal-axes box of the points (support of the uniform outlier density)."""
    mean = pts.mean(axis=0)
    evals, evecs = np.linalg.eigh(np.cov((pts - mean).T))
    rot = evecs[:, np.argsort(-evals)]
    if np.linalg.det(rot) < 0:
        rot[:, 2] = -rot[:, 2]
    local = (pts - mean) @ rot
    # Percentiles, not min/max, so a few far outliers do not inflate the initial shape.
    lo, hi = np.percentile(local, [2.0, 98.0], axis=0)
    centre = mean + rot @ ((lo + hi) / 2.0)
    half = np.maximum((hi - lo) / 2.0, 1e-6)
    full = local.max(axis=0) - local.min(axis=0)
    # A flat cloud would give a near-zero volume, i.e. an outlier density so high that every
    # point counts as an outlier; give the region at least 1 % of the size in every direction.
    volume = float(np.prod(np.maximum(full, 1e-2 * full.max())))
    return _State(np.ones(2), half, rot, centre), volume


def _log_mix(d: np.ndarray, sigma2: float, w0: float, log_p0: float) -> tuple[np.ndarray, ...]:
    """Per-point log inlier density, log mixture density, and inlier posterior z (all (N,))."""
    log_in = np.log1p(-w0) - 1.5 * np.log(2.0 * np.pi * sigma2) - d**2 / (2.0 * sigma2)
    if w0 <= 0.0:
        return log_in, log_in, np.ones_like(d)
    log_out = np.log(w0) + log_p0
    log_mix = np.logaddexp(log_in, log_out)
    return log_in, log_mix, np.exp(log_in - log_mix)


class _Problem:
    """Fixed data of one fit: points, outlier model, bounds, optional surface term."""

    def __init__(
        self,
        pts: np.ndarray,
        w0: float,
        log_p0: float,
        size: float,
        surface_fn: Callable[[np.ndarray], np.ndarray] | None,
        surface_weight: float,
        surface_dirs: np.ndarray,
        sigma2_min: float,
    ) -> None:
        self.pts = pts
        self.w0 = w0
        self.log_p0 = log_p0
        self.size = size
        self.surface_fn = surface_fn
        self.surface_weight = surface_weight
        self.surface_dirs = surface_dirs  # (K, 3) directions on the unit box surface
        self.sigma2_min = sigma2_min

    def surface_points(self, s: _State) -> np.ndarray:
        """Points (K, 3) on the current superquadric in the object frame, smooth in the params."""
        q = self.surface_dirs * s.a
        return _project_to_surface(q, s.e[0], s.e[1], s.a) @ s.rot.T + s.t

    def surface_term(self, s: _State) -> np.ndarray:
        d = np.asarray(self.surface_fn(self.surface_points(s)), dtype=np.float64)  # type: ignore[misc]
        return np.nan_to_num(d, nan=self.size, posinf=self.size)

    def objective(self, s: _State, sigma2: float) -> float:
        """Negative log-likelihood plus the (likelihood-scaled) surface term."""
        d = s.radial(self.pts)
        _, log_mix, z = _log_mix(d, sigma2, self.w0, self.log_p0)
        nll = -float(log_mix.sum())
        if self.surface_fn is not None and self.surface_weight > 0:
            ds = self.surface_term(s)
            nll += self.surface_weight * z.sum() * float(np.mean(ds**2)) / (2.0 * sigma2)
        return nll

    def e_step(self, s: _State, sigma2: float) -> tuple[np.ndarray, np.ndarray]:
        d = s.radial(self.pts)
        return d, _log_mix(d, sigma2, self.w0, self.log_p0)[2]

    def sigma2_update(self, d: np.ndarray, z: np.ndarray) -> float:
        # MLE of an isotropic 3-D Gaussian's variance from 1-D distances (hence the 3).
        zs = max(float(z.sum()), 1e-12)
        return max(float(np.sum(z * d**2)) / (3.0 * zs), self.sigma2_min)

    def m_step(self, s: _State, z: np.ndarray, max_nfev: int) -> _State:
        """Minimise sum z_i d_i^2 (+ surface term) by bounded trust-region least squares."""
        sqrt_z = np.sqrt(z)
        rot0 = s.rot
        use_surface = self.surface_fn is not None and self.surface_weight > 0
        surf_scale = np.sqrt(self.surface_weight * z.sum() / max(len(self.surface_dirs), 1))

        def unpack(x: np.ndarray) -> _State:
            st = _State.__new__(_State)
            st.e, st.a, st.t = x[0:2], x[2:5], x[8:11]
            st.rot = rot0 @ _rotvec_matrix(x[5:8])
            return st

        pts = self.pts

        cache: dict[bytes, tuple[np.ndarray, np.ndarray]] = {}

        def data_terms(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            """Weighted radial residuals (N,) and their exact Jacobian (N, 11)."""
            # least_squares asks for the residuals and then the Jacobian at the same x, and
            # one pass computes both.
            key = x.tobytes()
            if key not in cache:
                cache.clear()
                cache[key] = _data_terms(x)
            return cache[key]

        def _data_terms(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            rot = rot0 @ _rotvec_matrix(x[5:8])
            xc = (pts - x[8:11]) @ rot
            d, dd_de, dd_da, dd_dx = _radial_with_grad(xc, x[0], x[1], x[2:5])
            jac = np.empty((len(d), 11))
            jac[:, 0:2] = dd_de
            jac[:, 2:5] = dd_da
            # x_c = R^T (p - t); a right perturbation R exp([delta]) moves x_c by x_c x delta.
            jac[:, 5:8] = np.cross(dd_dx, xc) @ _right_jacobian(x[5:8])
            jac[:, 8:11] = -dd_dx @ rot.T
            return sqrt_z * d, jac * sqrt_z[:, None]

        def surface_res(x: np.ndarray) -> np.ndarray:
            return surf_scale * self.surface_term(unpack(x))

        def residuals(x: np.ndarray) -> np.ndarray:
            r = data_terms(x)[0]
            if use_surface:
                r = np.concatenate([r, surface_res(x)])
            return r

        def jacobian(x: np.ndarray) -> np.ndarray:
            jac = data_terms(x)[1]
            if use_surface:
                # The user's distance function has no gradient: forward differences (half
                # the calls of central ones; the data term's exact rows dominate anyway).
                steps = 1e-6 * np.r_[1.0, 1.0, [self.size] * 3, [1.0] * 3, [self.size] * 3]
                base = surface_res(x)
                cols = []
                for i, h in enumerate(steps):
                    dx = np.zeros(11)
                    # Step away from the upper bound so the probe stays feasible.
                    dx[i] = -h if x[i] + h > (EPS_MAX if i < 2 else np.inf) else h
                    cols.append((surface_res(x + dx) - base) / dx[i])
                jac = np.vstack([jac, np.stack(cols, axis=1)])
            return jac

        size = self.size
        a_lo, a_hi = 1e-3 * size, 4.0 * size
        lower = np.r_[EPS_MIN, EPS_MIN, [a_lo] * 3, [-np.inf] * 3, s.t - 2 * size]
        upper = np.r_[EPS_MAX, EPS_MAX, [a_hi] * 3, [np.inf] * 3, s.t + 2 * size]
        x0 = np.r_[s.e, s.a, np.zeros(3), s.t]
        # Strictly inside the box: trf rejects starting points on a bound.
        span = upper - lower
        margin = np.where(np.isfinite(span), 1e-9 * np.where(np.isfinite(span), span, 0), 0)
        x0 = np.clip(x0, lower + margin, upper - margin)
        x_scale = np.r_[1.0, 1.0, [size] * 3, [1.0] * 3, [size] * 3]
        sol = least_squares(
            residuals,
            x0,
            jac=jacobian,
            bounds=(lower, upper),
            method="trf",
            x_scale=x_scale,
            max_nfev=max_nfev,
            xtol=1e-10,
            ftol=1e-10,
            gtol=1e-10,
        )
        return unpack(sol.x)


def _switch_candidates(s: _State) -> list[_State]:
    """Parameter sets describing the same or a similar shape as ``s`` (EMS switching).

    - Axis relabelling: make the old x or y axis the new z axis (cyclic, so still a rotation),
      with the exponents kept or exchanged (exact when eps1 = eps2, e.g. boxes and spheres;
      otherwise it is the similar shape with the profiles attached to the new axes).
    - xy duality: a square cross-section (eps2 -> 0.1) and a diamond (eps2 -> 2) are the same
      shape rotated by 45 degrees about z with the semi-axes scaled by sqrt(2); the candidate
      maps eps2 -> 2 - eps2 with the interpolated scale 2^((1 - eps2) / 2).
    The duality is also applied after each relabelling, so every axis pair is covered.
    """
    cands: list[_State] = []
    relabelled = [s]
    for perm in ((1, 2, 0), (2, 0, 1)):
        rot = s.rot[:, perm]
        a = s.a[list(perm)]
        for e in (s.e, s.e[::-1]):
            cands.append(_State(e.copy(), a.copy(), rot.copy(), s.t.copy()))
        relabelled.append(cands[-2])
    c45, s45 = np.cos(np.pi / 4), np.sin(np.pi / 4)
    rz = np.array([[c45, -s45, 0.0], [s45, c45, 0.0], [0.0, 0.0, 1.0]])
    for r in relabelled:
        scale = 2.0 ** ((1.0 - r.e[1]) / 2.0)
        a = r.a * np.array([scale, scale, 1.0])
        cands.append(_State(np.array([r.e[0], 2.0 - r.e[1]]), a, r.rot @ rz, r.t.copy()))
    return cands


def _downsample(pts: np.ndarray, n: int, seed: int) -> np.ndarray:
    if len(pts) <= n:
        return pts
    idx = np.sort(np.random.default_rng(seed).choice(len(pts), size=n, replace=False))
    return pts[idx]


def _relative_change(old: _State, new: _State, size: float) -> float:
    rot_change = np.linalg.norm(old.rot.T @ new.rot - np.eye(3))
    return float(
        np.linalg.norm(new.e - old.e) / 2.0
        + np.linalg.norm(new.a - old.a) / size
        + np.linalg.norm(new.t - old.t) / size
        + rot_change
    )


def fit_superquadric(
    points: np.ndarray,
    normals: np.ndarray | None = None,
    *,
    outlier_ratio: float = 0.1,
    max_iters: int = 30,
    seed: int = 0,
    n_points: int = 1500,
    tol: float = 1e-2,
    max_switches: int = 4,
    m_step_nfev: int = 15,
    switch_nfev: int = 12,
    switch_every: int = 8,
    surface_distance_fn: Callable[[np.ndarray], np.ndarray] | None = None,
    surface_weight: float = 0.0,
    surface_samples: int = 200,
) -> tuple[np.ndarray, dict[str, float]]:
    """Fit a superquadric to surface points with EMS (expectation, maximisation, switching).

    Model: each point is an inlier with prior 1 - ``outlier_ratio``, with density a Gaussian
    (isotropic 3-D normalisation, variance sigma^2) of its radial distance d to the surface,
    or an outlier, uniform over the points' principal-axes box. EM alternates:
    E-step (inlier posterior z_i), M-step (bounded ``least_squares`` on sqrt(z_i) d_i over
    exponents, semi-axes, a local rotation vector and translation), sigma^2 update. When the
    relative parameter change drops below ``tol``, the switching step tries shapes equivalent
    or similar to the current one (axis relabellings, square/diamond duals), refines each
    briefly and keeps the best if it lowers the negative log-likelihood; EM then continues.

    Regularisation seam (the paper's second loss): if ``surface_distance_fn`` is given and
    ``surface_weight > 0``, the M-step also minimises ``surface_weight`` x (inlier count) x
    the mean squared ``surface_distance_fn`` of ``surface_samples`` points on the current
    superquadric (same scale as the data term), which pulls surfaces that bulge away from the
    object (bowls, mugs) back toward it. ``surface_distance_fn`` maps (K, 3) object-frame
    points (m) to (K,) unsigned distances (m) to the object's surface; it is differenced
    numerically, so it should be continuous and cheap for ~200 points. The M-step's points
    are fixed directions on the canonical box projected onto the surface (smooth in the
    params, only roughly area-uniform); ``surface_mean_m`` is reported on area-uniform
    :func:`sample_surface` points.

    Args:
        points: (N, 3) surface points in metres, N >= 10, finite.
        normals: (N, 3) unit normals or None; accepted for API stability, not used by EMS.
        outlier_ratio: prior outlier probability w0 in [0, 1).
        max_iters: maximum EM iterations (switch attempts included).
        seed: seed of the deterministic subsample (and of the surface directions).
        n_points: the input is subsampled to this many points for speed.
        tol: relative parameter change that counts as converged.
        max_switches: maximum accepted switches.
        m_step_nfev: residual evaluations per M-step (EM repeats, so it need not converge).
        switch_nfev: residual evaluations to refine each switching candidate.
        switch_every: also try switching every this many iterations (0: only on convergence).
        surface_distance_fn, surface_weight, surface_samples: see above.

    Returns:
        params: (11,) float64, see the module docstring.
        diagnostics: floats ``mean_radial_m`` (mean radial distance of all used points),
        ``inlier_mean_radial_m`` (posterior-weighted mean), ``sigma_m``, ``inlier_fraction``,
        ``nll``, ``iters``, ``switches``, ``n_points``, ``seconds`` and, with a surface term,
        ``surface_mean_m`` (mean surface_distance_fn of the superquadric's samples).
    """
    with _single_thread_blas():
        return _fit(
            points,
            normals,
            outlier_ratio=outlier_ratio,
            max_iters=max_iters,
            seed=seed,
            n_points=n_points,
            tol=tol,
            max_switches=max_switches,
            m_step_nfev=m_step_nfev,
            switch_nfev=switch_nfev,
            switch_every=switch_every,
            surface_distance_fn=surface_distance_fn,
            surface_weight=surface_weight,
            surface_samples=surface_samples,
        )


def _fit(
    points: np.ndarray,
    normals: np.ndarray | None,
    *,
    outlier_ratio: float,
    max_iters: int,
    seed: int,
    n_points: int,
    tol: float,
    max_switches: int,
    m_step_nfev: int,
    switch_nfev: int,
    switch_every: int,
    surface_distance_fn: Callable[[np.ndarray], np.ndarray] | None,
    surface_weight: float,
    surface_samples: int,
) -> tuple[np.ndarray, dict[str, float]]:
    """Body of :func:`fit_superquadric` (arguments as documented there)."""
    start = time.perf_counter()
    pts = _check_points(points)
    if len(pts) < MIN_POINTS:
        raise GeomprepError(
            f"got {len(pts)} points, need at least {MIN_POINTS} to fit a superquadric: "
            "sample more surface points"
        )
    if normals is not None:
        nrm = _check_points(normals, "normals")
        if nrm.shape != pts.shape:
            raise GeomprepError("normals must match points in shape: pass one normal per point")
    if not 0.0 <= outlier_ratio < 1.0:
        raise GeomprepError(f"outlier_ratio must be in [0, 1), got {outlier_ratio}: fix the call")
    if surface_weight < 0:
        raise GeomprepError(f"surface_weight must be >= 0, got {surface_weight}: fix the call")
    if not float(np.ptp(pts, axis=0).max()) > 1e-9:
        raise GeomprepError("points are all (nearly) identical: pass points spread over a surface")
    pts = _downsample(pts, n_points, seed)
    state, volume = _initial_state(pts)
    size = float(state.a.max())

    rng = np.random.default_rng(seed)
    dirs = _box_surface_points(np.ones(3), surface_samples, rng)
    problem = _Problem(
        pts,
        float(outlier_ratio),
        -np.log(volume),
        size,
        surface_distance_fn,
        float(surface_weight),
        dirs,
        sigma2_min=(1e-5 * size) ** 2,
    )
    d = state.radial(pts)
    sigma2 = max(float(np.mean(d**2)) / 3.0, problem.sigma2_min)
    switches = 0
    iters = 0
    while iters < max_iters:
        iters += 1
        _, z = problem.e_step(state, sigma2)
        new = problem.m_step(state, z, m_step_nfev)
        d, z = problem.e_step(new, sigma2)
        sigma2 = problem.sigma2_update(d, z)
        change = _relative_change(state, new, size)
        state = new
        converged = change <= tol
        # EM can also creep for many iterations toward a degenerate fit that explains only
        # part of the points; offering the switch periodically catches that too.
        periodic = switch_every > 0 and iters % switch_every == 0
        if not (converged or periodic) or switches >= max_switches:
            if converged:
                break
            continue
        best, best_sigma2 = _try_switch(problem, state, sigma2, switch_nfev)
        if best is not None:
            state, sigma2 = best, best_sigma2
            switches += 1
        elif converged:
            break

    state = _prefer_square_section(problem, state, sigma2, switch_nfev)
    d, z = problem.e_step(state, sigma2)
    diag = {
        "mean_radial_m": float(d.mean()),
        "inlier_mean_radial_m": float(np.sum(z * d) / max(z.sum(), 1e-12)),
        "sigma_m": float(np.sqrt(sigma2)),
        "inlier_fraction": float(z.mean()),
        "nll": problem.objective(state, sigma2),
        "iters": float(iters),
        "switches": float(switches),
        "n_points": float(len(pts)),
    }
    if surface_distance_fn is not None:
        # Reported on area-uniform samples (the M-step's fixed directions are only roughly so).
        surf = sample_surface(state.params(), max(surface_samples, 200), seed=seed)
        diag["surface_mean_m"] = float(np.mean(surface_distance_fn(surf)))
    diag["seconds"] = time.perf_counter() - start
    return state.params(), diag


def _try_switch(
    problem: _Problem, state: _State, sigma2: float, nfev: int
) -> tuple[_State | None, float]:
    """Best switching candidate if it beats ``state``'s objective, else (None, sigma2)."""
    current = problem.objective(state, sigma2)
    best: _State | None = None
    best_obj, best_sigma2 = current, sigma2
    for cand in _switch_candidates(state):
        _, z = problem.e_step(cand, sigma2)
        cand = problem.m_step(cand, z, nfev)
        d, z = problem.e_step(cand, sigma2)
        cand_sigma2 = problem.sigma2_update(d, z)
        # Compare at the current sigma^2 so the two objectives share a scale.
        obj = problem.objective(cand, sigma2)
        # A relative margin stops switching back and forth between equivalent parameter sets.
        if obj < best_obj - 1e-3 * abs(best_obj) - 1e-6:
            best, best_obj, best_sigma2 = cand, obj, cand_sigma2
    return best, best_sigma2


def _prefer_square_section(problem: _Problem, state: _State, sigma2: float, nfev: int) -> _State:
    """Report a square cross-section rather than the equivalent 45-degree diamond.

    A box fits equally well as eps2 ~ 0.1 or as eps2 ~ 2 turned by 45 degrees about z; the
    former is the conventional description (and what a policy sees for other boxes), so the
    diamond's dual is kept when it fits about as well (inlier-weighted mean radial distance
    at most 0.3 % of the size worse: eps2 >= 0.1 rounds the corners a little, which the exact
    diamond eps2 = 2 does not).
    """
    # Only a near-exact diamond with equal diagonals has a near-exact square dual.
    a1, a2 = state.a[0], state.a[1]
    if state.e[1] <= 1.9 or abs(a1 - a2) > 0.1 * max(a1, a2):
        return state
    dual = _switch_candidates(state)[-3]  # the xy dual of the un-relabelled state
    _, z = problem.e_step(dual, sigma2)
    dual = problem.m_step(dual, z, nfev)

    def score(s: _State) -> float:
        d, z = problem.e_step(s, sigma2)
        return float(np.sum(z * d) / max(z.sum(), 1e-12))

    if score(dual) <= score(state) + 3e-3 * problem.size:
        return dual
    return state
