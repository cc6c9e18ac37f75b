"""The mesh stage on shapes whose mass properties are known exactly."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
import trimesh
from scipy.spatial import Delaunay

from geomprep import builtin, decompose, mesh, mjcf
from geomprep.config import Config
from geomprep.errors import GeomprepError
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


def _box(extents: tuple[float, float, float], at: tuple[float, float, float]) -> trimesh.Trimesh:
    box = trimesh.creation.box(extents=extents)
    box.apply_translation(at)
    return box


def _box_inertia_per_kg(a: float, b: float, c: float) -> np.ndarray:
    return np.diag([b * b + c * c, a * a + c * c, a * a + b * b]) / 12.0


def test_overlapping_closed_parts_count_once():
    # Two 5 cm cubes interpenetrating by half (not unioned, as CAD exports leave them): the
    # solid is one 7.5 x 5 x 5 cm box; summing the parts would count the overlap twice.
    parts = trimesh.util.concatenate(
        [_box((0.05,) * 3, (0.0, 0.0, 0.0)), _box((0.05,) * 3, (0.025, 0.0, 0.0))]
    )
    assert parts.is_watertight and parts.volume == pytest.approx(2 * 0.05**3)
    norm = mesh.normalize_mesh(parts, Config().mesh, 0.3, None)
    assert norm.volume_m3 == pytest.approx(0.075 * 0.05 * 0.05, rel=1e-9)
    np.testing.assert_allclose(norm.com_offset, [0.0125, 0, 0], atol=1e-12)
    expected = 0.3 * _box_inertia_per_kg(0.075, 0.05, 0.05)
    np.testing.assert_allclose(norm.inertia_kg_m2, expected, rtol=1e-9, atol=1e-15)
    # The geometry mesh is the union: no faces left inside the solid.
    assert norm.n_unioned == 2 and norm.watertight
    np.testing.assert_allclose(np.ptp(norm.vertices, axis=0), [0.075, 0.05, 0.05], atol=1e-12)
    centroids = norm.vertices[norm.faces].mean(axis=1)
    on_boundary = np.isclose(np.abs(centroids), [0.0375, 0.025, 0.025], atol=1e-12).any(axis=1)
    assert on_boundary.all()


def test_cavity_stays_hollow_when_parts_are_unioned():
    # A 6 cm box with a 3 cm cavity (an inward-wound inner box): nested parts take the union
    # path, which must subtract the cavity, not fill it.
    inner = _box((0.03,) * 3, (0.0, 0.0, 0.0))
    inner.invert()
    hollow = trimesh.util.concatenate([_box((0.06,) * 3, (0.0, 0.0, 0.0)), inner])
    norm = mesh.normalize_mesh(hollow, Config().mesh, 0.2, None)
    volume = 0.06**3 - 0.03**3
    assert norm.volume_m3 == pytest.approx(volume, rel=1e-9)
    per_kg = (
        0.06**3 * _box_inertia_per_kg(0.06, 0.06, 0.06)
        - 0.03**3 * _box_inertia_per_kg(0.03, 0.03, 0.03)
    ) / volume
    np.testing.assert_allclose(norm.inertia_kg_m2, 0.2 * per_kg, rtol=1e-9, atol=1e-15)


def test_overlapping_parts_with_a_hole_are_refused():
    # One cube has a missing face: its inside is not defined, so the overlap cannot be given a
    # sign; a wrong mass (the overlap left out by parity) is worse than an error.
    holed = _box((0.05,) * 3, (0.025, 0.0, 0.0))
    holed.update_faces(np.arange(len(holed.faces)) != 0)
    parts = trimesh.util.concatenate([_box((0.05,) * 3, (0.0, 0.0, 0.0)), holed])
    with pytest.raises(GeomprepError, match="overlap.*ambiguous") as err:
        mesh.normalize_mesh(parts, Config().mesh, 0.3, None, label="object 'parts'")
    assert "\n" not in str(err.value)


@pytest.mark.parametrize("x", [3e3, 1e6])
def test_far_from_origin_mass_properties_are_exact(x: float, tmp_path):
    cube = _box((0.05,) * 3, (x, -0.02, 0.01))
    norm = mesh.normalize_mesh(cube, Config().mesh, 0.5, None)
    expected = 0.5 * 0.05**2 / 6.0
    # Exact cube inertia, diagonal (before: 25 % off with off-diagonals at 3 km, a MuJoCo
    # error at 1e6 m); the remaining error is the vertices' float64 rounding at x.
    np.testing.assert_allclose(
        norm.inertia_kg_m2, expected * np.eye(3), rtol=1e-7, atol=1e-7 * expected
    )
    assert norm.volume_m3 == pytest.approx(0.05**3, rel=1e-7)
    np.testing.assert_allclose(norm.com_offset, [x, -0.02, 0.01], rtol=0, atol=1e-9)
    np.testing.assert_allclose(np.abs(norm.vertices), 0.025, atol=1e-9)
    # Downstream: the model MuJoCo compiles has the cube's inertia and hull.
    hulls = decompose.decompose(norm.vertices, norm.faces, Config().decompose)
    xml = mjcf.write_model_dir(
        tmp_path,
        "cube",
        norm.mass_kg,
        norm.inertia_kg_m2,
        hulls,
        (norm.visual_vertices, norm.visual_faces, None),
        None,
        Config().mjcf,
    )
    model = mujoco.MjModel.from_xml_path(str(xml))
    np.testing.assert_allclose(model.body_inertia[1], expected, rtol=1e-6)
    np.testing.assert_allclose(model.body_ipos[1], 0.0, atol=1e-9)


def _planar_sheet(tilt: float, offset: float) -> trimesh.Trimesh:
    """A 10 x 8 cm triangulated sheet, rotated by ``tilt`` rad and shifted by ``offset`` m."""
    xs, ys = np.meshgrid(np.linspace(0, 0.1, 5), np.linspace(0, 0.08, 4))
    points = np.stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)], axis=1)
    faces = Delaunay(points[:, :2]).simplices
    rotation = trimesh.transformations.rotation_matrix(tilt, [1, 2, 3])[:3, :3]
    return trimesh.Trimesh(points @ rotation.T + offset, faces, process=False)


@pytest.mark.parametrize(("tilt", "offset"), [(0.0, 0.0), (0.7, 0.3)])
@pytest.mark.parametrize(("mass", "density"), [(0.1, None), (None, 500.0)])
def test_flat_mesh_is_refused_in_one_line(tilt, offset, mass, density):
    # Before: a Qhull error, a silent zero volume, a 'fix masses.csv' or a made-up voxel volume.
    with pytest.raises(GeomprepError, match=r"is flat \(zero volume\).*thick.*not a solid") as err:
        mesh.normalize_mesh(
            _planar_sheet(tilt, offset), Config().mesh, mass, density, label="object 'sheet'"
        )
    assert "\n" not in str(err.value) and "masses.csv" not in str(err.value)


def test_points_or_lines_are_refused_in_one_line():
    collinear = np.array([[0, 0, 0], [0.05, 0, 0], [0.1, 0, 0], [0.1, 0, 0]], dtype=float)
    lines = trimesh.Trimesh(collinear, [[0, 1, 2], [1, 2, 3]], process=False)
    with pytest.raises(GeomprepError, match="only points or lines") as err:
        mesh.normalize_mesh(lines, Config().mesh, 0.1, None, label="object 'lines'")
    assert "\n" not in str(err.value)


def test_mass_in_grams_is_refused():
    cube = _box((0.06,) * 3, (0.0, 0.0, 0.0))
    with pytest.raises(GeomprepError, match="1.16e\\+06 kg/m\\^3.*grams\\? it must be kilograms"):
        mesh.normalize_mesh(cube, Config().mesh, 250.0, None)  # 250 g written as kg
    with pytest.raises(GeomprepError, match="lighter than the plausible 1 kg/m\\^3"):
        mesh.normalize_mesh(cube, Config().mesh, 1e-4, None)
    with pytest.raises(GeomprepError, match="density 2e\\+06 kg/m\\^3 is outside"):
        mesh.normalize_mesh(cube, Config().mesh, None, 2e6)
    assert mesh.normalize_mesh(cube, Config().mesh, 0.25, None).mass_kg == 0.25


@pytest.mark.parametrize(
    ("name", "density"), [("070-a_colored_wood_blocks", 4.6), ("042_adjustable_wrench", 12_889)]
)
def test_extreme_ycb_densities_are_accepted(name: str, density: float):
    # The lightest and the densest of the 78 YCB objects by mass / mesh-stage volume.
    ycb = require_ycb()
    masses = dict(
        line.split(",") for line in (ycb / "masses.csv").read_text().splitlines()[1:] if line
    )
    source = mesh.load_source(ycb / name / "google_16k" / "textured.obj")
    norm = mesh.normalize_mesh(source, Config().mesh, float(masses[name]), None)
    assert norm.mass_kg / norm.volume_m3 == pytest.approx(density, rel=0.01)


def test_reduced_keeps_small_meshes_and_shrinks_large_ones():
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=0.05)  # 5120 faces
    v, f = mesh.reduced(sphere.vertices, sphere.faces, 10_000)
    assert v is not None and np.array_equal(f, sphere.faces)
    v, f = mesh.reduced(sphere.vertices, sphere.faces, 1000)
    assert 200 < len(f) <= 1000
    # Still the sphere: every vertex of the copy within 1 mm of its surface.
    np.testing.assert_allclose(np.linalg.norm(v, axis=1), 0.05, atol=1e-3)
