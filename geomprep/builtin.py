"""The built-in object set: procedural shapes that need no download.

They cover the geometric cases the YCB set is known for (a box, a cylinder, a sphere, a thin
plate, a knife-like slab, a dice-sized cube and a concave mug) so the pipeline and the trainer
can run on a fresh machine with no network. Sizes and masses are those of everyday objects.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    import trimesh

PREFIX = "builtin_"


def _box(trimesh: ModuleType) -> trimesh.Trimesh:
    return trimesh.creation.box(extents=(0.16, 0.06, 0.21))  # a cereal box


def _cylinder(trimesh: ModuleType) -> trimesh.Trimesh:
    return trimesh.creation.cylinder(radius=0.033, height=0.10, sections=48)  # a soup can


def _sphere(trimesh: ModuleType) -> trimesh.Trimesh:
    return trimesh.creation.icosphere(subdivisions=3, radius=0.036)  # a baseball


def _plate(trimesh: ModuleType) -> trimesh.Trimesh:
    return trimesh.creation.cylinder(radius=0.11, height=0.012, sections=64)  # a thin plate


def _knife(trimesh: ModuleType) -> trimesh.Trimesh:
    return trimesh.creation.box(extents=(0.21, 0.022, 0.008))  # a knife-like slab


def _dice(trimesh: ModuleType) -> trimesh.Trimesh:
    return trimesh.creation.box(extents=(0.016, 0.016, 0.016))


def _mug(trimesh: ModuleType) -> trimesh.Trimesh:
    """A cup (outer r 40 mm, h 90 mm, 5 mm wall, 6 mm floor) with a ring handle; concave."""
    outer = trimesh.creation.cylinder(radius=0.040, height=0.090, sections=48)
    inner = trimesh.creation.cylinder(radius=0.035, height=0.090, sections=48)
    inner.apply_translation((0, 0, 0.006))
    handle = trimesh.creation.torus(major_radius=0.025, minor_radius=0.006)
    handle.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, (1, 0, 0)))
    handle.apply_translation((0.052, 0, 0))
    cup = trimesh.boolean.difference([outer, inner], engine="manifold")
    return trimesh.boolean.union([cup, handle], engine="manifold")


# The builders take the trimesh module: it is imported only to build a mesh, so that reading
# NAMES (geomprep.contract.resolve_objects, the trainer) does not load the mesh stack.
BUILDERS: dict[str, tuple[Callable[[ModuleType], trimesh.Trimesh], float]] = {
    # name: (builder, mass in kg)
    "builtin_box": (_box, 0.40),
    "builtin_cylinder": (_cylinder, 0.35),
    "builtin_sphere": (_sphere, 0.15),
    "builtin_plate": (_plate, 0.28),
    "builtin_knife": (_knife, 0.03),
    "builtin_dice": (_dice, 0.005),
    "builtin_mug": (_mug, 0.12),
}
NAMES: tuple[str, ...] = tuple(BUILDERS)


def build(name: str) -> trimesh.Trimesh:
    """The built-in object ``name`` (metres, resting on z = 0, centred in x and y)."""
    import trimesh

    mesh = BUILDERS[name][0](trimesh)
    # Like a scanned object: the source origin is at the base, not at the centre of mass.
    mesh.apply_translation((0.0, 0.0, -mesh.bounds[0, 2]))
    return mesh


def write_source(name: str, directory: Path) -> tuple[Path, float]:
    """Write the built-in object's mesh as ``directory/<name>.stl``; return (path, mass_kg)."""
    path = Path(directory) / f"{name}.stl"
    build(name).export(path)
    return path, BUILDERS[name][1]
