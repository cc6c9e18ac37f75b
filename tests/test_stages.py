"""Every stage's output on the built-in set and on real YCB objects, checked for real properties."""

from __future__ import annotations

import h5py
import mujoco
import numpy as np
import open3d as o3d
import pytest
import trimesh

from geomprep import decompose, mesh, mjcf, pipeline, store
from geomprep.config import MJCFParams
from geomprep.masses import read_masses
from tests.conftest import YCB_DIR


def _surface_distance(vertices: np.ndarray, faces: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Exact unsigned distance of points to a triangle mesh (open3d's BVH)."""
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(
        o3d.core.Tensor(vertices.astype(np.float32)), o3d.core.Tensor(faces.astype(np.uint32))
    )
    return scene.compute_distance(o3d.core.Tensor(points.astype(np.float32))).numpy()


def test_contract_layout(built):
    """processed/<name>.h5 holds every dataset of the data contract, with its shape and dtype."""
    cfg, names = built
    for name in names:
        with h5py.File(cfg.processed_dir / f"{name}.h5", "r") as f:
            v, fc = f["mesh/vertices"], f["mesh/faces"]
            assert v.dtype == np.float32 and v.shape[1] == 3
            assert fc.dtype == np.int32 and fc.shape[1] == 3 and fc[()].max() < len(v)
            for attr in ("mass_kg", "volume_m3", "watertight", "source_sha256", "com_offset"):
                assert attr in f["mesh"].attrs, attr
            assert f["sdf/grid"].shape == (200, 200, 200) and f["sdf/grid"].dtype == np.float32
            np.testing.assert_allclose(f["sdf"].attrs["bounds_min"], [-0.5] * 3)
            np.testing.assert_allclose(f["sdf"].attrs["bounds_max"], [0.5] * 3)
            assert float(f["sdf"].attrs["voxel_size"]) == pytest.approx(0.005)
            assert f["bbox/center"].shape == (3,) and f["bbox/rotation"].shape == (3, 3)
            assert f["bbox/extents"].shape == (3,)
            assert f["superquadric/params"].shape == (11,)
            for n in (32, 128, 512):
                assert f[f"pointcloud/pc{n}"].shape == (n, 3)
                assert f[f"pointcloud/normals_{n}"].shape == (n, 3)
            for group in (
                "mesh",
                "decomposition",
                "mjcf",
                "sdf",
                "bbox",
                "superquadric",
                "pointcloud",
            ):
                assert "stage_params" in f[group].attrs and "stage_code_version" in f[group].attrs


def test_mesh_centred_at_centre_of_mass(built):
    cfg, names = built
    for name in names:
        arrays, attrs = store.read_group(cfg.processed_dir / f"{name}.h5", "mesh")
        m = trimesh.Trimesh(arrays["vertices"], arrays["faces"], process=False)
        size = np.linalg.norm(np.ptp(arrays["vertices"], axis=0))
        _, com, _, method = mesh.mass_properties(m)  # the same method the stage used
        assert method == attrs["com_method"], name
        assert np.linalg.norm(com) < 1e-3 * size, name
        assert attrs["mass_kg"] > 0


def test_mass_comes_from_masses_csv(ycb_data):
    masses = read_masses(YCB_DIR / "masses.csv")
    for name in ("032_knife", "025_mug"):
        _, attrs = store.read_group(ycb_data.processed_dir / f"{name}.h5", "mesh")
        assert attrs["mass_kg"] == pytest.approx(masses[name], rel=1e-6)


def test_hulls_cover_the_mesh_and_stay_small(built):
    """The hull union contains the mesh up to decimation error; each hull <= 64 vertices."""
    cfg, names = built
    for name in names:
        path = cfg.processed_dir / f"{name}.h5"
        arrays, _ = store.read_group(path, "mesh")
        hulls = decompose.unpack_hulls(store.read_group(path, "decomposition")[0])
        assert all(len(v) <= cfg.decompose.max_hull_vertices for v, _ in hulls), name
        outside = decompose.distance_outside_hulls(arrays["vertices"].astype(np.float64), hulls)
        size = float(np.linalg.norm(np.ptp(arrays["vertices"], axis=0)))
        tolerance = max(2e-3, 0.02 * size)
        assert np.mean(outside <= tolerance) >= 0.99, (name, np.mean(outside <= tolerance))
        # And the hulls are no bloated stand-in: their volume stays near the mesh's hull.
        hull_volume = sum(trimesh.Trimesh(v, f).volume for v, f in hulls)
        mesh_hull_volume = trimesh.Trimesh(arrays["vertices"], arrays["faces"]).convex_hull.volume
        assert hull_volume <= 1.5 * mesh_hull_volume, name


def test_mjcf_loads_and_settles_on_a_plane(built):
    """The model loads from its XML path and, dropped 2 cm onto a plane, comes to rest on it."""
    cfg, names = built
    for name in names:
        xml = cfg.processed_dir / name / f"{name}.xml"
        model = mujoco.MjModel.from_xml_path(str(xml))
        _, attrs = store.read_group(cfg.processed_dir / f"{name}.h5", "mesh")
        assert model.body_mass[1] == pytest.approx(attrs["mass_kg"], rel=1e-6)
        result = mjcf.settle_on_plane(xml, drop_height_m=0.02, seconds=2.0)
        assert result.final_speed_m_s < 0.01, (name, result)
        assert -0.002 < result.lowest_point_m < 0.003, (name, result)  # on the plane, not in it
        assert result.max_height_m < result.start_height_m + 1e-3, (name, result)  # no jump


def _hull_contact(model: mujoco.MjModel) -> list[tuple[tuple[float, ...], ...]]:
    """(friction, condim, solref, solimp) of each collision hull geom (group 3) of ``model``."""
    return [
        (
            tuple(model.geom_friction[g]),
            (int(model.geom_condim[g]),),
            tuple(model.geom_solref[g]),
            tuple(model.geom_solimp[g]),
        )
        for g in range(model.ngeom)
        if model.geom_group[g] == 3
    ]


def _expected_contact(params: MJCFParams) -> tuple[tuple[float, ...], ...]:
    return (params.friction, (params.condim,), params.solref, params.solimp)


def test_mjcf_params_are_the_contact_parameters_the_trainer_trains_with():
    """The MJCF is the single source of an object's contact parameters: its defaults are the
    values every learning result used (the trainer reads them from the MJCF)."""
    params = MJCFParams()
    assert params.friction == (1.0, 0.01, 0.0001)
    assert params.condim == 4
    assert params.solref == (0.01, 1.0)
    assert params.solimp == (0.9, 0.95, 0.001, 0.5, 2.0)


def test_mjcf_hull_geoms_carry_exactly_the_contact_parameters(tmp_path):
    """Every collision hull of the written MJCF has MJCFParams' friction, condim, solref and
    solimp: non-default values show that each one is written, none left to MuJoCo's default."""
    box = trimesh.creation.box((0.04, 0.03, 0.02))
    hulls = [(np.asarray(box.vertices), np.asarray(box.faces))] * 2
    params = MJCFParams(
        friction=(0.7, 0.02, 0.0003),
        condim=6,
        solref=(0.02, 0.8),
        solimp=(0.8, 0.9, 0.002, 0.4, 3.0),
    )
    xml = mjcf.write_model_dir(
        tmp_path,
        "box",
        0.1,
        np.diag([1e-5, 2e-5, 3e-5]),
        hulls,
        (np.asarray(box.vertices), np.asarray(box.faces), None),
        None,
        params,
    )
    contact = _hull_contact(mujoco.MjModel.from_xml_path(str(xml)))
    assert len(contact) == 2
    for hull in contact:
        for got, want in zip(hull, _expected_contact(params), strict=True):
            np.testing.assert_allclose(got, want, rtol=1e-9, atol=0)


def test_built_mjcf_hull_geoms_carry_the_built_contact_parameters(built):
    """The built models (what the trainer loads) carry the config's contact parameters, and
    their XML states solimp itself rather than relying on MuJoCo's default."""
    cfg, names = built
    for name in names:
        xml = cfg.processed_dir / name / f"{name}.xml"
        assert f'solimp="{mjcf._fmt(cfg.mjcf.solimp)}"' in xml.read_text(), name
        contact = _hull_contact(mujoco.MjModel.from_xml_path(str(xml)))
        assert contact, name
        for hull in contact:
            for got, want in zip(hull, _expected_contact(cfg.mjcf), strict=True):
                np.testing.assert_allclose(got, want, rtol=1e-9, atol=0, err_msg=name)


def test_bbox_contains_vertices_and_is_tight(built):
    cfg, names = built
    for name in names:
        path = cfg.processed_dir / f"{name}.h5"
        arrays, _ = store.read_group(path, "mesh")
        box, _ = store.read_group(path, "bbox")
        r = box["rotation"].astype(np.float64)
        np.testing.assert_allclose(r.T @ r, np.eye(3), atol=1e-5)
        assert np.linalg.det(r) == pytest.approx(1.0, abs=1e-5)
        local = (arrays["vertices"] - box["center"]) @ r
        inside = np.all(np.abs(local) <= box["extents"] / 2 + 1e-5, axis=1)
        assert inside.mean() >= 0.99, name
        # Never looser than 2x the minimum-volume box (the box-shaped objects are tested in
        # test_bbox.py against the optimum; here every object must at least be sane).
        _, optimal_extents = trimesh.bounds.oriented_bounds(arrays["vertices"].astype(np.float64))
        assert np.prod(box["extents"]) <= 2.0 * np.prod(optimal_extents), name


def test_box_shaped_bbox_near_optimal(builtin_data):
    for name, expected in (("builtin_box", (0.21, 0.16, 0.06)), ("builtin_dice", (0.016,) * 3)):
        box, _ = store.read_group(builtin_data.processed_dir / f"{name}.h5", "bbox")
        np.testing.assert_allclose(np.sort(box["extents"])[::-1], expected, atol=1e-4)


def test_pointclouds_on_surface_and_spread(built):
    cfg, names = built
    for name in names:
        path = cfg.processed_dir / f"{name}.h5"
        arrays, _ = store.read_group(path, "mesh")
        pc, _ = store.read_group(path, "pointcloud")
        for n in (32, 128, 512):
            points, normals = pc[f"pc{n}"], pc[f"normals_{n}"]
            d = _surface_distance(arrays["vertices"], arrays["faces"], points)
            assert d.max() < 1e-3, (name, n, d.max())
            np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-4)
        # Farthest-point sampling: the 32 points are far better spread than random ones.
        p = pc["pc32"].astype(np.float64)
        nearest = np.sort(np.linalg.norm(p[:, None] - p[None], axis=2), axis=1)[:, 1]
        size = float(np.linalg.norm(np.ptp(arrays["vertices"], axis=0)))
        assert nearest.min() > 0.05 * size, (name, nearest.min() / size)
        np.testing.assert_array_equal(pc["pc512"][:32], pc["pc32"])


def test_sdf_sign_and_zero_crossing(built):
    """Inside negative, far outside positive, and the surface lies where the grid crosses zero."""
    cfg, names = built
    for name in names:
        path = cfg.processed_dir / f"{name}.h5"
        with h5py.File(path, "r") as f:
            grid = f["sdf/grid"][()]
        arrays, _ = store.read_group(path, "mesh")
        assert grid[0, 0, 0] > 0.4  # a corner of the cube is far outside
        pc, _ = store.read_group(path, "pointcloud")
        # Trilinear value at surface samples is within a voxel diagonal of zero.
        centres = (np.arange(200) + 0.5) * 0.005 - 0.5
        from scipy.interpolate import RegularGridInterpolator

        at_surface = RegularGridInterpolator((centres,) * 3, grid)(pc["pc512"])
        assert np.abs(at_surface).max() < 0.005, (name, np.abs(at_surface).max())
        if name not in ("032_knife", "029_plate", "builtin_knife"):  # thinner than a voxel
            assert grid.min() < -0.002, name


def test_status_and_stage_paths(builtin_data):
    status = pipeline.stage_status(builtin_data, "builtin_box")
    assert set(status.values()) == {"done"}
