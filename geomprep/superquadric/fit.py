"""Robust recovery of a superquadric from surface points (EMS), with an optional surface term.

Fitting follows the idea of EMS (Liu et al., CVPR 2022): maximum likelihood of the points under
a Gaussian on the radial distance to the surface mixed with a uniform outlier density, solved by
EM with a bounded least-squares M-step, plus a "switching" step that jumps between parameter
sets describing the same or similar shapes to escape local minima. The implementation here is
written from the paper's description, not from the reference code. Parameters follow the data
contract in :mod:`.geometry`.
"""

from __future__ import annotations

import functools
import time
from collections.abc import Callable
from typing import Any, TypeVar

import numpy as np
from scipy.optimize import least_squares
from threadpoolctl import threadpool_limits

from geomprep.errors import GeomprepError
from geomprep.superquadric.geometry import (
    EPS_MAX,
    EPS_MIN,
    _box_surface_points,
    _check_points,
    _radial_canonical,
    _radial_with_grad,
    _surface_canonical,
    _surface_canonical_with_grad,
    make_params,
    sample_surface,
)

T = TypeVar("T")

MIN_POINTS = 10


class _SurfaceOracle:
    """Unsigned distance (K,) m to the object's surface and its gradient w.r.t. the query point.

    With ``closest_fn`` (closest surface points (K, 3)) the gradient is exact: the unit vector
    from the closest point. With only ``distance_fn`` it is a forward difference along the
    three axes, evaluated in one batched call of 3K points.
    """

    def __init__(
        self,
        distance_fn: Callable[[np.ndarray], np.ndarray] | None,
        closest_fn: Callable[[np.ndarray], np.ndarray] | None,
        size: float,
    ) -> None:
        self.distance_fn = distance_fn
        self.closest_fn = closest_fn
        self.size = size

    def _clean(self, d: np.ndarray) -> np.ndarray:
        # A failed query (NaN / inf) counts as far away rather than poisoning the solver.
        return np.nan_to_num(np.asarray(d, dtype=np.float64), nan=self.size, posinf=self.size)

    def distance(self, p: np.ndarray) -> np.ndarray:
        if self.closest_fn is not None:
            return self._clean(np.linalg.norm(p - np.asarray(self.closest_fn(p)), axis=1))
        return self._clean(self.distance_fn(p))  # type: ignore[misc]

    def distance_and_offset(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """Distances (K,) and, with closest points, the offsets p - closest (K, 3) (else None)."""
        if self.closest_fn is None:
            return self.distance(p), None
        diff = p - np.asarray(self.closest_fn(p), dtype=np.float64)
        return self._clean(np.linalg.norm(diff, axis=1)), np.nan_to_num(diff)

    def gradient(self, p: np.ndarray, d: np.ndarray, offset: np.ndarray | None) -> np.ndarray:
        """Gradient (K, 3) of the distance at p, given :meth:`distance_and_offset`'s output."""
        if offset is not None:
            # On the surface the unsigned distance has no gradient; zero is the subgradient
            # that leaves such a sample alone.
            dist = np.linalg.norm(offset, axis=1)
            return np.where((dist > 1e-12)[:, None], offset / np.maximum(dist, 1e-12)[:, None], 0)
        h = 1e-4 * self.size  # well above float32 resolution of typical distance backends
        probes = (p[None, :, :] + h * np.eye(3)[:, None, :]).reshape(-1, 3)
        dp = self._clean(self.distance_fn(probes)).reshape(3, -1)  # type: ignore[misc]
        return ((dp - d) / h).T

    def distance_and_gradient(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Distances (K,) m and their gradients (K, 3) w.r.t. the points p (K, 3) m."""
        d, offset = self.distance_and_offset(p)
        return d, self.gradient(p, d, offset)


def _single_threaded_blas(fit: Callable[..., T]) -> Callable[..., T]:
    """Run ``fit`` with BLAS/LAPACK single-threaded: the fit's matrices are tiny (1500 x 11),
    and OpenBLAS worker threads made it 10-20x slower on a busy 2-core machine."""

    @functools.wraps(fit)
    def wrapper(*args: Any, **kwargs: Any) -> T:
        with threadpool_limits(limits=1, user_api="blas"):
            return fit(*args, **kwargs)

    return wrapper


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
        surface: _SurfaceOracle | None,
        surface_weight: float,
        surface_dirs: np.ndarray,
        sigma2_min: float,
    ) -> None:
        self.pts = pts
        self.w0 = w0
        self.log_p0 = log_p0
        self.size = size
        self.surface = surface
        self.surface_weight = surface_weight
        self.surface_dirs = surface_dirs  # (K, 3) directions on the unit box surface
        self.sigma2_min = sigma2_min

    @property
    def use_surface(self) -> bool:
        return self.surface is not None and self.surface_weight > 0

    def surface_points(self, s: _State) -> np.ndarray:
        """Points (K, 3) on the current superquadric in the object frame, smooth in the params."""
        return _surface_canonical(self.surface_dirs, s.e, s.a) @ s.rot.T + s.t

    def surface_term(self, s: _State) -> np.ndarray:
        return self.surface.distance(self.surface_points(s))  # type: ignore[union-attr]

    def objective(self, s: _State, sigma2: float) -> float:
        """Negative log-likelihood plus the (likelihood-scaled) surface term."""
        d = s.radial(self.pts)
        _, log_mix, z = _log_mix(d, sigma2, self.w0, self.log_p0)
        nll = -float(log_mix.sum())
        if self.use_surface:
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
        use_surface = self.use_surface
        surf_scale = np.sqrt(self.surface_weight * z.sum() / max(len(self.surface_dirs), 1))

        pts = self.pts
        dirs = self.surface_dirs

        # least_squares asks for the residuals and then the Jacobian at the same x; one pass
        # computes both (for the surface term, one closest-point query serves both).
        data_cache: dict[bytes, tuple[np.ndarray, Any]] = {}
        surf_cache: dict[bytes, tuple[np.ndarray, Any]] = {}

        def cached(
            cache: dict[bytes, tuple[np.ndarray, Any]],
            fn: Callable[[np.ndarray], tuple[np.ndarray, Any]],
            x: np.ndarray,
        ) -> tuple[np.ndarray, Any]:
            key = x.tobytes()
            if key not in cache:
                cache.clear()
                cache[key] = fn(x)
            return cache[key]

        def data_terms(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            """Weighted radial residuals (N,) and their exact Jacobian (N, 11)."""
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

        def surface_values(x: np.ndarray) -> tuple[np.ndarray, tuple[Any, ...]]:
            """Weighted surface residuals (K,) and what their Jacobian reuses: the samples
            (K, 3) m, distances (K,) m and closest-point offsets (K, 3) or None. Trial steps
            that trf rejects never pay for the Jacobian."""
            p = _surface_canonical(dirs, x[0:2], x[2:5]) @ (rot0 @ _rotvec_matrix(x[5:8])).T
            p += x[8:11]
            d, offset = self.surface.distance_and_offset(p)  # type: ignore[union-attr]
            return surf_scale * d, (p, d, offset)

        def surface_jacobian(x: np.ndarray) -> np.ndarray:
            """Jacobian (K, 11) of the weighted surface residuals.

            Chain rule: the distance gradient w.r.t. the sample (the unit vector from its
            closest mesh point) times d(sample)/d(params), analytic for the pose and by cheap
            central differences of the closed-form projection for exponents and semi-axes.
            This replaced 11 forward-difference distance queries per Jacobian.
            """
            p, d, offset = cached(surf_cache, surface_values, x)[1]
            g = self.surface.gradient(p, d, offset)  # type: ignore[union-attr]
            rot = rot0 @ _rotvec_matrix(x[5:8])
            sc, dsc = _surface_canonical_with_grad(dirs, x[0:2], x[2:5])
            gc = g @ rot  # gradient in the canonical frame
            jac = np.empty((len(g), 11))
            jac[:, 0:5] = np.einsum("ki,kij->kj", gc, dsc)
            # p = R exp([delta]) s + t moves by R (delta x s): d/d delta = s x g_c.
            jac[:, 5:8] = np.cross(sc, gc) @ _right_jacobian(x[5:8])
            jac[:, 8:11] = g
            return surf_scale * jac

        def residuals(x: np.ndarray) -> np.ndarray:
            r = cached(data_cache, data_terms, x)[0]
            if use_surface:
                r = np.concatenate([r, cached(surf_cache, surface_values, x)[0]])
            return r

        def jacobian(x: np.ndarray) -> np.ndarray:
            jac = cached(data_cache, data_terms, x)[1]
            if use_surface:
                jac = np.vstack([jac, surface_jacobian(x)])
            return jac

        def unpack(x: np.ndarray) -> _State:
            st = _State.__new__(_State)
            st.e, st.a, st.t = x[0:2], x[2:5], x[8:11]
            st.rot = rot0 @ _rotvec_matrix(x[5:8])
            return st

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


@_single_threaded_blas
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
    surface_closest_fn: Callable[[np.ndarray], np.ndarray] | None = None,
    surface_weight: float = 0.0,
    surface_samples: int = 200,
) -> tuple[np.ndarray, dict[str, float]]:
    """Fit a superquadric to surface points with EMS (expectation, maximisation, switching).

    Model: each point is an inlier with prior 1 - ``outlier_ratio``, with density a Gaussian
    (isotropic 3-D normalisation, variance sigma^2) of its radial distance d to the surface,
    or an outlier, uniform over the points' principal-axes box. EM alternates:
    E-step (inlier posterior z_i), M-step (bounded ``least_squares`` on sqrt(z_i) d_i over
    exponents in [0.1, 2], semi-axes, a local rotation vector and translation), sigma^2
    update. Convergence: the relative parameter change of one iteration (exponents / 2,
    semi-axes and translation / object size, rotation by the Frobenius norm of R_old^T R_new -
    I) drops to ``tol``; then (and every ``switch_every`` iterations) the switching step tries
    shapes equivalent or similar to the current one (axis relabellings, square/diamond duals),
    refines each briefly and keeps the best if it lowers the negative log-likelihood; EM then
    continues. It stops when converged and no switch helps, after ``max_switches`` accepted
    switches and convergence, or after ``max_iters`` iterations.

    Regularisation (the paper's second loss): with ``surface_closest_fn`` or
    ``surface_distance_fn`` and ``surface_weight > 0``, the M-step also minimises
    ``surface_weight`` x (inlier count) x the mean squared distance to the object's surface of
    ``surface_samples`` points on the current superquadric (same scale as the data term),
    which pulls surfaces that bulge away from the object (bowls, mugs) back toward it. The
    M-step's points are fixed directions on the canonical box projected onto the surface
    (smooth in the params, only roughly area-uniform); ``surface_mean_m`` is reported on
    area-uniform :func:`sample_surface` points.

    Args:
        points: (N, 3) surface points in metres, N >= 10, finite.
        normals: (N, 3) unit normals or None; accepted for API stability, not used by EMS.
        outlier_ratio: prior outlier probability w0 in [0, 1).
        max_iters: maximum EM iterations (switch attempts included), >= 1.
        seed: seed of the deterministic subsample (and of the surface directions).
        n_points: the input is subsampled to this many points for speed.
        tol: relative parameter change that counts as converged, > 0.
        max_switches: maximum accepted switches (0 disables switching).
        m_step_nfev: residual evaluations per M-step (EM repeats, so it need not converge).
        switch_nfev: residual evaluations to refine each switching candidate.
        switch_every: also try switching every this many iterations (0: only on convergence).
        surface_closest_fn: maps (K, 3) object-frame points (m) to the (K, 3) closest points on
            the object's surface (preferred: gives the surface term's exact gradient; see
            :class:`.quality.MeshOracle`).
        surface_distance_fn: maps (K, 3) points to (K,) unsigned distances (m) to the object's
            surface; used when no ``surface_closest_fn`` is given (gradient by forward
            differences, one extra batched call of 3K points per Jacobian).
        surface_weight: weight of the surface term, >= 0 (0: EMS alone).
        surface_samples: K, points on the superquadric for the surface term.

    Returns:
        params: (11,) float64, see :mod:`.geometry`.
        diagnostics: floats ``mean_radial_m`` (mean radial distance of all used points),
        ``inlier_mean_radial_m`` (posterior-weighted mean), ``sigma_m``, ``inlier_fraction``,
        ``nll``, ``iters``, ``switches``, ``converged`` (1.0 if the tolerance was reached,
        0.0 if ``max_iters`` ran out), ``n_points``, ``seconds`` and, with a surface term,
        ``surface_mean_m`` (mean distance of the superquadric's samples to the object).
    """
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
    _check_options(
        outlier_ratio,
        max_iters,
        n_points,
        tol,
        max_switches,
        m_step_nfev,
        switch_nfev,
        switch_every,
        surface_weight,
        surface_samples,
    )
    if not float(np.ptp(pts, axis=0).max()) > 1e-9:
        raise GeomprepError("points are all (nearly) identical: pass points spread over a surface")
    pts = _downsample(pts, n_points, seed)
    state, volume = _initial_state(pts)
    size = float(state.a.max())

    rng = np.random.default_rng(seed)
    dirs = _box_surface_points(np.ones(3), surface_samples, rng)
    oracle = None
    if surface_closest_fn is not None or surface_distance_fn is not None:
        oracle = _SurfaceOracle(surface_distance_fn, surface_closest_fn, size)
    problem = _Problem(
        pts,
        float(outlier_ratio),
        -np.log(volume),
        size,
        oracle,
        float(surface_weight),
        dirs,
        sigma2_min=(1e-5 * size) ** 2,
    )
    d = state.radial(pts)
    sigma2 = max(float(np.mean(d**2)) / 3.0, problem.sigma2_min)
    switches = 0
    iters = 0
    converged = False
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
            converged = False  # the switched state has not been iterated yet
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
        "converged": float(converged),
        "n_points": float(len(pts)),
    }
    if oracle is not None:
        # Reported on area-uniform samples (the M-step's fixed directions are only roughly so).
        surf = sample_surface(state.params(), max(surface_samples, 200), seed=seed)
        diag["surface_mean_m"] = float(np.mean(oracle.distance(surf)))
    diag["seconds"] = time.perf_counter() - start
    return state.params(), diag


def _check_options(
    outlier_ratio: float,
    max_iters: int,
    n_points: int,
    tol: float,
    max_switches: int,
    m_step_nfev: int,
    switch_nfev: int,
    switch_every: int,
    surface_weight: float,
    surface_samples: int,
) -> None:
    """Raise GeomprepError with the fix for any out-of-range fitting option."""
    checks = [
        (0.0 <= outlier_ratio < 1.0, f"outlier_ratio must be in [0, 1), got {outlier_ratio}"),
        (max_iters >= 1, f"max_iters must be >= 1, got {max_iters}"),
        (n_points >= MIN_POINTS, f"n_points must be >= {MIN_POINTS}, got {n_points}"),
        (tol > 0, f"tol must be > 0, got {tol}"),
        (max_switches >= 0, f"max_switches must be >= 0, got {max_switches}"),
        (m_step_nfev >= 1 and switch_nfev >= 1, "m_step_nfev and switch_nfev must be >= 1"),
        (switch_every >= 0, f"switch_every must be >= 0, got {switch_every}"),
        (surface_weight >= 0, f"surface_weight must be >= 0, got {surface_weight}"),
        (surface_samples >= 1, f"surface_samples must be >= 1, got {surface_samples}"),
    ]
    for ok, message in checks:
        if not ok:
            raise GeomprepError(f"{message}: fix the call or the [sq] config")


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
