"""Stage 3, mjcf: one MuJoCo model per object, and the check that it rests on a plane.

Layout of ``processed/<name>/``::

    <name>.xml      the model: one free body, origin at the centre of mass
    hull_000.stl …  collision hulls (geom group 3)
    visual.obj      the textured mesh (geom group 2, no collisions)
    texture.png     its texture, when the source had one

Mass and inertia are written explicitly (from the closed mesh, see ``mesh.mass_properties``),
so they do not depend on how MuJoCo would integrate the hulls.

Every collision hull carries the object's contact material (``geomgrasp.materials``, set by
``MJCFParams``' friction, condim, solref and solimp; all written out, none left to MuJoCo's
defaults): this MJCF is its single source. The settle check simulates the model as written (on
a plane of MuJoCo's default contact), and the trainer reads the material from it and does not
override it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from xml.sax.saxutils import quoteattr

import mujoco
import numpy as np
import trimesh
from PIL import Image

from geomprep.config import MJCFParams
from geomprep.decompose import Hull
from geomprep.errors import GeomprepError

VERSION = 3


def _fmt(values: np.ndarray | tuple[float, ...] | list[float]) -> str:
    return " ".join(f"{float(v):.9g}" for v in values)


def write_obj(path: Path, vertices: np.ndarray, faces: np.ndarray, uv: np.ndarray | None) -> None:
    """Write a Wavefront OBJ with per-vertex texture coordinates (if any); faces 1-based."""
    lines = [f"v {x:.7f} {y:.7f} {z:.7f}" for x, y, z in vertices]
    if uv is not None:
        lines += [f"vt {u:.6f} {v:.6f}" for u, v in uv]
        lines += [f"f {a}/{a} {b}/{b} {c}/{c}" for a, b, c in faces + 1]
    else:
        lines += [f"f {a} {b} {c}" for a, b, c in faces + 1]
    path.write_text("\n".join(lines) + "\n")


def model_xml(
    name: str,
    mass_kg: float,
    inertia: np.ndarray,
    n_hulls: int,
    textured: bool,
    params: MJCFParams,
) -> str:
    """The MJCF text for an object whose files sit beside it (see the module docstring)."""
    material = params.material()
    i = inertia
    full_inertia = _fmt([i[0, 0], i[1, 1], i[2, 2], i[0, 1], i[0, 2], i[1, 2]])
    assets = [f'    <mesh name="{name}_visual" file="visual.obj"/>']
    if textured:
        assets += [
            f'    <texture name="{name}_texture" type="2d" file="texture.png"/>',
            f'    <material name="{name}_material" texture="{name}_texture"/>',
        ]
    assets += [
        f'    <mesh name="{name}_hull_{k:03d}" file="hull_{k:03d}.stl"/>' for k in range(n_hulls)
    ]
    look = f' material="{name}_material"' if textured else ' rgba="0.7 0.7 0.7 1"'
    geoms = [
        f'      <geom name="{name}_visual" type="mesh" mesh="{name}_visual"{look} '
        'contype="0" conaffinity="0" group="2" density="0"/>'
    ]
    geoms += [
        f'      <geom name="{name}_hull_{k:03d}" type="mesh" mesh="{name}_hull_{k:03d}" '
        f'class="{name}_collision"/>'
        for k in range(n_hulls)
    ]
    return "\n".join(
        [
            f"<mujoco model={quoteattr(name)}>",
            '  <compiler angle="radian" meshdir="." texturedir="."/>',
            "  <default>",
            f'    <default class="{name}_collision">',
            f'      <geom group="3" density="0" friction="{_fmt(material.friction)}" '
            f'condim="{material.condim}" solref="{_fmt(material.solref)}" '
            f'solimp="{_fmt(material.solimp)}" rgba="0.4 0.6 0.9 0.5"/>',
            "    </default>",
            "  </default>",
            "  <asset>",
            *assets,
            "  </asset>",
            "  <worldbody>",
            f'    <body name="{name}">',
            f'      <freejoint name="{name}_joint"/>',
            f'      <inertial pos="0 0 0" mass="{mass_kg:.9g}" fullinertia="{full_inertia}"/>',
            *geoms,
            "    </body>",
            "  </worldbody>",
            "</mujoco>",
            "",
        ]
    )


def write_model_dir(
    directory: Path,
    name: str,
    mass_kg: float,
    inertia: np.ndarray,
    hulls: list[Hull],
    visual: tuple[np.ndarray, np.ndarray, np.ndarray | None],
    texture: np.ndarray | None,
    params: MJCFParams,
) -> Path:
    """Write the model's files into ``directory`` (which must exist); return the XML path."""
    for k, (vertices, faces) in enumerate(hulls):
        trimesh.Trimesh(vertices, faces, process=False).export(directory / f"hull_{k:03d}.stl")
    visual_vertices, visual_faces, uv = visual
    textured = texture is not None and uv is not None
    write_obj(directory / "visual.obj", visual_vertices, visual_faces, uv if textured else None)
    if textured:
        Image.fromarray(texture).save(directory / "texture.png")
    xml_path = directory / f"{name}.xml"
    xml_path.write_text(model_xml(name, mass_kg, inertia, len(hulls), textured, params))
    return xml_path


@dataclass(frozen=True)
class SettleResult:
    """What happened when the object was dropped onto a plane (metres, m/s, seconds)."""

    final_height_m: float
    """Height of the centre of mass above the plane at the end."""
    lowest_point_m: float
    """Lowest hull vertex's height at the end (negative: penetration)."""
    final_speed_m_s: float
    start_height_m: float
    """Centre-of-mass height when dropped."""
    max_height_m: float
    """Highest centre-of-mass height seen: a model that explodes jumps above its start."""
    seconds: float


def settle_on_plane(
    xml_path: Path, drop_height_m: float = 0.01, seconds: float = 1.0
) -> SettleResult:
    """Drop the model from ``drop_height_m`` above a plane and simulate for ``seconds``.

    Raises GeomprepError if the model does not compile or the state becomes NaN.
    """
    try:
        spec = mujoco.MjSpec.from_file(str(xml_path))
        spec.worldbody.add_geom(type=mujoco.mjtGeom.mjGEOM_PLANE, size=[2, 2, 0.1])
        model = spec.compile()
    except Exception as exc:
        raise GeomprepError(f"MuJoCo cannot load {xml_path}: {exc}") from exc
    data = mujoco.MjData(model)
    hull_geoms = [g for g in range(model.ngeom) if model.geom_group[g] == 3]
    body = model.geom_bodyid[hull_geoms[0]]
    # Put the lowest hull point drop_height above the plane.
    mujoco.mj_forward(model, data)
    lowest = _lowest_point(model, data, hull_geoms)
    adr = model.jnt_qposadr[model.body_jntadr[body]]
    data.qpos[adr + 2] += drop_height_m - lowest
    start_height = float(data.qpos[adr + 2])
    max_height = start_height
    steps = int(round(seconds / model.opt.timestep))
    for _ in range(steps):
        mujoco.mj_step(model, data)
        max_height = max(max_height, float(data.qpos[adr + 2]))
    if not np.isfinite(data.qpos).all():
        raise GeomprepError(f"simulation of {xml_path} became NaN: the collision hulls are broken")
    mujoco.mj_forward(model, data)
    speed = float(np.linalg.norm(data.qvel[:3]))
    return SettleResult(
        final_height_m=float(data.qpos[adr + 2]),
        lowest_point_m=_lowest_point(model, data, hull_geoms),
        final_speed_m_s=speed,
        start_height_m=start_height,
        max_height_m=max_height,
        seconds=seconds,
    )


def _lowest_point(model: mujoco.MjModel, data: mujoco.MjData, geoms: list[int]) -> float:
    lowest = np.inf
    for g in geoms:
        mesh_id = model.geom_dataid[g]
        start, count = model.mesh_vertadr[mesh_id], model.mesh_vertnum[mesh_id]
        local = model.mesh_vert[start : start + count]
        world = local @ data.geom_xmat[g].reshape(3, 3).T + data.geom_xpos[g]
        lowest = min(lowest, float(world[:, 2].min()))
    return lowest
