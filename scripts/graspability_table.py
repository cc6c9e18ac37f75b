"""The graspability of every YCB object (issue 62): for each object, the lift rate of the
hand-written grasp families and of its searched grasp, the best of them, and for each object
that no grasp lifts in ``LIFTS`` of its trials, why, from measured attributes.

    python scripts/graspability_table.py --out results/graspability-all-DATE --data-dir data \\
        [--objects ycb|NAMES] [--trials 20] [--families top,pinch:press6+noslip,pinch:rim] \\
        [--seed 0] [--minutes 100] [--config FILE] [--set KEY=VALUE ...] [--remake]

Per object, in one process, one object at a time:

- each family of ``--families`` (default ``DEFAULT_FAMILIES``: the hand-written ones that are
  some Table I object's best, ``trainer.grasps.families.BEST``) runs ``--trials`` randomized
  trials (``trainer.grasps.trials.run_trials``, the lift task, seed ``--seed``), each trial
  lifted, dropped, no_grip or pushed (``trainer.grasps.outcomes``);
- its searched grasp (``trainer.grasps.search.find_grasps`` for the configuration's hand and
  physics: the data directory's, else the shipped seed's, else searched now and stored in the
  data directory: about 2-3 minutes of one core) runs the same trials from the same seeded
  initial states, under the same configuration (not the seed file's own);
- the attributes the reasons are told from: the object's oriented box extents and mass
  (geomprep's processed file), and of its best grasp(s) the failing trials' outcomes and the
  widths the object rested with in its lifted and its failed trials.

Each object's row goes to ``OUT/rows/<object>.json`` (written whole) as soon as it is measured;
a rerun skips the objects that have a row, so ``--minutes`` chunks (checked between objects: an
object begun is finished, up to ~5 minutes with a search) add up across sessions. The rows of
one folder must share their settings (trials, seed, families, configuration): another setting
is refused in one line. After each object the table is made again from every row of
``OUT/rows``: ``OUT/graspability.csv`` and ``OUT/table.md`` (with its summary line: how many
objects the search, and any grasp, lifts in >= ``LIFTS`` of its trials).

``--remake`` measures nothing: it makes every row of ``OUT/rows`` again from its measured
counts by today's rules (``make_row``: the best, the reason), then the table.

The reason (``reasons``) of an object whose best rate is below ``LIFTS``: every physical limit
it breaks, in this order: ``beyond span`` (its smallest box extent is wider than the hand opens,
``HandLimits.span_m``), ``too heavy`` (its weight exceeds what the servo torque can hold by
friction, ``HandLimits.holdable_kg``), ``too thin/flat`` (its smallest extent is below
``THIN_M``), ``rests wide`` (its best grasp failed where the object rested at least
``REST_WIDE`` of the span wide and lifted it, if at all, where it rested narrower: the medians
of each trial's narrowest horizontal box width after the first action); where it breaks none,
the dominant outcome of its best grasp's failing trials (``no_grip``, ``dropped``,
``pushed``). The box is the whole object's: a thinner part (a handle,
a wing) that a grasp could close on is not seen, so ``beyond span`` and ``too thin/flat`` speak
of the object's box, not of its parts.
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from geomgrasp.errors import UserError
from geomgrasp.files import atomic_path

LIFTS = 0.6
"""Issue 62's bar: an object is graspable when a grasp lifts it in >= 60 % of its trials."""
SEARCHED = "searched"
"""The searched grasp's name among an object's grasps (a row's ``grasps`` key)."""
FAILURES = ("dropped", "no_grip", "pushed")
"""The outcomes of a trial that did not lift (``trainer.grasps.outcomes.OUTCOMES``), in the
order that breaks a tie for the dominant one."""
GRAVITY = 9.81
"""m/s^2."""
LOAD_SHARE = 0.73
"""The share of its friction capacity (friction x summed grip force) a two-pad grip resists
before it slides: one pad reaches its friction limit first (pull ratio 0.71-0.76 at slip,
results/hold-at-slip-2026-11-26/)."""
THIN_M = 0.0105
"""m: the smallest extent below which an object counts as too thin to squeeze from its sides
off the table: the finger links' radius (``trainer.robots.sih.FINGER_RADIUS``; the hulls'
distal links are 20 mm wide, the same within 0.5 mm). A pad resting on the table touches a
thinner object above the pad's widest point, so the squeeze presses it into the table."""
REST_WIDTHS = ("rest_width_lifted_mm", "rest_width_failed_mm")
"""A grasp's median resting width of the target over its lifted and its failed trials
(``trainer.grasps.outcomes.outcome_rows``: the narrowest horizontal width of its box as it
rests, what a grasp from above spans)."""
REST_WIDE = 0.9
"""A resting width of at least this share of the hand's span is ``rests wide``: the fingers
then close from nearly their open end (the cracker box lying flat, 169 mm of the 171, was
lifted by no grasp; on its side, 82 mm, by its grasps: results/graspability-all-2026-11-29/)."""
SPAN_FINGERS = ("tip_if", "tip_mf", "tip_rf", "tip_lf")
"""The finger pads whose distance to the thumb's pad gives the hand's span."""


def default_families() -> tuple[str, ...]:
    """The hand-written families (``FAMILY:VARIANT``) that are the best of some Table I object
    (``BEST``, less the searched grasps), in the order ``BEST`` first names them."""
    from trainer.grasps.families import BEST

    return tuple(dict.fromkeys(spec for spec in BEST.values() if spec != SEARCHED))


@dataclass(frozen=True)
class HandLimits:
    """What the hand can grasp at most, measured once from its model (``hand_limits``)."""

    span_m: float
    """The largest opening: the thumb's pad to the farthest finger pad, the thumb opposed and
    every joint else at its open end (MuJoCo forward kinematics of the fingertip sites)."""
    thumb_lever_m: float
    """The thumb pad's distance from the thumb's flexion axis in that pose: the lever over which
    the flexion servo presses the pad."""
    torque_nm: float
    """Each hand servo's torque limit (``[robot] hand_forcerange``)."""
    friction: float
    """The sliding friction of a pad on an object (MuJoCo takes the larger of the two geoms':
    ``[physics] finger_friction`` and the objects' ``geomgrasp.materials.OBJECT``)."""

    @property
    def grip_n(self) -> float:
        """The most a pad presses: the thumb's flexion torque over its lever. The thumb opposes
        every grasp and one or more fingers push back, so it is the weaker side of the grip
        (with the default hand 11.7 N, two pads 23.5 N: the measured pinch and searched grips of
        the dice were 20-23 N, results/hold-at-slip-2026-11-26/)."""
        return self.torque_nm / self.thumb_lever_m

    @property
    def holdable_kg(self) -> float:
        """The heaviest object the grip holds: friction on both sides of the squeeze, each
        pressed by ``grip_n``, of which ``LOAD_SHARE`` is resisted before the grip slides:
        m g <= 2 mu F share, F = torque / lever. An object heavier than this is ``too heavy``
        (m g lever > 2 mu share torque: its weight's moment on the thumb over what the servo
        holds with friction)."""
        return 2 * self.friction * self.grip_n * LOAD_SHARE / GRAVITY


def hand_limits(cfg: Any) -> HandLimits:
    """The ``HandLimits`` of the hand of ``cfg`` (an ``EnvConfig``): its model built alone,
    the thumb opposed, every other joint open."""
    import mujoco
    import numpy as np

    from geomgrasp import materials
    from trainer.robots import sih

    spec = mujoco.MjSpec()
    sih.add_sih_hand(spec, spec.worldbody, (0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0), cfg.robot)
    model = spec.compile()
    data = mujoco.MjData(model)
    data.qpos[:] = 0.0  # every finger joint and the thumb's flexion at their open end
    data.qpos[model.jnt_qposadr[model.joint("th_rot").id]] = sih.THUMB_ROT_RANGE[0]  # opposed
    mujoco.mj_kinematics(model, data)
    thumb = data.site("tip_th").xpos
    span = max(float(np.linalg.norm(thumb - data.site(s).xpos)) for s in SPAN_FINGERS)
    flex = model.joint("th_flex").id
    arm = thumb - data.xanchor[flex]
    axis = data.xaxis[flex]
    lever = float(np.linalg.norm(arm - (arm @ axis) * axis))
    friction = max(cfg.physics.finger_friction[0], materials.OBJECT.friction[0])
    return HandLimits(span, lever, cfg.robot.hand_forcerange, friction)


def dominant(failures: Mapping[str, int]) -> str:
    """The most frequent failing outcome of ``failures`` (outcome -> count; a tie goes to the
    first of ``FAILURES``); empty when nothing failed."""
    best = max(FAILURES, key=lambda o: (failures.get(o, 0), -FAILURES.index(o)))
    return best if failures.get(best, 0) > 0 else ""


def rests_wide(rest_mm: Mapping[str, Any], hand: HandLimits) -> bool:
    """Whether a grasp's failures are its target resting wide: its failed trials rested with a
    median width of at least ``REST_WIDE`` of the hand's span, and its lifts (if any) narrower
    (``rest_mm``: the grasp's ``REST_WIDTHS``, mm, empty strings where it has no such trial)."""
    failed = rest_mm.get("rest_width_failed_mm", "")
    lifted = rest_mm.get("rest_width_lifted_mm", "")
    if failed in ("", None):
        return False
    wide = REST_WIDE * hand.span_m * 1000
    return failed >= wide and (lifted in ("", None) or lifted < wide)


def reasons(extents_m: Sequence[float], mass_kg: float, hand: HandLimits,
            failures: Mapping[str, int], rest_mm: Mapping[str, Any] | None = None) -> str:
    """Why an object is not lifted: each physical limit it breaks (``beyond span``, ``too
    heavy``, ``too thin/flat``, ``rests wide``: its best grasp's failures are the resting
    poses at least ``REST_WIDE`` of the span wide (``rests_wide`` of ``rest_mm``), comma-
    separated), else the dominant outcome of the failing trials ``failures`` (outcome ->
    count)."""
    smallest = min(extents_m)
    found = []
    if smallest > hand.span_m:
        found.append("beyond span")
    if mass_kg > hand.holdable_kg:
        found.append("too heavy")
    if smallest < THIN_M:
        found.append("too thin/flat")
    if "beyond span" not in found and rest_mm is not None and rests_wide(rest_mm, hand):
        found.append("rests wide")
    return ", ".join(found) or dominant(failures)


class _Parser(argparse.ArgumentParser):
    """argparse whose usage errors are one-line ``UserError``s, like every other error here."""

    def error(self, message: str) -> None:  # type: ignore[override]
        raise UserError(message)


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    """The command line (``main``)."""
    parser = _Parser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, required=True,
                        help="folder of the rows (rows/<object>.json) and the table")
    parser.add_argument("--objects", default=None,
                        help="object names or the set ycb [every YCB object built in the data "
                        "directory]")
    parser.add_argument("--data-dir", type=Path, default=None, help="[./data]")
    parser.add_argument("--trials", type=int, default=20, help="trials per grasp [20]")
    parser.add_argument("--families", default=None,
                        help="FAMILY[:VARIANT], comma-separated [the hand-written families of "
                        "BEST: top, pinch:press6+noslip, pinch:rim]")
    parser.add_argument("--seed", type=int, default=0, help="seed of the initial states [0]")
    parser.add_argument("--minutes", type=float, default=None,
                        help="begin no object after this many minutes [no limit]")
    parser.add_argument("--config", type=Path, default=None,
                        help="TOML config of the hand and physics [the defaults]")
    parser.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE",
                        help="one config key, as in trainer --set (repeatable)")
    parser.add_argument("--remake", action="store_true",
                        help="measure nothing: make every row's best and reason again from its "
                        "measured counts (after the rules changed), then the table")
    return parser.parse_args(argv)


def parse_families(spec: str | None) -> list[str]:
    """The ``FAMILY[:VARIANT]`` specs of ``--families`` (default: ``default_families``; no
    variant: ``base``), each checked against the registry; an unknown one, ``searched`` (measured
    for every object anyway) and none at all are one-line errors."""
    from trainer.grasps import family, family_variants

    if spec is None:
        return list(default_families())
    chosen = []
    for item in (s.strip() for s in spec.split(",") if s.strip()):
        name, _, variant = item.partition(":")
        if name == SEARCHED:
            raise UserError("--families searched: the searched grasp is measured for every "
                            "object anyway; name hand-written families")
        family(name)
        family_variants(name, [variant or "base"])
        chosen.append(item)
    if not chosen:
        raise UserError("--families: name at least one grasp family (top, pinch:rim, ...)")
    return list(dict.fromkeys(chosen))


def built(data_dir: Path, names: Sequence[str]) -> list[str]:
    """Those of ``names`` whose processed file is there and current (geomprep's check)."""
    from geomprep import contract

    dirs = contract.DataDirs(Path(data_dir))
    return [n for n in names if contract.processed_path(dirs, n).is_file()
            and contract.verify_processed(dirs, n) is None]


def choose_objects(spec: str | None, data_dir: Path) -> list[str]:
    """The objects to measure: ``spec``'s (each must be built), or every YCB object built in
    ``data_dir`` (the ones still unbuilt said in one line, left for a later run)."""
    from trainer.objects import resolve_names

    names = resolve_names(spec or "ycb", data_dir)
    ready = built(data_dir, names)
    if spec is not None and len(ready) < len(names):
        missing = [n for n in names if n not in ready]
        raise UserError(f"not built (or not current) in {data_dir}: {', '.join(missing)}: run "
                        f"`geomprep build-all --objects {','.join(missing)}`")
    if spec is None:
        if not ready:
            raise UserError(f"no YCB object is built in {data_dir}: run `geomprep build-all`")
        if len(ready) < len(names):
            later = [n for n in names if n not in ready]
            print(f"{len(ready)} of {len(names)} YCB objects built; {len(later)} left for a "
                  f"later run: {', '.join(later[:5])}{' ...' if len(later) > 5 else ''}")
    return ready


def read_rows(out: Path) -> dict[str, dict]:
    """Object -> its row, for every readable ``OUT/rows/*.json`` (a damaged one is said and
    measured again)."""
    rows = {}
    for path in sorted((out / "rows").glob("*.json")):
        try:
            row = json.loads(path.read_text())
            rows[row["object"]] = row
        except (ValueError, KeyError, TypeError):
            print(f"{path}: not a row (damaged): measured again")
    return rows


def check_settings(rows: Mapping[str, dict], settings: dict, out: Path) -> None:
    """Every row of ``out`` was measured with ``settings``; another is a one-line error."""
    for name, row in rows.items():
        if row.get("settings") != settings:
            theirs = ", ".join(f"{k} {v}" for k, v in row.get("settings", {}).items()
                               if settings.get(k) != v)
            raise UserError(f"{out} holds rows measured otherwise ({name}: {theirs}): rerun "
                            f"with their settings or choose another --out")


def measure_object(
    name: str, families: Sequence[str], trials: int, seed: int, cfg: Any,
    config_path: Path | None, env: Mapping[str, Any],
) -> tuple[dict[str, dict], dict[str, Any]]:
    """Grasp name -> its row (``trials``, ``lifted``, ``dropped``, ``no_grip``, ``pushed``,
    ...) for each of ``families`` and ``SEARCHED`` on object ``name``, all on the same seeded
    initial states, and the searched grasp's record (``source``: where ``find_grasps`` took it
    from; ``search_lifted`` / ``search_trials``: its own final trials)."""
    from trainer.grasps import family_variants, searched
    from trainer.grasps import search as search_module
    from trainer.grasps.families import Variant
    from trainer.grasps.keyframes import KeyframeGrasp
    from trainer.grasps.trials import run_trials

    if searched.read_object(cfg.data_dir, name).get(searched.hand_key(cfg)) is not None:
        source = "data directory"
    elif searched.shipped_object(name).get(searched.hand_key(cfg)) is not None:
        source = "shipped per hand"
    elif name in searched.load_searched()["objects"]:
        source = "shipped seed"
    else:
        source = "searched now"
    entry = search_module.find_grasps(cfg, [name])[name]
    # The entry itself, under this configuration: not the seed file's own configuration, nor
    # another object's row.
    script = KeyframeGrasp(by_object=((name, searched.theta_row(entry)),))
    variants = []
    for spec in families:
        fam, _, variant = spec.partition(":")
        variants.append((fam, variant or "base",
                         family_variants(fam, [variant or "base"])[variant or "base"]))
    variants.append((SEARCHED, "base", Variant(script)))
    specs = [*families, SEARCHED]
    grasps = {}
    for spec, batch in zip(specs, run_trials(variants, [name], trials, [seed],
                                             config_path=config_path, **env), strict=True):
        (row,) = batch.rows
        grasps[spec] = {k: row[k]
                        for k in ("trials", "lifted", *FAILURES, "max_rise_cm", *REST_WIDTHS)}
    record = {"source": source, "search_lifted": entry.get("lifted"),
              "search_trials": entry.get("final_trials")}
    return grasps, record


def make_row(name: str, grasps: Mapping[str, dict], record: Mapping[str, Any],
             extents_m: Sequence[float], mass_kg: float, hand: HandLimits,
             settings: dict, seconds: float) -> dict:
    """An object's row: its grasps' counts, the best family, the search's rate, the best of all
    (ties: the search, then the families' order), its attributes and, below ``LIFTS``, the
    reason (``reasons``; the failures pooled over the grasps tied at the best rate)."""
    rate = {spec: g["lifted"] / g["trials"] for spec, g in grasps.items()}
    families = [s for s in grasps if s != SEARCHED]
    best_family = max(families, key=lambda s: rate[s]) if families else ""
    best_rate = max(rate.values())
    best = [s for s in (SEARCHED, *families) if rate[s] == best_rate]
    failures = {o: sum(grasps[s][o] for s in best) for o in FAILURES}
    extents = sorted(float(e) for e in extents_m)
    return {
        "object": name, "settings": settings, "grasps": dict(grasps), **record,
        "best_family": best_family, "best_family_rate": rate[best_family] if families else None,
        "search_rate": rate[SEARCHED], "best": best[0], "best_rate": best_rate,
        "lifts": best_rate >= LIFTS,
        "failures": failures, "dominant_failure": dominant(failures),
        "reason": "" if best_rate >= LIFTS else reasons(extents, mass_kg, hand, failures,
                                                        grasps[best[0]]),
        "extents_mm": [round(e * 1000, 1) for e in extents], "mass_kg": round(mass_kg, 4),
        "hand": {"span_mm": round(hand.span_m * 1000, 1), "torque_nm": hand.torque_nm,
                 "thumb_lever_mm": round(hand.thumb_lever_m * 1000, 1),
                 "friction": hand.friction, "holdable_kg": round(hand.holdable_kg, 3)},
        "seconds": round(seconds, 1),
    }


def remade(row: Mapping[str, Any], hand: HandLimits) -> dict:
    """``row`` made again by today's rules (``make_row``) from what it measured: its grasps'
    counts, the search's record, the object's extents and mass."""
    record = {k: row[k] for k in ("source", "search_lifted", "search_trials")}
    return make_row(row["object"], row["grasps"], record,
                    [e / 1000 for e in row["extents_mm"]], row["mass_kg"], hand,
                    row["settings"], row["seconds"])


def write_row(out: Path, row: dict) -> Path:
    """``OUT/rows/<object>.json``, written whole."""
    path = out / "rows" / f"{row['object']}.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(row, indent=1) + "\n")
    return path


def summary(rows: Sequence[dict]) -> str:
    """How many objects the search, and any grasp, lifts in >= ``LIFTS`` of its trials, and
    how many of the others have a reason."""
    search = sum(r["search_rate"] >= LIFTS for r in rows)
    lifted = sum(r["lifts"] for r in rows)
    explained = sum(bool(r["reason"]) for r in rows if not r["lifts"])
    return (f"{len(rows)} objects: the search lifts >= {LIFTS:.0%} of its trials on {search}, "
            f"some grasp on {lifted}; {len(rows) - lifted} not, {explained} of them with a "
            f"reason")


def _pct(rate: float | None) -> str:
    return "" if rate is None else f"{rate:.2f}"


def table_rows(rows: Sequence[dict]) -> list[dict]:
    """The CSV's rows (one per object, sorted by name)."""
    out = []
    for r in sorted(rows, key=lambda r: r["object"]):
        extents = r["extents_mm"]
        line = {
            "object": r["object"], "trials": r["settings"]["trials"],
            "best_family": r["best_family"], "best_family_rate": _pct(r["best_family_rate"]),
            "search_rate": _pct(r["search_rate"]), "search_source": r["source"],
            "best": r["best"], "best_rate": _pct(r["best_rate"]), "reason": r["reason"],
            "dominant_failure": r["dominant_failure"],
            "extent_min_mm": extents[0], "extent_mid_mm": extents[1],
            "extent_max_mm": extents[2], "mass_kg": r["mass_kg"],
            **{k: r["hand"][k] for k in ("span_mm", "torque_nm", "holdable_kg")},
        }
        best = r["grasps"][r["best"]]
        line.update({f"best_{k}": best.get(k, "") for k in REST_WIDTHS})
        line.update({f"{spec}_lifted": g["lifted"] for spec, g in r["grasps"].items()})
        out.append(line)
    return out


def write_table(out: Path, rows: Sequence[dict]) -> None:
    """``OUT/graspability.csv`` and ``OUT/table.md`` from ``rows``, each written whole."""
    lines = table_rows(rows)
    fields = list(dict.fromkeys(k for line in lines for k in line))
    with atomic_path(out / "graspability.csv") as tmp, open(tmp, "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=fields, restval="")
        writer.writeheader()
        writer.writerows(lines)
    settings = rows[0]["settings"]
    hand = rows[0]["hand"]
    md = [
        "# Graspability", "",
        f"{summary(rows)}.", "",
        f"{settings['trials']} trials per grasp, seed {settings['seed']}, families "
        f"{', '.join(settings['families'])} and the searched grasp; configuration: "
        f"{settings['config'] or 'the defaults'}"
        f"{''.join(f' --set {s}' for s in settings['set'])}.",
        f"The hand: span {hand['span_mm']} mm, {hand['torque_nm']} N·m per servo over a "
        f"{hand['thumb_lever_mm']} mm thumb lever, friction {hand['friction']}: holds "
        f"{hand['holdable_kg']} kg (`scripts/graspability_table.py`: the model); too thin "
        f"below {THIN_M * 1000:.1f} mm.", "",
        "| object | best family (rate) | search (rate, grasp from) | best | reason | "
        "extents mm | mass kg | failures of the best |",
        "|---|---|---|---|---|---|---:|---|",
    ]
    for line, r in zip(lines, sorted(rows, key=lambda r: r["object"]), strict=True):
        fails = ", ".join(f"{o} {n}" for o, n in r["failures"].items() if n)
        if not r["lifts"] and line["best_rest_width_failed_mm"] != "":
            lifted = line["best_rest_width_lifted_mm"]
            fails += (f" (resting {line['best_rest_width_failed_mm']:g} mm wide"
                      + (f"; its lifts {lifted:g} mm" if lifted != "" else "") + ")")
        md.append(
            f"| {r['object']} | {line['best_family']} ({line['best_family_rate']}) | "
            f"{line['search_rate']} ({r['source']}) | {r['best']} {line['best_rate']} | "
            f"{r['reason']} | {' x '.join(map(str, r['extents_mm']))} | {r['mass_kg']} | "
            f"{fails} |")
    with atomic_path(out / "table.md") as tmp:
        tmp.write_text("\n".join(md) + "\n")


def run(args: argparse.Namespace) -> None:
    """Measure every object without a row, writing its row and the table after each."""
    from geomprep import contract
    from trainer.config import dotted_overrides, load_env_config
    from trainer.config_keys import parse_sets
    from trainer.grasps.families import merge_overrides

    if args.trials < 1:
        raise UserError(f"--trials {args.trials}: must be at least 1")
    if args.seed < 0:
        raise UserError(f"--seed {args.seed}: must be >= 0")
    if args.minutes is not None and not args.minutes > 0:
        raise UserError(f"--minutes {args.minutes}: must be > 0")
    start = time.monotonic()
    families = parse_families(args.families)
    given = parse_sets(args.sets)
    data = {"data_dir": args.data_dir} if args.data_dir is not None else {}
    cfg = load_env_config(args.config, given, task="lift", context="none",
                          representation="com", **data)
    if args.remake:  # the rows as they are, whatever objects and settings they hold
        hand = hand_limits(cfg)
        rows = {name: remade(row, hand) for name, row in read_rows(args.out).items()}
        for row in rows.values():
            write_row(args.out, row)
        if rows:
            write_table(args.out, list(rows.values()))
        print(f"{len(rows)} rows made again by today's rules\n{summary(list(rows.values()))}")
        return
    names = choose_objects(args.objects, cfg.data_dir)
    settings = {"trials": args.trials, "seed": args.seed, "families": families,
                "config": str(args.config) if args.config else "", "set": list(args.sets)}
    rows = read_rows(args.out)
    check_settings(rows, settings, args.out)
    env = merge_overrides(dotted_overrides(given), {"data_dir": cfg.data_dir})
    hand = hand_limits(cfg)
    dirs = contract.DataDirs(cfg.data_dir)
    todo = [n for n in names if n not in rows]
    print(f"{len(names) - len(todo)} of {len(names)} objects already measured in {args.out}; "
          f"{len(todo)} to go (hand span {hand.span_m * 1000:.0f} mm, holds "
          f"{hand.holdable_kg:.2f} kg)")
    for k, name in enumerate(todo):
        if args.minutes is not None and time.monotonic() - start > 60 * args.minutes:
            print(f"stopped after {args.minutes:g} minutes: {len(todo) - k} objects left "
                  f"(rerun the same command to continue)")
            break
        began = time.monotonic()
        grasps, record = measure_object(name, families, args.trials, args.seed, cfg,
                                        args.config, env)
        obj = contract.read_object(dirs, name)
        row = make_row(name, grasps, record, obj.bbox_extents.tolist(), obj.mass_kg, hand,
                       settings, time.monotonic() - began)
        write_row(args.out, row)
        rows[name] = row
        write_table(args.out, list(rows.values()))
        counts = ", ".join(f"{s} {g['lifted']}/{g['trials']}" for s, g in grasps.items())
        verdict = "lifts" if row["lifts"] else f"not lifted: {row['reason']}"
        print(f"[{k + 1}/{len(todo)}] {name}: {counts} ({record['source']}) -> best "
              f"{row['best']} {row['best_rate']:.2f}, {verdict} ({row['seconds']:.0f} s)",
              flush=True)
    if rows:
        write_table(args.out, list(rows.values()))
        print(f"{summary(list(rows.values()))}\ntable: {args.out / 'table.md'}, "
              f"{args.out / 'graspability.csv'}")


def main(argv: Sequence[str] | None = None) -> None:
    """The command line: ``error: <message>`` and exit status 1 on bad input; a
    ``TrainerWarning`` one ``warning:`` line, as ``trainer`` prints it."""
    import warnings

    from trainer.cli import format_warning

    warnings.formatwarning = format_warning
    try:
        run(parse_args(argv))
    except UserError as exc:
        print(f"error: {exc}", file=sys.stderr)
        sys.exit(1)


if __name__ == "__main__":
    main()
