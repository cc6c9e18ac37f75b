"""Stage 7, pc: well-spread points on the mesh surface, with their normals.

Uniform area sampling alone clusters points by chance; farthest-point sampling over a dense
uniform candidate set spreads them evenly, which matters most for the 32-point cloud.
"""

from __future__ import annotations

import numpy as np

from geomprep.errors import GeomprepError

VERSION = 1


def sample_uniform(
    vertices: np.ndarray, faces: np.ndarray, count: int, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """``count`` points uniform by area on the triangles, and the triangles' unit normals.

    Args:
        vertices: (V, 3) metres. faces: (F, 3) int.
    Returns:
        points (count, 3) float64 metres, normals (count, 3) float64 (face normals).
    """
    tri = np.asarray(vertices, dtype=np.float64)[faces]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    doubled_area = np.linalg.norm(cross, axis=1)
    if not doubled_area.sum() > 0:
        raise GeomprepError("mesh has zero surface area: nothing to sample")
    face = rng.choice(len(faces), size=count, p=doubled_area / doubled_area.sum())
    # Fold the unit square onto the triangle so barycentric samples are uniform.
    u, v = rng.random((2, count))
    flip = u + v > 1
    u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
    t = tri[face]
    points = t[:, 0] + u[:, None] * (t[:, 1] - t[:, 0]) + v[:, None] * (t[:, 2] - t[:, 0])
    normals = cross[face] / np.maximum(doubled_area[face], 1e-30)[:, None]
    return points, normals


def farthest_point_indices(points: np.ndarray, count: int, start: int = 0) -> np.ndarray:
    """Indices of ``count`` points chosen greedily, each the farthest from those chosen so far.

    Args:
        points: (N, 3). count: <= N. start: index of the first pick.
    Returns:
        (count,) int64 indices, in pick order (so a prefix is itself well spread).
    """
    if count > len(points):
        raise GeomprepError(f"cannot pick {count} points from {len(points)} candidates")
    chosen = np.empty(count, dtype=np.int64)
    chosen[0] = start
    dist = np.sum((points - points[start]) ** 2, axis=1)
    for k in range(1, count):
        chosen[k] = int(np.argmax(dist))
        dist = np.minimum(dist, np.sum((points - points[chosen[k]]) ** 2, axis=1))
    return chosen


def sample_pointclouds(
    vertices: np.ndarray,
    faces: np.ndarray,
    sizes: tuple[int, ...],
    candidates: int,
    seed: int,
) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """One farthest-point cloud per size, all drawn from one uniform candidate set.

    Returns:
        {size: (points (size, 3) float64 metres, normals (size, 3) float64 unit)}.
        The clouds are nested: the first 32 points of the 512-cloud are the 32-cloud.
    """
    rng = np.random.default_rng(seed)
    points, normals = sample_uniform(vertices, faces, candidates, rng)
    order = farthest_point_indices(points, max(sizes), start=int(rng.integers(candidates)))
    return {n: (points[order[:n]], normals[order[:n]]) for n in sizes}
