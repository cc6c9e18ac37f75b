"""The mesh stage on shapes whose mass properties are known exactly."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from geomprep import builtin, mesh
from geomprep.config import Config
from tests.conftest import require_ycb


def test_box_mass_properties_are_exact():
    source = builtin.build("builtin_box")  # 0.16 x 0.06 x 0.21 m, resting on z = 0
    norm = mesh.normalize_mesh(source, Config().mesh, 0.4, None)
    a, b, c = 0.16, 0.06, 0.21
    assert norm.volume_m3 == pytest.approx(a * b * c, rel=1e-9)
    np.testing.assert_allclose(norm.com_offset, [0, 0, c / 2], atol=1e-12)
    np.testing.assert_allclose(norm.vertices.mean(axis=0), 0, atol=1e-12)
    expected = 0.4 / 12 * np.diag([b * b + c * c, a * a + c * c, a * a + b * b])
    np.testing.assert_allclose(norm.inertia_kg_m2, expected, rtol=1e-9, atol=1e-15)
    assert norm.watertight and norm.com_method == "volume"


def test_density_fallback():
    norm = mesh.normalize_mesh(builtin.build("builtin_dice"), Config().mesh, None, 1000.0)
    assert norm.mass_kg == pytest.approx(1000.0 * 0.016**3, rel=1e-9)


def test_cleaning_merges_uv_seams_and_drops_degenerate_faces():
    box = trimesh.creation.box(extents=(0.1, 0.1, 0.1))
    # Split every face into its own vertices (as UV seams do) and add a zero-area face.
    vertices = box.vertices[box.faces].reshape(-1, 3)
    faces = np.arange(len(vertices)).reshape(-1, 3)
    faces = np.vstack([faces, [[0, 0, 1]]])
    split = trimesh.Trimesh(vertices, faces, process=False)
    norm = mesh.normalize_mesh(split, Config().mesh, 1.0, None)
    assert len(norm.vertices) == 8 and len(norm.faces) == 12 and norm.watertight
    assert len(norm.visual_vertices) == len(vertices)  # the visual mesh keeps its seams


def test_ycb_textured_mesh_keeps_texture_and_moves_to_com():
    ycb = require_ycb()
    source = mesh.load_source(ycb / "032_knife" / "google_16k" / "textured.obj")
    norm = mesh.normalize_mesh(source, Config().mesh, 0.031, None)
    assert norm.texture is not None and norm.visual_uv is not None
    assert norm.visual_uv.shape == (len(norm.visual_vertices), 2)
    m = trimesh.Trimesh(norm.vertices, norm.faces)
    assert np.linalg.norm(m.center_mass) < 1e-6
    # The visual mesh moved by the same offset as the geometry.
    np.testing.assert_allclose(
        norm.visual_vertices + norm.com_offset, np.asarray(source.vertices), atol=1e-9
    )
