"""Fit quality of a superquadric against a mesh: mesh queries, two-sided distances, volume IoU."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from scipy.spatial import cKDTree

from geomprep.superquadric.geometry import (
    _bounds_of,
    _check_points,
    implicit,
    radial_distance,
    sample_surface,
    sample_surface_dense,
)
from geomprep.syslibs import import_open3d


class MeshOracle:
    """Closest points, distances and inside tests for a triangle mesh (open3d / embree).

    Args:
        vertices: (V, 3) metres. faces: (F, 3) int.
        threads: open3d query threads; 1 by default because the fit's queries are small
            (~200 points) and the pipeline already runs objects in parallel.
    """

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, threads: int = 1) -> None:
        o3d = import_open3d()  # heavy import, only where a mesh is queried

        self._o3d = o3d
        self.threads = threads
        self.scene = o3d.t.geometry.RaycastingScene()
        self.scene.add_triangles(
            o3d.core.Tensor(np.asarray(vertices, dtype=np.float32)),
            o3d.core.Tensor(np.asarray(faces, dtype=np.uint32)),
        )
        v = np.asarray(vertices, dtype=np.float64)
        self.bounds = (v.min(axis=0), v.max(axis=0))

    def _query(self, points: np.ndarray) -> object:
        return self._o3d.core.Tensor(np.asarray(points, dtype=np.float32).reshape(-1, 3))

    def closest(self, points: np.ndarray) -> np.ndarray:
        """Closest surface points (N, 3) float64 m of query points (N, 3) m."""
        out = self.scene.compute_closest_points(self._query(points), nthreads=self.threads)
        return out["points"].numpy().astype(np.float64)

    def distance(self, points: np.ndarray) -> np.ndarray:
        """Unsigned distance (N,) float64 m to the surface."""
        return self.scene.compute_distance(self._query(points), nthreads=self.threads).numpy()

    def inside(self, points: np.ndarray, nsamples: int = 7) -> np.ndarray:
        """Inside mask (N,) bool: majority vote of ``nsamples`` ray parity tests (odd).

        A single ray misclassifies points whose ray leaves through a hole of an open scan;
        the vote over random directions is robust to small holes.
        """
        occ = self.scene.compute_occupancy(
            self._query(points), nthreads=self.threads, nsamples=nsamples
        )
        return occ.numpy() > 0.5


def volume_iou(
    params: np.ndarray,
    inside_mesh: Callable[[np.ndarray], np.ndarray],
    mesh_bounds: tuple[np.ndarray, np.ndarray],
    voxel: float = 0.0025,
    max_cells: int = 1_000_000,
) -> float:
    """Volume intersection-over-union of the superquadric and a solid, on a voxel grid.

    Cell centres fill the union of the superquadric's and the solid's bounding boxes; a cell is
    inside the superquadric when ``implicit <= 1`` and inside the solid when ``inside_mesh``
    says so (e.g. :meth:`MeshOracle.inside`).

    Args:
        params: (11,) superquadric.
        inside_mesh: maps (N, 3) points m to an (N,) bool mask.
        mesh_bounds: the solid's axis-aligned bounds, two (3,) arrays, m.
        voxel: cell edge, m; grown so that the grid has at most ``max_cells`` cells (the IoU
            of objects larger than ~25 cm is then measured at a coarser step).

    Returns:
        IoU in [0, 1]; 0 if both are empty on the grid.
    """
    lo_s, hi_s = _bounds_of(params)
    lo = np.minimum(lo_s, np.asarray(mesh_bounds[0], dtype=np.float64))
    hi = np.maximum(hi_s, np.asarray(mesh_bounds[1], dtype=np.float64))
    span = hi - lo
    voxel = max(voxel, float(np.prod(span) / max_cells) ** (1.0 / 3.0))
    counts = np.maximum(np.ceil(span / voxel).astype(int), 1)
    axes = [lo[i] + (np.arange(counts[i]) + 0.5) * span[i] / counts[i] for i in range(3)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    in_sq = implicit(params, grid) <= 1.0
    in_mesh = np.asarray(inside_mesh(grid), dtype=bool)
    union = int(np.count_nonzero(in_sq | in_mesh))
    return float(np.count_nonzero(in_sq & in_mesh) / union) if union else 0.0


def fit_quality(
    params: np.ndarray,
    mesh_points: np.ndarray,
    oracle: MeshOracle,
    seed: int = 0,
    n_sq_samples: int = 2000,
    voxel: float = 0.0025,
) -> dict[str, float]:
    """Two-sided distances (m) and volume IoU of a fitted superquadric against a mesh.

    - ``mesh_to_sq_{mean,p95}_m``: over ``mesh_points`` (N, 3) m (area-uniform samples of the
      mesh), the distance to the superquadric: the smaller of the radial distance and the
      distance to the nearest of 50k dense surface samples (both are upper bounds of the
      Euclidean distance; the radial one is exact on the surface, the sampled one far from
      the centre).
    - ``sq_to_mesh_{mean,p95}_m``: over ``n_sq_samples`` area-uniform superquadric samples, the
      exact distance to the mesh.
    - ``volume_iou``: :func:`volume_iou` with the oracle's majority-vote inside test.
    """
    pts = _check_points(mesh_points, "mesh_points")
    dense = sample_surface_dense(params, 50_000, seed=seed)
    nearest = cKDTree(dense).query(pts)[0]
    mesh_to_sq = np.minimum(radial_distance(params, pts), nearest)
    sq_to_mesh = oracle.distance(sample_surface(params, n_sq_samples, seed=seed))
    return {
        "mesh_to_sq_mean_m": float(mesh_to_sq.mean()),
        "mesh_to_sq_p95_m": float(np.percentile(mesh_to_sq, 95)),
        "sq_to_mesh_mean_m": float(sq_to_mesh.mean()),
        "sq_to_mesh_p95_m": float(np.percentile(sq_to_mesh, 95)),
        "volume_iou": volume_iou(params, oracle.inside, oracle.bounds, voxel=voxel),
    }
