"""Stage 2, decompose: split the mesh into convex hulls that MuJoCo collides quickly.

MuJoCo collides each mesh geom as its convex hull, so a concave object (a mug, a bowl) needs a
union of convex parts to be grasped realistically. CoACD gives that union; each hull is capped at
``max_hull_vertices`` vertices, because MuJoCo's convex collision cost grows with hull size.
"""

from __future__ import annotations

import numpy as np
import trimesh
from scipy.spatial import ConvexHull, QhullError

from geomprep.config import DecomposeParams
from geomprep.errors import GeomprepError
from geomprep.mesh import reduced

VERSION = 3

Hull = tuple[np.ndarray, np.ndarray]
"""One convex hull: vertices (V, 3) float64 metres, faces (F, 3) int32, outward winding."""


def convex_hull(points: np.ndarray) -> Hull:
    """Convex hull of a point set as (vertices, faces) with outward winding."""
    hull = trimesh.convex.convex_hull(np.asarray(points, dtype=np.float64))
    return np.asarray(hull.vertices), np.asarray(hull.faces, dtype=np.int32)


def limit_vertices(vertices: np.ndarray, max_vertices: int) -> np.ndarray:
    """At most ``max_vertices`` of a convex point set, chosen so their hull stays close to it.

    Greedy outer refinement (as Quickhull, stopped early): start from extreme points and keep
    adding the point farthest outside the current hull. This bounds how much of the object
    the reduced hull misses far better than spreading points evenly.

    Args:
        vertices: (N, 3) metres, typically the vertices of a convex hull.
    Returns:
        (min(N, max_vertices), 3) subset of ``vertices``.
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    if len(vertices) <= max_vertices:
        return vertices
    centred = vertices - vertices.mean(axis=0)
    # Extremes along the principal axes seed a solid start (at least a tetrahedron).
    _, _, axes = np.linalg.svd(centred, full_matrices=False)
    chosen = list(
        dict.fromkeys(
            int(i) for a in axes for i in (np.argmax(centred @ a), np.argmin(centred @ a))
        )
    )
    while len(chosen) < max_vertices:
        try:
            hull = ConvexHull(vertices[chosen])
        except QhullError:  # flat start: add the point farthest from the chosen ones
            gap = np.min(np.linalg.norm(vertices[:, None] - vertices[chosen][None], axis=2), axis=1)
            chosen.append(int(np.argmax(gap)))
            continue
        outside = (vertices @ hull.equations[:, :3].T + hull.equations[:, 3]).max(axis=1)
        outside[chosen] = -np.inf
        best = int(np.argmax(outside))
        if outside[best] <= 1e-9:
            break
        chosen.append(best)
    return vertices[chosen]


def decompose(vertices: np.ndarray, faces: np.ndarray, params: DecomposeParams) -> list[Hull]:
    """Convex decomposition of a mesh (object frame, metres) into at most ``params.max_hulls``.

    A mesh that is already nearly convex (volume / hull volume >= ``params.convex_ratio``) is
    used as one hull without running CoACD, which saves most of the stage's time on boxes,
    cans and balls.

    A mesh of more than ``params.max_faces`` triangles is decomposed from ``mesh.reduced``'s
    coarser copy (its convexity is still judged on the full mesh, whose closedness the copy may
    lose): CoACD remeshes its input at ``preprocess_resolution`` anyway and every hull is cut to
    ``max_hull_vertices``, so the detail is lost either way, while CoACD's and
    ``limit_vertices``' time grows with the input (a 550k-face mug: 58 s, a 330k-face sphere's
    160k hull vertices: 20 s).
    """
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    vertices, faces = reduced(vertices, faces, params.max_faces)
    hull_mesh = trimesh.convex.convex_hull(vertices)
    if hull_mesh.volume <= 0:
        raise GeomprepError("mesh is flat (zero hull volume): it cannot be simulated as a solid")
    if mesh.is_watertight and mesh.volume >= params.convex_ratio * hull_mesh.volume:
        return [
            convex_hull(limit_vertices(np.asarray(hull_mesh.vertices), params.max_hull_vertices))
        ]

    import coacd  # imported here: it prints a banner and is the slowest import of the package

    coacd.set_log_level("error")
    parts = coacd.run_coacd(
        coacd.Mesh(np.asarray(vertices, dtype=np.float64), np.asarray(faces, dtype=np.int64)),
        threshold=params.threshold,
        max_convex_hull=params.max_hulls,
        preprocess_resolution=params.preprocess_resolution,
        resolution=params.sample_resolution,
        mcts_iterations=params.mcts_iterations,
        mcts_max_depth=params.mcts_depth,
        mcts_nodes=params.mcts_nodes,
        decimate=False,  # limit_vertices below keeps the parts' coverage better
        seed=params.seed,
    )
    hulls = []
    for part_vertices, _ in parts:
        points = limit_vertices(
            np.asarray(part_vertices, dtype=np.float64), params.max_hull_vertices
        )
        if len(points) >= 4 and np.linalg.matrix_rank(points - points.mean(axis=0), tol=1e-9) == 3:
            hulls.append(convex_hull(points))
    if not hulls:
        raise GeomprepError("convex decomposition produced no solid hull: check the mesh")
    return hulls


def pack_hulls(hulls: list[Hull]) -> dict[str, np.ndarray]:
    """Hulls as flat arrays for HDF5: concatenated vertices/faces plus per-hull offsets."""
    vertex_counts = np.array([len(v) for v, _ in hulls], dtype=np.int64)
    face_counts = np.array([len(f) for _, f in hulls], dtype=np.int64)
    return {
        "vertices": np.concatenate([v for v, _ in hulls]),
        "faces": np.concatenate([f for _, f in hulls]).astype(np.int32),
        "vertex_counts": vertex_counts,
        "face_counts": face_counts,
    }


def unpack_hulls(arrays: dict[str, np.ndarray]) -> list[Hull]:
    """Inverse of :func:`pack_hulls`."""
    v_split = np.cumsum(arrays["vertex_counts"])[:-1]
    f_split = np.cumsum(arrays["face_counts"])[:-1]
    vertices = np.split(np.asarray(arrays["vertices"], dtype=np.float64), v_split)
    faces = np.split(np.asarray(arrays["faces"], dtype=np.int32), f_split)
    return list(zip(vertices, faces, strict=True))


def distance_outside_hulls(points: np.ndarray, hulls: list[Hull], chunk: int = 4096) -> np.ndarray:
    """How far each point lies outside the union of the hulls (0 inside), metres.

    Outside one convex hull the largest signed distance to its face planes is a lower bound of
    the true distance that is exact opposite a face and close to it elsewhere; inside it is <= 0.
    The union's value is the minimum over hulls.

    Args:
        points: (N, 3) metres. hulls: as returned by :func:`decompose`.
    Returns:
        (N,) float64, >= 0.
    """
    planes = []
    for vertices, faces in hulls:
        tri = vertices[faces]
        normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-30)
        planes.append((normal, np.einsum("ij,ij->i", normal, tri[:, 0])))
    points = np.asarray(points, dtype=np.float64)
    result = np.empty(len(points))
    for start in range(0, len(points), chunk):
        p = points[start : start + chunk]
        per_hull = np.stack([(p @ n.T - d).max(axis=1) for n, d in planes], axis=1)
        result[start : start + chunk] = np.maximum(per_hull.min(axis=1), 0.0)
    return result
