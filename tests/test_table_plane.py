"""``[physics] table_plane``: the table collides as the plane of its top. An object comes to
rest at the same height as on the box, with the table's material, and the plane is a primitive
pair for MuJoCo Warp's narrowphase (the reason for the option)."""

from __future__ import annotations

import dataclasses

import mujoco
import numpy as np

from geomprep.config import Config
from trainer.assets.scene import Scene, build_scene, slot_qpos_addresses
from trainer.config import load_env_config


def _rest_height(builtin_data: Config, plane: bool) -> tuple[float, mujoco.MjModel]:
    cfg = load_env_config(data_dir=builtin_data.data_dir)
    cfg = dataclasses.replace(cfg, physics=dataclasses.replace(cfg.physics, table_plane=plane))
    xml = builtin_data.data_dir / "processed" / "builtin_box" / "builtin_box.xml"
    model = build_scene(cfg, Scene(("table",), 1), [xml], visual=False).compile()
    data = mujoco.MjData(model)
    mujoco.mj_resetData(model, data)
    adr = int(slot_qpos_addresses(model, 1)[0])
    data.qpos[adr: adr + 7] = (0.05, -0.03, 0.12, 1.0, 0.0, 0.0, 0.0)  # above the table
    for _ in range(int(1.5 / model.opt.timestep)):
        mujoco.mj_step(model, data)
    assert np.abs(data.qvel).max() < 1e-2  # at rest
    return float(data.qpos[adr + 2]), model


def test_object_rests_at_the_same_height_on_plane_and_box(builtin_data: Config) -> None:
    on_box, box_model = _rest_height(builtin_data, plane=False)
    on_plane, plane_model = _rest_height(builtin_data, plane=True)
    assert abs(on_plane - on_box) < 1e-3
    assert on_box > 0.005  # resting on the top, not fallen through
    table = box_model.geom("table").id
    assert box_model.geom_type[table] == mujoco.mjtGeom.mjGEOM_BOX
    top = plane_model.geom("table_top").id
    assert plane_model.geom_type[top] == mujoco.mjtGeom.mjGEOM_PLANE
    for field in ("geom_friction", "geom_condim"):  # the table's material
        np.testing.assert_array_equal(getattr(box_model, field)[table],
                                      getattr(plane_model, field)[top])


def _collides(model: mujoco.MjModel, a: int, b: int) -> bool:
    return bool((model.geom_contype[a] & model.geom_conaffinity[b])
                | (model.geom_contype[b] & model.geom_conaffinity[a]))


def test_objects_meet_the_plane_and_the_robot_the_box(builtin_data: Config) -> None:
    _, model = _rest_height(builtin_data, plane=True)
    table, top = model.geom("table").id, model.geom("table_top").id
    body = model.body_rootid[model.geom_bodyid]
    objects = [g for g in range(model.ngeom) if model.body(int(body[g])).name.startswith("slot")
               and model.geom_contype[g]]
    robot = [g for g in range(model.ngeom) if body[g] != 0
             and not model.body(int(body[g])).name.startswith("slot") and model.geom_contype[g]]
    assert objects and robot
    assert all(_collides(model, g, top) and not _collides(model, g, table) for g in objects)
    # the unbounded plane would catch the arm's base beside the table: the robot meets the box
    assert all(_collides(model, g, table) and not _collides(model, g, top) for g in robot)


def test_plane_pairs_with_meshes_are_primitive_in_mujoco_warp() -> None:
    from mujoco_warp._src.collision_driver import MJ_COLLISION_TABLE, CollisionType
    from mujoco_warp._src.types import GeomType

    assert MJ_COLLISION_TABLE[(GeomType.PLANE, GeomType.MESH)] == CollisionType.PRIMITIVE
    assert MJ_COLLISION_TABLE[(GeomType.BOX, GeomType.MESH)] == CollisionType.CONVEX
