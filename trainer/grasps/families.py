"""The registry of scripted grasp families and their named variants, and the experiment that
runs them: N randomized trials per object in one batch, each trial's outcome classified.

A *variant* is a family's script with some parameters changed, plus environment overrides
(``load_env_config`` keywords: e.g. MuJoCo's no-slip solver). The variants are the ones
results/scripted-table1 measured (its README says what each changes and what it found); a grid
is a family's parameter scan there.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Collection, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from trainer.errors import TrainerError
from trainer.grasps.keyframes import KeyframeGrasp
from trainer.grasps.pinch import Pinch
from trainer.grasps.runner import GraspScript, episode_config, record_grasp
from trainer.grasps.searched import data_rows, load_searched, theta_row
from trainer.grasps.slide import SlideGrasp
from trainer.grasps.top import TopGrasp

TABLE1_OBJECTS = (
    "029_plate", "032_knife", "062_dice", "072-a_toy_airplane", "073-g_lego_duplo",
    "007_tuna_fish_can", "013_apple", "053_mini_soccer_ball", "065-a_cups", "077_rubiks_cube",
)
"""The paper's Table I objects, in the order of results/cpu-table1/table1.toml."""


@dataclass(frozen=True)
class Variant:
    """A family's script and the environment overrides it runs with."""

    script: GraspScript
    env: dict[str, Any] = field(default_factory=dict)
    """``load_env_config`` keyword overrides (sections as dicts of fields)."""


@dataclass(frozen=True)
class GridAxis:
    """One parameter of a family's grid scan: its script field, the short label of its value
    in the variant's name, and the values scanned."""

    param: str
    label: str
    values: tuple


@dataclass(frozen=True)
class Family:
    """A grasp family: its script's type (defaults: the ``base`` variant), named variants,
    the objects it is measured on by default and a grid scan of its geometry."""

    script: Callable[..., GraspScript]
    variants: dict[str, Variant]
    objects: tuple[str, ...]
    grid: tuple[GridAxis, ...] = ()
    grid_objects: tuple[str, ...] = ()
    """Objects of the grid scan (default: ``objects``)."""

    def grid_variants(self) -> dict[str, Variant]:
        """Every combination of the grid's values, named ``<label><value>_...``."""
        out = {}
        for values in itertools.product(*(axis.values for axis in self.grid)):
            params = {axis.param: v for axis, v in zip(self.grid, values, strict=True)}
            name = "_".join(f"{axis.label}{_text(v)}"
                            for axis, v in zip(self.grid, values, strict=True))
            out[name] = Variant(replace(self.script(), **params))
        return out


def _text(value: object) -> str:
    """A grid value as written in a variant's name: tuples joined by ``/``."""
    return "/".join(map(str, value)) if isinstance(value, tuple) else str(value)


NOSLIP = {"physics": {"noslip_iterations": 5}}
"""MuJoCo's no-slip solver: removes the creep of the soft frictional contacts."""
FRICTION2 = {"physics": {"finger_friction": (2.0, 0.01, 0.0001)}}
IMPRATIO10 = {"physics": {"impratio": 10.0}}

_TOP = TopGrasp()
_RIM = replace(_TOP, grasp_depth=0.22, lateral=0.0)
"""The top grid's best geometry for the plate: the fingertips at its rim."""
_PINCH = Pinch()

def _searched_family() -> Family:
    """The seed's grasps (``searched.SEARCHED_PATH``) with its configuration, each object's row
    replaced, where the env's data directory has one for its hand and physics, by that."""
    data = load_searched()
    rows = tuple((name, theta_row(entry)) for name, entry in sorted(data["objects"].items()))
    script = KeyframeGrasp(by_object=rows, extra_rows=data_rows)
    return Family(KeyframeGrasp, {"base": Variant(script, dict(data["config"]))},
                  tuple(name for name, _ in rows))


FAMILIES: dict[str, Family] = {
    "top": Family(
        TopGrasp,
        {  # one change from the capsule hand each (results/scripted-table1, "one knob at a
            # time"); with the default hand of 2026-11-26 (0.75 N·m, no-slip on) force0.75 and
            # noslip are the base variant.
            "base": Variant(_TOP),
            "friction2": Variant(_TOP, FRICTION2),
            "force0.75": Variant(_TOP, {"robot": {"hand_forcerange": 0.75}}),
            "force15": Variant(_TOP, {"robot": {"hand_forcerange": 15.0}}),
            "kp60": Variant(_TOP, {"robot": {"hand_kp": 60.0}}),
            "substeps20": Variant(_TOP, {"physics": {"substeps": 20}}),
            "deeper": Variant(replace(_TOP, grasp_depth=0.19)),
            "shallower": Variant(replace(_TOP, grasp_depth=0.13)),
            "thumb0.8": Variant(replace(_TOP, thumb_closed=0.8)),
            "rim": Variant(_RIM),
            "rim+friction2": Variant(_RIM, FRICTION2),
            "noslip": Variant(_TOP, NOSLIP),
            "impratio10": Variant(_TOP, IMPRATIO10),
        },
        TABLE1_OBJECTS,
        grid=(
            GridAxis("grasp_depth", "d", (0.13, 0.16, 0.19, 0.22)),
            GridAxis("lateral", "l", (-0.05, -0.03, 0.0)),
            GridAxis("thumb_closed", "t", (0.4, 0.8, 1.2)),
            GridAxis("palm_clearance", "c", (0.016, 0.03, 0.05)),
        ),
        # The objects the default top grasp lifts <= 2 times in 10.
        grid_objects=("029_plate", "032_knife", "062_dice", "072-a_toy_airplane",
                      "007_tuna_fish_can", "053_mini_soccer_ball"),
    ),
    "pinch": Family(
        Pinch,
        {
            "base": Variant(_PINCH),
            "middle": Variant(replace(_PINCH, middle="index")),
            "pitch30": Variant(replace(_PINCH, pitch=30.0)),
            "pitch10": Variant(replace(_PINCH, pitch=10.0)),
            "press": Variant(replace(_PINCH, clearance=-0.003)),
            "high": Variant(replace(_PINCH, clearance=0.008)),
            "soft": Variant(replace(_PINCH, closed=(0.6, -1.0))),
            "press6": Variant(replace(_PINCH, clearance=-0.006)),
            "press+follow": Variant(replace(_PINCH, clearance=-0.003, follow=True)),
            "press6+follow": Variant(replace(_PINCH, clearance=-0.006, follow=True)),
            "pitch30+press": Variant(replace(_PINCH, pitch=30.0, clearance=-0.003)),
            "pitch30+press+follow": Variant(
                replace(_PINCH, pitch=30.0, clearance=-0.003, follow=True)),
            "press+middle": Variant(replace(_PINCH, clearance=-0.003, middle="index")),
            "press6+handle": Variant(replace(_PINCH, clearance=-0.006, handle=True)),
            "press10+handle": Variant(replace(_PINCH, clearance=-0.010, handle=True)),
            "press6+follow+handle": Variant(
                replace(_PINCH, clearance=-0.006, follow=True, handle=True)),
            "noslip": Variant(_PINCH, NOSLIP),
            "press6+noslip": Variant(replace(_PINCH, clearance=-0.006), NOSLIP),
            # Rolled -90 degrees about the squeeze once lifted: the load leaves the flexion
            # servos (results/hold-turned-2026-11-26/).
            "press6+turn": Variant(replace(_PINCH, clearance=-0.006, turn=-90.0, turn_steps=30)),
            # The plate's rim, the pads 11 mm up and a slower lift: every upright plate lifted,
            # none upside down (results/graspability-plate-rim-2026-11-26/).
            "rim": Variant(replace(_PINCH, clearance=0.011, rim_inset=0.035, lift_rate=0.3)),
            "press6+handle+noslip": Variant(
                replace(_PINCH, clearance=-0.006, handle=True), NOSLIP),
            "middle+noslip": Variant(replace(_PINCH, middle="index"), NOSLIP),
            "impratio10": Variant(_PINCH, IMPRATIO10),
        },
        ("062_dice", "032_knife", "007_tuna_fish_can", "029_plate"),
        grid=(
            GridAxis("pitch", "p", (15.0, 20.0, 25.0)),
            GridAxis("clearance", "c", (-0.002, 0.002, 0.006)),
            GridAxis("closed", "s", ((0.6, -1.0), (0.8, -1.2), (1.0, -1.4))),
        ),
    ),
    "slide": Family(
        SlideGrasp,
        {  # results/graspability-plate-2026-11-26/: tips the plate 16-21 degrees, lifts 0
            "base": Variant(SlideGrasp()),
            "flatten": Variant(replace(SlideGrasp(), push=0.08, push_steps=40,
                                       fingers_pushed=-1.0)),
            "wrap": Variant(replace(SlideGrasp(), fingers_closed=0.5)),
        },
        ("029_plate",),
    ),
}
FAMILIES["searched"] = _searched_family()
"""The ``searched`` family: one keyframe grasp per object, found by the cross-entropy search
of ``search.py`` (``trainer grasp-search``): the data directory's grasp for the env's hand and
physics where there is one, else the shipped ``searched.json``'s (``searched.py``); its variant
runs with the configuration the shipped grasps were searched with."""


BEST = {
    "032_knife": "pinch:press6+noslip",
    "062_dice": "searched",
    "072-a_toy_airplane": "searched",
    "073-g_lego_duplo": "searched",
    "007_tuna_fish_can": "pinch:press6+noslip",
    "013_apple": "top",
    "053_mini_soccer_ball": "searched",
    "065-a_cups": "top",
    "077_rubiks_cube": "top",
    "029_plate": "pinch:rim",
}
"""The hand-written best family (``FAMILY:VARIANT``) of each object someone tuned: the Table I
objects, with the hand ``searched.json`` names (issue 33's candidate, the default hand since
2026-11-26: link hulls, damping 0.1, 0.75 N·m, all joints driven, no-slip):
results/graspability-drives-2026-11-25/ and results/graspability-search-2026-11-26/ (each
>= 8 of 10); the plate: results/graspability-plate-rim-2026-11-26/ (every upright plate, no
upside-down one: 8 of 10 only where 8 of the 10 trials start upright). These override the
search: any other object's best grasp is its searched one (``best_variants``' ``searched``,
``search.find_grasps``)."""


def best_variants(
    names: Sequence[str], searched: Collection[str] = (),
) -> dict[str, tuple[Variant, list[str]]]:
    """``FAMILY:VARIANT`` -> (its variant with the searched grasps' hand configuration under
    its own overrides, the ``names`` it is best for): each object's ``BEST`` entry, else the
    ``searched`` family for the objects named in ``searched`` (those that have a searched
    grasp); any other object is a one-line error."""
    missing = [n for n in names if n not in BEST and n not in searched]
    if missing:
        raise TrainerError(f"no grasp family lifts {', '.join(missing)} yet: search one with "
                           f"`trainer grasp-search --objects {','.join(missing)}`, choose of "
                           f"{', '.join(BEST)}, or name a family")
    hand = FAMILIES["searched"].variants["base"].env  # searched.json's configuration
    out: dict[str, tuple[Variant, list[str]]] = {}
    for name in names:
        spec = BEST.get(name, "searched")
        if spec not in out:
            family_name, _, variant_name = spec.partition(":")
            variant = variants(family_name, [variant_name or "base"])[variant_name or "base"]
            out[spec] = (Variant(variant.script, merge_overrides(hand, variant.env)), [])
        out[spec][1].append(name)
    return out


def family(name: str) -> Family:
    """The registered family ``name``; an unknown name is a one-line error listing them."""
    if name not in FAMILIES:
        raise TrainerError(f"unknown grasp family {name!r}: choose one of {', '.join(FAMILIES)}")
    return FAMILIES[name]


def variants(family_name: str, names: Sequence[str] | None = None,
             grid: bool = False) -> dict[str, Variant]:
    """The family's variants ``names`` (default: all), or with ``grid`` its grid scan; an
    unknown name is a one-line error listing the family's variants."""
    fam = family(family_name)
    if grid:
        if not fam.grid:
            raise TrainerError(f"grasp family {family_name!r} has no grid")
        return fam.grid_variants()
    if names is None:
        return dict(fam.variants)
    unknown = [n for n in names if n not in fam.variants]
    if unknown:
        raise TrainerError(
            f"unknown variant {unknown[0]!r} of grasp family {family_name!r}: choose of "
            f"{', '.join(fam.variants)}"
        )
    return {n: fam.variants[n] for n in names}


def merge_overrides(base: dict[str, Any], extra: dict[str, Any]) -> dict[str, Any]:
    """``base`` with ``extra`` on top, section dicts merged field by field."""
    out = dict(base)
    for key, value in extra.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = {**out[key], **value}
        else:
            out[key] = value
    return out


def measure(
    family_name: str, variant_name: str, variant: Variant, objects: Sequence[str], trials: int,
    seed: int = 0, config_path: Path | None = None, hold: bool = False, **env: Any,
) -> list[dict]:
    """Run ``trials`` randomized trials of ``variant`` on each object (one batch of
    ``trials * len(objects)`` envs, the lift task, seed ``seed``: the same initial states for
    every variant of a batch) and classify them; one row per object (``outcome_rows``).

    ``env``: more ``load_env_config`` overrides (data_dir, backend, device, reward, ...) under
    the variant's own. The initial states depend on the batch's size and objects: the same
    objects, trials and seed give the same trials.

    ``hold`` (CPU backend): each trial that ends the script lifted is probed by
    ``hold.measure_hold``; each row gains ``held_end`` (how many the hand held through the
    probe's hold) and the medians of ``HOLD_KEYS`` over those (empty without such a trial),
    and ``holds``: that object's probed trials (``hold.Hold``, held or not) for a caller that
    pools them (not a CSV column)."""
    from trainer.config import check_device, load_env_config
    from trainer.grasps.outcomes import outcome_rows
    from trainer.objects import resolve_names
    from trainer.tasks import make_env

    overrides = merge_overrides({"representation": "com", **env}, variant.env)
    cfg = load_env_config(config_path, task="lift", context="none", **overrides)
    check_device(cfg.device, f"device {cfg.device!r}", 'use device "cpu"')
    names = resolve_names(",".join(objects), cfg.data_dir)
    cfg = replace(cfg, num_envs=trials * len(names), objects=",".join(names))
    grasp_env = make_env(episode_config(cfg, variant.script), seed=seed)
    try:
        trajectory = record_grasp(grasp_env, variant.script)
        ids = grasp_env.target_objects()
        holds = _probe_holds(grasp_env, trajectory.success[-1]) if hold else None
    finally:
        grasp_env.close()
    script = variant.script
    rows = outcome_rows(names, ids, trajectory, script.close_window, script.pushed_at,
                        family=family_name, variant=variant_name)
    if holds is not None:
        _add_hold_columns(rows, names, ids.cpu(), holds)
    return rows


HOLD_KEYS = ("slip_mm_s", "grip_n", "pull_ratio", "slip_grip_n", "slip_pull_ratio",
             "slip_cone_min", "slip_cone_max")
"""The hold probe's measurements (``hold.Hold`` fields and properties) that ``measure(...,
hold=True)`` adds to each row, as medians over the held trials."""


def _probe_holds(env: Any, held: Any) -> dict[int, Any]:
    """Env id -> ``Hold`` for every env whose target is lifted at the script's end."""
    from trainer.assets.scene import slot_name
    from trainer.grasps.hold import measure_hold

    slots = env.state["target_slot"].cpu()
    out = {}
    for i in held.nonzero()[:, 0].tolist():
        try:
            model, data = env.backend.snapshot(i)
        except NotImplementedError as exc:
            raise TrainerError(f"the hold probe needs the cpu backend: {exc}") from None
        out[i] = measure_hold(model, data, model.body(slot_name(int(slots[i]))).id)
    return out


def _add_hold_columns(rows: list[dict], names: Sequence[str], ids: Any,
                      holds: dict[int, Any]) -> None:
    """Each object's row gains ``held_end`` and the medians of its holds' measurements (over
    the holds where a measurement is defined: a ratio needs a contact)."""
    import math
    import statistics

    by_name = {row["object"]: row for row in rows}
    for k, name in enumerate(names):
        if name not in by_name:
            continue
        row = by_name[name]
        row["holds"] = [h for i, h in sorted(holds.items()) if int(ids[i]) == k]
        mine = [h for h in row["holds"] if h.held]
        row["held_end"] = len(mine)
        for key in HOLD_KEYS:  # ``Hold`` fields and properties of the same names
            values = [v for v in (getattr(h, key) for h in mine) if not math.isnan(v)]
            row[key] = round(statistics.median(values), 3) if values else ""
