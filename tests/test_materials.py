"""Contact materials defined once (``geomgrasp.materials``): every geom of a built scene has the
material its group is configured with, the trainer's ``[physics]`` fields reach exactly their
groups, and geomprep's object material and the trainer's defaults are the same numbers."""

from __future__ import annotations

import dataclasses

import mujoco
import numpy as np
import pytest

from geomgrasp import materials
from geomgrasp.materials import ContactMaterial, apply_materials, group_of
from geomprep.config import Config, MJCFParams
from trainer.assets.scene import Scene, build_scene
from trainer.config import EnvConfig, PhysicsConfig, load_env_config

# MuJoCo's geom defaults: what a material field left None keeps.
MUJOCO_DEFAULT = ContactMaterial(
    friction=(1.0, 0.005, 0.0001), condim=3, solref=(0.02, 1.0),
    solimp=(0.9, 0.95, 0.001, 0.5, 2.0), priority=0,
)


def _geom_material(model: mujoco.MjModel, geom: int) -> ContactMaterial:
    return ContactMaterial(
        friction=tuple(model.geom_friction[geom]), condim=int(model.geom_condim[geom]),
        solref=tuple(model.geom_solref[geom]), solimp=tuple(model.geom_solimp[geom]),
        priority=int(model.geom_priority[geom]),
    )


def _expected(material: ContactMaterial) -> ContactMaterial:
    """``material`` with MuJoCo's defaults where it sets nothing."""
    fields = {
        f.name: getattr(MUJOCO_DEFAULT, f.name) if getattr(material, f.name) is None
        else getattr(material, f.name)
        for f in dataclasses.fields(ContactMaterial)
    }
    return ContactMaterial(**fields)


def _groups(
    cfg: EnvConfig, scene: Scene, xmls: list
) -> tuple[mujoco.MjModel, dict[str, list[int]]]:
    """The compiled scene and the geom ids of each material group (objects: their hulls)."""
    spec = build_scene(cfg, scene, xmls, visual=False)
    model = spec.compile()
    groups: dict[str, list[int]] = {}
    for geom in spec.geoms:
        group = group_of(geom)
        if group is None and geom.name.startswith("slot"):
            group = "object"
        if group is not None:
            groups.setdefault(group, []).append(geom.id)
    return model, groups


def _with(cfg: EnvConfig, kind: str = "ur5e", **physics: object) -> EnvConfig:
    return dataclasses.replace(
        cfg, robot=dataclasses.replace(cfg.robot, kind=kind),
        physics=dataclasses.replace(cfg.physics, **physics),
    )


@pytest.mark.parametrize(
    ("kind", "fixtures"),
    [("ur5e", ("table",)), ("floating", ("table",)), ("ur5e", ("table", "bin"))],
)
def test_every_group_has_its_configured_material(
    builtin_data: Config, kind: str, fixtures: tuple[str, ...]
) -> None:
    processed = builtin_data.data_dir / "processed"
    names = ("builtin_box", "builtin_mug")
    xmls = [processed / n / f"{n}.xml" for n in names]
    # Non-default values, so that a group given another group's material would show.
    cfg = _with(
        load_env_config(data_dir=builtin_data.data_dir), kind,
        table_friction=(0.7, 0.004, 0.0002), finger_friction=(1.3, 0.02, 0.0003), condim=6,
        solref=(0.015, 0.9), solimp=(0.8, 0.9, 0.002, 0.4, 3.0),
    )
    model, groups = _groups(cfg, Scene(fixtures, len(xmls)), xmls)
    expected = {**cfg.physics.materials(), "object": MJCFParams().material()}
    want = {"floor", "table", "hand", "object"} | ({"arm"} if kind == "ur5e" else set())
    want |= {"bin"} if "bin" in fixtures else set()
    assert set(groups) == want
    for group, ids in groups.items():
        for geom in ids:
            assert _geom_material(model, geom) == _expected(expected[group]), (group, geom)
    # Every geom that collides belongs to a group.
    colliding = np.flatnonzero((model.geom_contype != 0) | (model.geom_conaffinity != 0))
    assert set(colliding) <= {g for ids in groups.values() for g in ids}


def test_each_physics_field_reaches_its_groups_only() -> None:
    base = load_env_config()
    _, groups = _groups(base, Scene(("table", "bin"), 0), [])
    reference = build_scene(base, Scene(("table", "bin"), 0), []).compile()
    changes = {
        "table_friction": ((0.5, 0.005, 0.0001), {"table", "bin", "arm"}),
        "finger_friction": ((1.5, 0.01, 0.0001), {"hand"}),
        "condim": (3, {"floor", "table", "bin", "arm", "hand"}),
        "solref": ((0.03, 1.0), {"hand"}),
        "solimp": ((0.8, 0.95, 0.001, 0.5, 2.0), {"hand"}),
    }
    for name, (value, touched) in changes.items():
        model = build_scene(_with(base, **{name: value}), Scene(("table", "bin"), 0), []).compile()
        for group, ids in groups.items():
            same = _geom_material(model, ids[0]) == _geom_material(reference, ids[0])
            assert same == (group not in touched), (name, group)


def test_one_set_of_defaults() -> None:
    """geomprep's object defaults, the trainer's [physics] defaults and the materials module's
    are the same numbers."""
    assert MJCFParams().material() == materials.DEFAULTS["object"]
    defaults = PhysicsConfig().materials()
    for group, material in defaults.items():
        assert material == materials.DEFAULTS[group], group
    assert set(defaults) | {"object"} == set(materials.GROUPS)


def test_apply_materials_sets_tagged_geoms_only() -> None:
    spec = mujoco.MjSpec()
    tagged, untagged, other = (spec.worldbody.add_geom(size=(0.1, 0, 0)) for _ in range(3))
    materials.tag(spec, tagged, "table")
    materials.tag(spec, other, "bin")
    untagged.friction = (0.3, 0.003, 0.0003)
    apply_materials(spec, {"table": ContactMaterial(friction=(0.6, 0.006, 0.0006), priority=2)})
    model = spec.compile()
    np.testing.assert_allclose(model.geom_friction, [[0.6, 0.006, 0.0006], [0.3, 0.003, 0.0003],
                                                     [1.0, 0.005, 0.0001]])
    assert list(model.geom_priority) == [2, 0, 0]
    assert list(model.geom_condim) == [3, 3, 3]  # condim None: left as it was
    with pytest.raises(ValueError, match="unknown material group"):
        materials.tag(spec, tagged, "carpet")
