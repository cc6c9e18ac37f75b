"""Oriented bounding box of a mesh along its principal axes.

The principal axes are the eigenvectors of the area-weighted covariance of the mesh *surface*
(uniform density over the triangles, not over the vertices, so that finely tessellated regions
do not pull the axes). Where two or three eigenvalues are (nearly) equal the axes inside that
eigenspace are arbitrary (cylinders, cubes, spheres); there the rotation inside the degenerate
subspace is chosen to minimise the box volume instead.

Deterministic output convention (documented in :func:`oriented_bbox`): columns sorted by
decreasing extent, each of the first two columns signed so that its largest-magnitude component
is positive, and the third column is ``cross(col0, col1)`` (right-handed, det = +1).
"""

from __future__ import annotations

import numpy as np
import trimesh
from scipy.spatial import ConvexHull, QhullError

from geomprep.errors import GeomprepError
from geomprep.mesh import reduced

# Bump when the output for the same input changes (the pipeline's cache key uses it).
VERSION = 2

# Relative eigenvalue gap (of the largest eigenvalue) below which two principal axes count as
# degenerate. Generous on purpose: inside a "degenerate" pair we pick the min-volume rotation,
# which is never worse than the PCA rotation, so a false positive costs nothing but time.
DEGENERATE_TOL = 0.05

MIN_POINTS = 4  # a tetrahedron: the fewest vertices a solid can have


def _validate_vertices(vertices: np.ndarray) -> np.ndarray:
    v = np.asarray(vertices, dtype=np.float64)
    if v.ndim != 2 or v.shape[1] != 3:
        raise GeomprepError(
            f"vertices must have shape (N, 3), got {v.shape}: pass the mesh's vertex array"
        )
    if len(v) < MIN_POINTS:
        raise GeomprepError(
            f"mesh has {len(v)} vertices, need at least {MIN_POINTS}: check the mesh file loaded"
        )
    if not np.all(np.isfinite(v)):
        raise GeomprepError("mesh vertices contain NaN or inf: repair or re-export the mesh")
    if not float(np.ptp(v, axis=0).max()) > 0.0:
        raise GeomprepError("all mesh vertices coincide: check the mesh file loaded")
    return v


def _surface_covariance(v: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted covariance (3, 3) of the triangle surface, m^2; vertex covariance fallback.

    Uses the exact second moment of a uniform triangle, E[x x^T] = (sum v_i v_i^T + s s^T) / 12
    with s = v0 + v1 + v2, so the result does not depend on the tessellation.
    """
    f = np.asarray(faces)
    if f.ndim == 2 and f.shape[1] == 3 and len(f) > 0:
        if not np.issubdtype(f.dtype, np.integer) or f.min() < 0 or f.max() >= len(v):
            raise GeomprepError(
                "faces must be (M, 3) integer indices into vertices: re-load the mesh"
            )
        tri = v[f]  # (M, 3, 3)
        area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
        total = area.sum()
        if total > 0 and np.isfinite(total):
            s = tri.sum(axis=1)  # (M, 3)
            second = np.einsum("mki,mkj->mij", tri, tri) + np.einsum("mi,mj->mij", s, s)
            second = np.einsum("m,mij->ij", area, second) / (12.0 * total)
            mean = (area[:, None] * s).sum(axis=0) / (3.0 * total)
            return second - np.outer(mean, mean)
    # No usable faces (point cloud or zero-area mesh): fall back to the vertex covariance.
    return np.cov(v.T)


def _hull_points(v: np.ndarray) -> np.ndarray:
    """Convex hull vertices (the box of the hull equals the box of all vertices); all if flat."""
    try:
        return v[ConvexHull(v).vertices]
    except (QhullError, ValueError):
        return v


def _min_area_angle(p2: np.ndarray) -> float:
    """Angle (rad) rotating 2-D points so their axis-aligned rectangle has minimum area.

    A minimum-area enclosing rectangle has a side collinear with a convex hull edge, so it
    suffices to test each hull edge direction (rotating-calipers argument).
    """
    try:
        hull = p2[ConvexHull(p2).vertices]
    except (QhullError, ValueError):
        hull = p2  # collinear points: any edge direction of the data works as a candidate
    edges = np.roll(hull, -1, axis=0) - hull
    angles = np.mod(np.arctan2(edges[:, 1], edges[:, 0]), np.pi / 2)
    angles = np.unique(np.round(angles, 12))
    c, s = np.cos(angles), np.sin(angles)
    # Coordinates of every hull point along the rotated axes, per candidate angle: (K, H).
    u = c[:, None] * hull[None, :, 0] + s[:, None] * hull[None, :, 1]
    w = -s[:, None] * hull[None, :, 0] + c[:, None] * hull[None, :, 1]
    area = (u.max(1) - u.min(1)) * (w.max(1) - w.min(1))
    return float(angles[int(np.argmin(area))])


def _degenerate(evals: np.ndarray) -> list[bool]:
    """Whether eigenvalue pairs (0, 1) and (1, 2) of ``evals`` (sorted decreasing) are close."""
    scale = max(float(evals[0]), 1e-30)
    return [bool((evals[i] - evals[i + 1]) / scale < DEGENERATE_TOL) for i in range(2)]


def _refine_degenerate(v: np.ndarray, axes: np.ndarray, evals: np.ndarray) -> np.ndarray:
    """Replace arbitrary axes inside (nearly) degenerate eigenspaces by min-volume ones.

    ``axes`` columns are eigenvectors sorted by decreasing eigenvalue ``evals``.
    """
    close = _degenerate(evals)
    if all(close):
        # Fully degenerate (cube, sphere, dice): no preferred axis, take the global
        # minimum-volume box that trimesh finds over the hull.
        with np.errstate(invalid="ignore"):  # trimesh casts NaNs of flat hull facets; harmless
            to_origin, _ = trimesh.bounds.oriented_bounds(v)
        return np.asarray(to_origin[:3, :3], dtype=np.float64).T
    if not any(close):
        return axes
    i, j = (0, 1) if close[0] else (1, 2)
    k = 3 - i - j
    # The volume is (extent along the unique axis) x (area in the degenerate plane), so
    # minimising the plane's rectangle area minimises the volume.
    p2 = np.stack([v @ axes[:, i], v @ axes[:, j]], axis=1)
    theta = _min_area_angle(p2)
    c, s = np.cos(theta), np.sin(theta)
    out = axes.copy()
    out[:, i] = c * axes[:, i] + s * axes[:, j]
    out[:, j] = -s * axes[:, i] + c * axes[:, j]
    out[:, k] = axes[:, k]
    return out


def _canonical_axes(axes: np.ndarray, extents: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sort columns by decreasing extent, sign them, and make the frame right-handed."""
    order = np.argsort(-extents, kind="stable")
    axes = axes[:, order]
    extents = extents[order]
    for c in range(2):
        col = axes[:, c]
        if col[int(np.argmax(np.abs(col)))] < 0:
            axes[:, c] = -col
    axes[:, 2] = np.cross(axes[:, 0], axes[:, 1])
    return axes, extents


def oriented_bbox(
    vertices: np.ndarray, faces: np.ndarray, max_faces: int | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Oriented bounding box of a mesh along its principal axes.

    Principal axes are the eigenvectors of the area-weighted covariance of the triangle surface
    (second moment about the surface centroid; if ``faces`` is empty or has zero area, of the
    vertices). Inside a degenerate eigenspace (relative eigenvalue gap < ``DEGENERATE_TOL``)
    the rotation minimises the box volume: exact rotating-calipers search for a 2-fold
    degeneracy, ``trimesh.bounds.oriented_bounds`` (global min-volume box) for a 3-fold one.

    Axis convention (deterministic): columns sorted by decreasing extent; columns 0 and 1 are
    signed so that their largest-magnitude component is positive; column 2 is
    ``cross(col0, col1)``, so ``det(rotation) = +1``.

    Large meshes: the covariance, the hull and the 2-fold search are (near) linear in the mesh,
    but the 3-fold search (``oriented_bounds``) grows with the square of the hull's size (41 s
    on a 916k-face sphere), so a mesh of more than ``max_faces`` triangles runs it on the hull
    of ``mesh.reduced``'s coarser copy.  The centre and extents always come from all vertices,
    so the containment guarantee below is unaffected.

    Args:
        vertices: (N, 3) vertex positions in metres (object frame), N >= 10, finite.
        faces: (M, 3) integer vertex indices (may be empty, shape (0, 3)).
        max_faces: triangle budget of the 3-fold min-volume search; None: no budget.

    Returns:
        center: (3,) float32, box centre in metres (object frame; the midpoint of the vertex
            extremes along each axis, not the centroid).
        rotation: (3, 3) float32, columns are the box axes in the object frame.
        extents: (3,) float32, full edge lengths in metres along those columns; every vertex
            satisfies ``|rotation.T @ (v - center)| <= extents / 2`` up to float32 rounding.
    """
    v = _validate_vertices(vertices)
    cov = _surface_covariance(v, faces)
    evals, evecs = np.linalg.eigh(cov)
    order = np.argsort(-evals)
    evals, axes = evals[order], evecs[:, order]
    f = np.asarray(faces)
    if max_faces is not None and len(f) > max_faces and all(_degenerate(evals)):
        # Only the global min-volume search grows with the square of the hull's size.
        hull = _hull_points(reduced(v, f, max_faces)[0])
    else:
        hull = _hull_points(v)
    axes = _refine_degenerate(hull, axes, evals)
    # Re-orthonormalise so the later containment guarantee holds to float precision.
    axes, _ = np.linalg.qr(axes)
    # Extents over every vertex: the hull of a reduced mesh may miss some.
    proj = v @ axes
    lo, hi = proj.min(axis=0), proj.max(axis=0)
    axes, _ = _canonical_axes(axes, hi - lo)
    proj = v @ axes
    lo, hi = proj.min(axis=0), proj.max(axis=0)
    center = axes @ ((lo + hi) / 2.0)
    extents = hi - lo
    # float32 rounding of centre/rotation could push an extreme vertex a hair outside; pad by
    # a few ulps of the object's size so containment holds for the returned float32 values.
    pad = 4.0 * np.finfo(np.float32).eps * (np.abs(v).max() + extents.max())
    return (
        center.astype(np.float32),
        axes.astype(np.float32),
        (extents + 2.0 * pad).astype(np.float32),
    )
