"""Contact materials, defined once: what each group of collision geoms is made of (friction,
contact dimensionality, solver softness, priority), with the one set of defaults that geomprep
(its object MJCF and settle check) and the trainer (table, bin, arm, hand) both read.

Groups: ``floor``, ``table``, ``bin``, ``arm``, ``hand`` (the trainer's scene builder and robots
tag their geoms with a default class of the group's name, ``tag``), and ``object`` (geomprep
writes it on every collision hull of an object's MJCF; the trainer uses those hulls as written).
``apply_materials`` sets the materials of the tagged geoms of an ``MjSpec`` in one pass.

A field left ``None`` is not written: the geom keeps MuJoCo's default (or its class's).
Imports nothing heavy: ``mujoco`` only for type hints.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import mujoco

GROUPS = ("floor", "table", "bin", "arm", "hand", "object")


@dataclass(frozen=True)
class ContactMaterial:
    """The contact parameters of one group of geoms (MuJoCo ``geom`` attributes)."""

    friction: tuple[float, float, float] | None = None
    """Sliding, torsional, rolling friction (``geom/@friction``; None: MuJoCo's 1, 0.005,
    0.0001)."""
    condim: int | None = None
    """Contact dimensionality: 1 frictionless, 3 sliding, 4 plus torsional, 6 plus rolling."""
    solref: tuple[float, float] | None = None
    """Solver reference: time constant (s) and damping ratio."""
    solimp: tuple[float, float, float, float, float] | None = None
    """Solver impedance: dmin, dmax, width (m), midpoint, power."""
    priority: int | None = None
    """Of two geoms in contact, the one of higher priority sets the contact's parameters."""

    def apply(self, geom: mujoco.MjsGeom) -> None:
        """Write the fields that are set onto ``geom``."""
        for name in ("friction", "condim", "solref", "solimp", "priority"):
            value = getattr(self, name)
            if value is not None:
                setattr(geom, name, value)


TABLE = ContactMaterial(friction=(0.8, 0.005, 0.0001), condim=4)
"""The table top (and by default the bin and the arm: a painted or laminated surface)."""
HAND = ContactMaterial(
    friction=(1.0, 0.01, 0.0001), condim=4, solref=(0.01, 1.0),
    solimp=(0.9, 0.95, 0.001, 0.5, 2.0),
)
"""The hand's links and pads."""
OBJECT = ContactMaterial(
    friction=(1.0, 0.01, 0.0001), condim=4, solref=(0.01, 1.0),
    solimp=(0.9, 0.95, 0.001, 0.5, 2.0),
)
"""Every object's collision hulls (geomprep's ``[mjcf]`` defaults): torsional friction
(condim 4) keeps a pinched object from spinning out, and every field is written so that the
object's MJCF alone says how it touches."""
DEFAULTS: Mapping[str, ContactMaterial] = {
    "floor": ContactMaterial(condim=TABLE.condim),
    "table": TABLE,
    "bin": TABLE,
    "arm": TABLE,
    "hand": HAND,
    "object": OBJECT,
}
"""The default material of each group. The floor under the table keeps MuJoCo's friction."""


def tag(spec: mujoco.MjSpec, geom: mujoco.MjsGeom, group: str) -> None:
    """Mark ``geom`` as made of ``group``'s material: its default class becomes the group's
    (created on first use; a class without attributes of its own, and classes do not reach
    the compiled model)."""
    if group not in GROUPS:
        raise ValueError(f"unknown material group {group!r}; known: {GROUPS}")
    geom.classname = spec.find_default(group) or spec.add_default(group, spec.default)


def group_of(geom: mujoco.MjsGeom) -> str | None:
    """The material group ``geom`` is tagged with (``tag``), or None."""
    name = geom.classname.name
    return name if name in GROUPS else None


def apply_materials(spec: mujoco.MjSpec, materials: Mapping[str, ContactMaterial]) -> None:
    """Set every tagged geom of ``spec`` to its group's material in ``materials`` (groups
    missing from ``materials`` are left as they are)."""
    for geom in spec.geoms:
        material = materials.get(group_of(geom) or "")
        if material is not None:
            material.apply(geom)
