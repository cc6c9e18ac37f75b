"""geomprep.decompose on meshes above its face budget."""

from __future__ import annotations

import dataclasses

import coacd
import numpy as np
import trimesh

from geomprep import decompose
from geomprep.config import DecomposeParams


def test_convex_mesh_above_the_budget_is_one_covering_hull() -> None:
    # Convexity is judged on the full (closed) mesh, the hull's points come from the reduced
    # copy: still one hull of at most max_hull_vertices that covers the sphere.
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=0.05)  # 5120 faces
    params = dataclasses.replace(DecomposeParams(), max_faces=1000)
    hulls = decompose.decompose(sphere.vertices, sphere.faces, params)
    assert len(hulls) == 1 and len(hulls[0][0]) <= params.max_hull_vertices
    outside = decompose.distance_outside_hulls(sphere.vertices, hulls)
    full = decompose.decompose(sphere.vertices, sphere.faces, DecomposeParams())
    # About as close as the 64-vertex hull of the full mesh (2.8 mm on this 5 cm sphere): the
    # 8 mm clustering cells of this 5x reduction pull the copy's vertices in by ~0.5 mm.
    assert outside.max() <= decompose.distance_outside_hulls(sphere.vertices, full).max() + 1e-3


def test_coacd_gets_at_most_max_faces(monkeypatch) -> None:
    # A concave mesh (an L of two boxes) above the budget: CoACD sees the reduced copy.
    shape = trimesh.boolean.union(
        [
            trimesh.creation.box(extents=(0.1, 0.02, 0.02)),
            trimesh.creation.box(extents=(0.02, 0.1, 0.02), transform=_shift(0.04, 0.04)),
        ],
        engine="manifold",
    )
    for _ in range(4):
        shape = shape.subdivide()
    seen: list[int] = []

    def fake_coacd(mesh: coacd.Mesh, **kwargs) -> list:
        seen.append(len(mesh.indices))
        return [(np.asarray(mesh.vertices), np.asarray(mesh.indices))]

    monkeypatch.setattr(coacd, "run_coacd", fake_coacd)
    params = dataclasses.replace(DecomposeParams(), max_faces=1000)
    assert len(shape.faces) > 4 * params.max_faces
    decompose.decompose(shape.vertices, shape.faces, params)
    assert seen and seen[0] <= params.max_faces


def _shift(x: float, y: float) -> np.ndarray:
    transform = np.eye(4)
    transform[:2, 3] = (x, y)
    return transform
