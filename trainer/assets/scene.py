"""Scenes: fixtures (the table; for bin picking a bin of a floor and four walls), K object
*slots* and the robot (``trainer.robots``, the one ``RobotConfig.kind`` names), assembled with
``mujoco.MjSpec``, with every part's contact material applied by group at the end
(``geomgrasp.materials``; the values: ``PhysicsConfig.materials``).

A ``Scene`` says what is fixed; an *assignment* (K object MJCF files) says which object fills
each slot. Slot k is the body ``slot{k}`` with one free joint: code finds objects by slot name
(``slot_qpos_addresses``), never by body order, and every assignment of the same scene has the
same qpos layout (the robot's joints first, then 7 per slot), so one batch can mix them.

World frame: the table top is the plane z = 0 around the origin; the UR5e base stands at
``RobotConfig.base_pos``; objects (and the bin) sit near the origin.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from geomgrasp import materials
from trainer.assets.collision import BIT_ARM, BIT_HAND, BIT_OBJECT, BIT_STATIC
from trainer.config import EnvConfig, PhysicsConfig
from trainer.errors import TrainerError
from trainer.robots import make_robot
from trainer.robots.base import matrix_to_quat_np

FLOOR_Z = -0.75
FIXTURES = ("table", "bin")


@dataclass(frozen=True)
class Scene:
    """What a task's scene holds besides the robot: ``fixtures`` (``table``, ``bin``) and
    ``num_slots`` object slots."""

    fixtures: tuple[str, ...] = ("table",)
    num_slots: int = 1

    def __post_init__(self) -> None:
        unknown = set(self.fixtures) - set(FIXTURES)
        if unknown:
            raise ValueError(f"unknown fixtures {sorted(unknown)}; known: {FIXTURES}")
        if self.num_slots < 0:
            raise ValueError("num_slots must be >= 0")


def slot_name(k: int) -> str:
    """Body name of object slot ``k`` (its geoms and joint are prefixed ``slot{k}/``)."""
    return f"slot{k}"


def subtree_geoms(model: mujoco.MjModel, root: int) -> np.ndarray:
    """Geom ids of body ``root`` and every body below it."""
    inside = np.zeros(model.nbody, dtype=bool)
    for body in range(model.nbody):
        # Parents come before children in MuJoCo's body order, so one pass marks the subtree.
        inside[body] = body == root or (body > 0 and inside[model.body_parentid[body]])
    return np.flatnonzero(inside[model.geom_bodyid])


def hand_geoms(model: mujoco.MjModel) -> np.ndarray:
    """Geom ids of the hand: the ``palm`` body and every body below it."""
    return subtree_geoms(model, model.body("palm").id)


def slot_geoms(model: mujoco.MjModel, slot: int) -> np.ndarray:
    """Geom ids of the object in slot ``slot`` (its body ``slot{k}`` and anything below it)."""
    return subtree_geoms(model, model.body(slot_name(slot)).id)


def _slot_joints(model: mujoco.MjModel, num_slots: int) -> np.ndarray:
    """(K,) int: each slot's free joint."""
    return np.array(
        [model.body_jntadr[model.body(slot_name(k)).id] for k in range(num_slots)], dtype=np.int64
    )


def slot_qpos_addresses(model: mujoco.MjModel, num_slots: int) -> np.ndarray:
    """(K,) int: where each slot's free joint starts in qpos (3 position, then 4 quaternion)."""
    return model.jnt_qposadr[_slot_joints(model, num_slots)].astype(np.int64)


def slot_qvel_addresses(model: mujoco.MjModel, num_slots: int) -> np.ndarray:
    """(K,) int: where each slot's free joint starts in qvel (3 linear, world frame; 3 angular)."""
    return model.jnt_dofadr[_slot_joints(model, num_slots)].astype(np.int64)


def _options(spec: mujoco.MjSpec, cfg: EnvConfig) -> None:
    spec.compiler.degree = False  # every angle in this package is in radians
    spec.option.timestep = cfg.timestep
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    spec.option.cone = mujoco.mjtCone.mjCONE_ELLIPTIC
    spec.option.iterations = cfg.physics.iterations
    spec.option.ls_iterations = cfg.physics.ls_iterations
    spec.option.impratio = cfg.physics.impratio
    spec.option.noslip_iterations = cfg.physics.noslip_iterations
    if cfg.physics.memory_mb:
        spec.memory = int(cfg.physics.memory_mb * 2**20)
    spec.visual.global_.offwidth = 640
    spec.visual.global_.offheight = 480


def _add_table(spec: mujoco.MjSpec, physics: PhysicsConfig) -> None:
    world = spec.worldbody
    light = world.add_light()
    light.pos = (0.0, -0.5, 1.5)
    light.dir = (0.0, 0.3, -1.0)
    floor = world.add_geom()
    floor.name = "floor"
    floor.type = mujoco.mjtGeom.mjGEOM_PLANE
    floor.size = (3.0, 3.0, 0.1)
    floor.pos = (0.0, 0.0, FLOOR_Z)
    floor.rgba = (0.35, 0.35, 0.4, 1.0)
    table = world.add_geom()
    table.name = "table"
    table.type = mujoco.mjtGeom.mjGEOM_BOX
    table.size = physics.table_size
    table.pos = (0.0, 0.0, -physics.table_size[2])
    table.rgba = (0.75, 0.65, 0.5, 1.0)
    materials.tag(spec, floor, "floor")
    materials.tag(spec, table, "table")
    for geom in (floor, table):
        geom.contype = BIT_STATIC
        geom.conaffinity = BIT_OBJECT | BIT_ARM | BIT_HAND
    if physics.table_plane:
        # The objects meet the table as the plane of its top (a primitive test for MuJoCo
        # Warp), the robot its box: an unbounded plane would catch the arm's base links,
        # which stand below the top beside the table.
        top = world.add_geom()
        top.name = "table_top"
        top.type = mujoco.mjtGeom.mjGEOM_PLANE
        top.size = (physics.table_size[0], physics.table_size[1], 0.05)
        top.rgba = (0.0, 0.0, 0.0, 0.0)
        materials.tag(spec, top, "table")
        # A pair collides when one's contype meets the other's conaffinity, and the objects,
        # the arm and the hand all take BIT_STATIC (and each other's bits): so the plane and the
        # box each select by their conaffinity alone.
        top.contype, top.conaffinity = 0, BIT_OBJECT
        table.contype, table.conaffinity = 0, BIT_ARM | BIT_HAND
    camera = world.add_camera()
    camera.name = "front"
    camera.pos = (0.75, -0.75, 0.55)
    x_axis = np.array([0.7071, 0.7071, 0.0])
    y_axis = np.array([-0.28, 0.28, 0.92])
    y_axis /= np.linalg.norm(y_axis)
    camera.quat = matrix_to_quat_np(np.stack([x_axis, y_axis, np.cross(x_axis, y_axis)], axis=1))


def _add_bin(spec: mujoco.MjSpec, cfg: EnvConfig) -> None:
    """A bin at the table centre: a floor (its top is the table top, z = 0) and four walls
    around an inside of ``2 * inner_half_size``. The floor is drawn but does not collide: the
    table under it is the same surface, and two coplanar supports would give every resting
    object each of its contacts twice (half the bin's contacts, for nothing)."""
    b = cfg.bin
    hx, hy = b.inner_half_size
    t, h = b.wall_thickness, b.wall_height
    boxes = {
        # 1 mm above the table top: a coplanar face would flicker against the table's.
        "bin_floor": ((0.0, 0.0, 0.001 - 0.5 * t), (hx + t, hy + t, 0.5 * t)),
        "bin_wall_x+": ((hx + 0.5 * t, 0.0, 0.5 * h), (0.5 * t, hy + t, 0.5 * h)),
        "bin_wall_x-": ((-hx - 0.5 * t, 0.0, 0.5 * h), (0.5 * t, hy + t, 0.5 * h)),
        "bin_wall_y+": ((0.0, hy + 0.5 * t, 0.5 * h), (hx, 0.5 * t, 0.5 * h)),
        "bin_wall_y-": ((0.0, -hy - 0.5 * t, 0.5 * h), (hx, 0.5 * t, 0.5 * h)),
    }
    for name, (pos, size) in boxes.items():
        geom = spec.worldbody.add_geom()
        geom.name = name
        geom.type = mujoco.mjtGeom.mjGEOM_BOX
        geom.pos = pos
        geom.size = size
        geom.rgba = (0.45, 0.55, 0.7, 1.0)
        materials.tag(spec, geom, "bin")
        collides = name != "bin_floor"
        geom.contype = BIT_STATIC if collides else 0
        geom.conaffinity = (BIT_OBJECT | BIT_ARM | BIT_HAND) if collides else 0


def strip_visuals(child: mujoco.MjSpec) -> None:
    """Delete the geoms that only show (contype = conaffinity = 0) with their meshes, materials
    and textures: a YCB object's texture and visual mesh are ~30 MB of every compiled model that
    the physics never reads."""
    meshes, materials = set(), set()
    for geom in list(child.geoms):
        if geom.contype == 0 and geom.conaffinity == 0:
            meshes.add(geom.meshname)
            materials.add(geom.material)
            child.delete(geom)
    for name in meshes - {""}:
        child.delete(child.mesh(name))
    for name in materials - {""}:
        material = child.material(name)
        textures = [t for t in material.textures if t]
        child.delete(material)
        for texture in textures:
            child.delete(child.texture(texture))


def add_object(spec: mujoco.MjSpec, xml_path: Path, slot: int, visual: bool = True) -> str:
    """Put geomprep's object model (a body with a free joint, named after the object) into
    slot ``slot`` at the world origin; return the body name (``slot{k}``). The hulls keep the
    contact parameters geomprep wrote (its ``[mjcf]`` config); only their collision groups are
    the scene's. ``visual=False`` leaves out what only renders (for the models that step)."""
    if not xml_path.is_file():
        raise TrainerError(
            f"object model {xml_path} not found: build it with `geomprep build-all --objects "
            f"{xml_path.stem}`"
        )
    child = mujoco.MjSpec.from_file(str(xml_path))
    if not visual:
        strip_visuals(child)
    frame = spec.worldbody.add_frame()
    body = frame.attach_body(child.body(xml_path.stem), f"{slot_name(slot)}/", "")
    body.name = slot_name(slot)
    for geom in body.geoms:
        if geom.contype == 0 and geom.conaffinity == 0:
            continue  # the visual mesh
        geom.contype = BIT_OBJECT
        geom.conaffinity = BIT_STATIC | BIT_OBJECT | BIT_ARM | BIT_HAND
    return body.name


def build_scene(
    cfg: EnvConfig, scene: Scene, object_xmls: Sequence[Path], robot: bool = True,
    visual: bool = True,
) -> mujoco.MjSpec:
    """The task scene with slot k holding ``object_xmls[k]`` (one per slot), as an ``MjSpec``
    (compile with ``.compile()``). ``robot=False``: fixtures and objects only (for settling
    initial states). ``visual=False``: without the objects' visual meshes and textures (the
    models that only step; same bodies, joints, sites and collision geoms).

    The robot is ``make_robot(cfg.robot)``'s part (``trainer.robots``). The contact materials
    of the fixtures and the robot are ``cfg.physics.materials()``; the objects keep geomprep's.
    """
    if len(object_xmls) != scene.num_slots:
        raise ValueError(f"the scene has {scene.num_slots} slots, got {len(object_xmls)} objects")
    spec = mujoco.MjSpec()
    spec.modelname = "grasp" if robot else "settle"
    _options(spec, cfg)
    _add_table(spec, cfg.physics)
    if "bin" in scene.fixtures:
        _add_bin(spec, cfg)
    if robot:
        make_robot(cfg.robot).build(spec)
    for k, xml in enumerate(object_xmls):
        add_object(spec, Path(xml), k, visual)
    materials.apply_materials(spec, cfg.physics.materials())
    return spec
