"""Graspability: which objects can the hand and its physics lift at all, with the package's
scripted grasp families (``trainer.grasps``), under one or more configurations, each compared
with a baseline measured in the same run.

For each configuration and each family (``top``, ``pinch``, or ``family:variant``; the ``base``
variant by default), the package's grasp-trial runner (``trainer.grasps.trials.run_trials``,
also behind ``trainer grasp``) runs ``--trials`` randomized trials per object in one batch
(the lift task, seed ``--seed``: every configuration and family sees the same initial states
for the same objects) and classifies each: *lifted* (raised by 0.2 m and held, the task's
success), *dropped*, *no_grip*, *pushed* (``trainer.grasps.outcomes``).

Configurations: the baseline is today's defaults (``--config`` if given); ``--set KEY=VALUE``
(``section.field``, a TOML value, repeatable) makes one configuration under test, ``--grid
KEY=V1,V2,...`` (repeatable) one per combination (with the ``--set`` values on each). A grid's
first combination that equals the baseline is measured once. Prints a table per configuration,
then one summary line each: lifted of all trials and the ratio to the baseline's lifts.

    python bench/graspability.py --objects 062_dice,032_knife --trials 10 --out dice.csv \\
        [--family top,pinch:press6+noslip] [--backend cpu|warp --device DEV] \\
        [--set robot.hand_geometry=hulls ...] [--grid robot.hand_forcerange=5.0,0.75 ...]

The CSV has one row per configuration, family and object: ``object,family,trials,lifted,
dropped,no_grip,pushed``, then ``variant``, ``config`` (the configuration's label: ``baseline``
or its ``key=value`` overrides) and one column per ``--set`` / ``--grid`` key (that row's value).
``--hold`` (CPU backend) probes every trial still lifted at the script's end
(``trainer.grasps.hold``: slip speed relative to the palm, grip force, the pull resisted over
what friction times the grip allows, and the grip and that ratio again with the contacts'
forces when the pull ended, and the least and most any contact then used of its friction
cone) and adds ``held_end`` and ``trainer.grasps.families.HOLD_KEYS`` (medians) to the table
and the CSV; ``--hold-out FILE`` writes every probed trial's measurements (one row each).

``--family best`` tries each object with its own best family only (``BEST``, else its searched
grasp): the graspability bench's check that a change keeps every object's grasp. A family
variant's own settings win over ``--set`` / ``--grid`` (a clash is an error) unless
``--over-family``: then the configuration's values replace the variant's, to measure a physics
change under the families that fix it (results/bench-step-phases-2026-11-29/).

``--seed`` takes several seeds (``0,1,2`` or ``0-4``): each configuration and family is measured
once per seed (the CSV's ``seed`` column), and with ``--hold`` a last table pools every held
trial per object over the seeds: the pull ratio's median and how many reach 0.8 (issue 33's
pull target), the slip speed and the grip while holding and when the pull ended.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import itertools
import math
import statistics
import sys
from dataclasses import asdict
from pathlib import Path
from typing import Any

from geomgrasp.config_schema import toml_value
from geomgrasp.errors import UserError
from geomgrasp.files import atomic_path
from trainer.config import dotted_overrides as overrides
from trainer.config_keys import check_set, parse_assignment, parse_sets, parse_value
from trainer.grasps.families import HOLD_KEYS, merge_overrides

COLUMNS = ("object", "family", "trials", "lifted", "dropped", "no_grip", "pushed")
"""The CSV's leading columns, as the graspability benchmark names them (issue 33)."""


def configurations(sets: list[str], grids: list[str]) -> list[dict[str, Any]]:
    """The configurations to measure, each a dict of dotted key -> value: the baseline (empty)
    first, then one per combination of the ``grids`` values, each with the ``sets`` values (a
    combination equal to the baseline is not repeated)."""
    fixed = parse_sets(sets)
    axes = []
    for g in grids:
        key, values = parse_assignment(g, "--grid")
        axes.append((key, [parse_value(v) for v in values.split(",") if v.strip()]))
        for value in axes[-1][1]:
            check_set(key, value, f"--grid {key}={toml_value(value)}", training=False)
    configs: list[dict[str, Any]] = [{}]
    for combo in itertools.product(*(values for _, values in axes)):
        config = {**fixed, **{key: v for (key, _), v in zip(axes, combo, strict=True)}}
        if config not in configs:
            configs.append(config)
    return configs


def is_baseline(config: dict[str, Any], default: dict[str, Any]) -> bool:
    """Whether ``config`` sets every key to its value in ``default`` (the baseline's config as
    nested dicts)."""
    for key, value in config.items():
        node: Any = default
        for part in key.split("."):
            node = node.get(part) if isinstance(node, dict) else None
        if node != value and not (isinstance(node, tuple) and list(node) == value):
            return False
    return True


def label(config: dict[str, Any]) -> str:
    """A configuration's name in the table and the CSV."""
    return " ".join(f"{k}={v}" for k, v in config.items()) or "baseline"


def parse_families(spec: str) -> list[tuple[str, str]]:
    """``top,pinch:press6+noslip`` -> [(family, variant)]; unknown names are one-line errors."""
    from trainer.grasps import family, family_variants

    chosen = []
    for item in (s.strip() for s in spec.split(",") if s.strip()):
        name, _, variant = item.partition(":")
        family(name)  # an unknown family: one line listing them
        family_variants(name, [variant or "base"])  # an unknown variant: one line listing them
        chosen.append((name, variant or "base"))
    if not chosen:
        raise UserError("--family: name at least one grasp family (top, pinch)")
    return chosen


def check_not_fixed(families: list[tuple[str, str]], configs: list[dict[str, Any]]) -> None:
    """A ``--set`` / ``--grid`` key that a chosen variant fixes itself (its environment
    overrides win) is a one-line error: the configurations would silently not differ."""
    from trainer.grasps import family_variants

    keys = {k for c in configs for k in c}
    for name, variant_name in families:
        fixed = set()
        for section, values in family_variants(name, [variant_name])[variant_name].env.items():
            if isinstance(values, dict):  # a section's fields
                fixed |= {f"{section}.{field}" for field in values}
            else:  # a top-level field
                fixed.add(section)
        clash = sorted(keys & fixed)
        if clash:
            raise UserError(f"{clash[0]}: the family {name}:{variant_name} fixes it (its "
                            f"variant's own setting wins): measure it with another family")


HOLD_COLUMNS = ("held_end", *HOLD_KEYS)
"""``--hold``'s columns (``trainer.grasps.measure``)."""
TRIAL_COLUMNS = ("object", "family", "variant", "config", "seed", "held", "slip_mm_s", "grip_n",
                 "capacity_n", "weight_n", "pull_n", "pull_ratio", "slip_grip_n",
                 "slip_capacity_n", "slip_pull_ratio", "slip_cone_min", "slip_cone_max")
"""``--hold-out``'s columns: one probed trial each (``trainer.grasps.hold.Hold``)."""
PULL_TARGET = 0.8
"""Issue 33: a held object resists >= 80 % of the pull friction times its grip allows."""


def parse_seeds(spec: str) -> list[int]:
    """``3``, ``0,1,2`` or ``0-4`` -> the seeds, in order; anything else a one-line error."""
    seeds: list[int] = []
    try:
        for part in (p.strip() for p in spec.split(",") if p.strip()):
            first, dash, last = part.partition("-")
            seeds += list(range(int(first), int(last) + 1)) if dash else [int(part)]
    except ValueError:
        seeds = []
    if not seeds or min(seeds) < 0:
        raise UserError(f"--seed {spec!r}: give seeds >= 0 as 3, 0,1,2 or 0-4")
    return list(dict.fromkeys(seeds))


def trial_rows(rows: list[dict]) -> list[dict]:
    """One ``TRIAL_COLUMNS`` row per probed trial of ``rows`` (their ``holds``)."""
    out = []
    for row in rows:
        for h in row.get("holds", ()):
            trial = {k: row[k] for k in ("object", "family", "variant", "config", "seed")}
            trial.update({k: getattr(h, k) for k in TRIAL_COLUMNS[5:]})
            out.append({k: round(v, 4) if isinstance(v, float) else v for k, v in trial.items()})
    return out


def pooled_holds(trials: list[dict]) -> list[dict]:
    """Per configuration, family, variant and object, over every seed: the held trials, the
    pull ratio's median and how many reach ``PULL_TARGET``, and the medians of the slip speed,
    the grip while holding and when the pull ended, and the ratio on the latter."""
    groups: dict[tuple, list[dict]] = {}
    for t in trials:
        groups.setdefault(tuple(t[k] for k in ("config", "family", "variant", "object")),
                          []).append(t)

    def median(values: list[dict], key: str) -> float | str:
        finite = [v[key] for v in values if not math.isnan(v[key])]
        return round(statistics.median(finite), 3) if finite else ""

    out = []
    for (config, fam, variant, obj), group in groups.items():
        held = [t for t in group if t["held"]]
        ratios = [t["pull_ratio"] for t in held if not math.isnan(t["pull_ratio"])]
        out.append({"config": config, "family": fam, "variant": variant, "object": obj,
                    "seeds": len({t["seed"] for t in group}), "probed": len(group),
                    "held": len(held), "pull_ratio": median(held, "pull_ratio"),
                    "at_target": sum(r >= PULL_TARGET for r in ratios),
                    "slip_mm_s": median(held, "slip_mm_s"), "grip_n": median(held, "grip_n"),
                    "slip_grip_n": median(held, "slip_grip_n"),
                    "slip_pull_ratio": median(held, "slip_pull_ratio")})
    return out


def write_csv(path: Path, rows: list[dict], keys: list[str], hold: bool = False) -> None:
    """The rows as a CSV (``COLUMNS``, ``variant``, ``config``, ``seed``, the trials that
    started upside down and of those the lifted, ``keys``, then with ``hold`` ``HOLD_COLUMNS``),
    atomically."""
    fields = [*COLUMNS, "variant", "config", "seed", "upside_down", "upside_down_lifted", *keys,
              *(HOLD_COLUMNS if hold else ())]
    with atomic_path(path) as tmp, open(tmp, "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=fields, extrasaction="ignore")
        writer.writeheader()
        writer.writerows(rows)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--objects", default=None,
                        help="object names or a set (builtin, ycb) [the Table I objects]")
    parser.add_argument("--trials", type=int, default=10, help="trials per object [10]")
    parser.add_argument("--out", type=Path, default=None, help="CSV of every row")
    parser.add_argument("--family", default="top",
                        help="families, comma-separated, each optionally FAMILY:VARIANT, or "
                        "best: each object's own best family only [top]")
    parser.add_argument("--backend", choices=("cpu", "warp"), default=None, help="[cpu]")
    parser.add_argument("--device", default=None, help="torch / Warp device [cpu]")
    parser.add_argument("--seed", default="0",
                        help="seed(s) of the initial states: 3, 0,1,2 or 0-4 [0]")
    parser.add_argument("--data-dir", type=Path, default=None, help="[./data]")
    parser.add_argument("--config", type=Path, default=None, help="TOML config of every run")
    parser.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE",
                        help="an override of the configuration under test (repeatable)")
    parser.add_argument("--grid", dest="grids", action="append", default=[],
                        metavar="KEY=V1,V2", help="one configuration per value (repeatable)")
    parser.add_argument("--over-family", action="store_true",
                        help="--set / --grid replace a family variant's own setting of the same "
                        "key (e.g. a physics cut under the families that fix no-slip)")
    parser.add_argument("--hold", action="store_true",
                        help="probe the held trials' slip and pull (cpu backend)")
    parser.add_argument("--hold-out", type=Path, default=None,
                        help="with --hold: CSV of every probed trial's measurements")
    args = parser.parse_args(argv)
    try:
        run(args)
    except UserError as exc:
        print(f"error: {exc}", file=sys.stderr)
        sys.exit(1)


def run(args: argparse.Namespace) -> None:
    """Measure every configuration x family and print the tables and the summary."""
    from trainer.config import load_env_config
    from trainer.grasps import TABLE1_OBJECTS, family_variants
    from trainer.grasps.outcomes import write_rows
    from trainer.grasps.trials import run_trials
    from trainer.objects import resolve_names

    if args.trials < 1:
        raise UserError(f"--trials {args.trials}: must be at least 1")
    if args.hold and args.backend == "warp":
        raise UserError("--hold probes states copied out of the cpu backend: drop --hold or "
                        "use --backend cpu")
    if args.hold_out is not None and not args.hold:
        raise UserError("--hold-out writes the hold probe's trials: add --hold")
    seeds = parse_seeds(str(args.seed))
    configs = configurations(args.sets, args.grids)
    best = args.family == "best"
    families = [] if best else parse_families(args.family)
    if not args.over_family:
        check_not_fixed(families, configs)
    env: dict[str, Any] = {k: v for k, v in {
        "data_dir": args.data_dir, "backend": args.backend, "device": args.device}.items()
        if v is not None}
    for config in configs:  # every configuration checked before the first trial runs
        load_env_config(args.config, **{**env, **overrides(config)})
    default = load_env_config(args.config, **env)
    objects = resolve_names(args.objects or ",".join(TABLE1_OBJECTS), default.data_dir)
    keys = list(dict.fromkeys(k for c in configs for k in c))
    # A configuration under test that equals the baseline is measured once, as the baseline.
    same = [c for c in configs[1:] if is_baseline(c, asdict(default))]
    if same:
        configs = [same[0], *(c for c in configs[1:] if c is not same[0])]

    rows: list[dict] = []
    totals: dict[str, tuple[int, int]] = {}
    # (family, variant name, Variant, the objects it is tried on)
    if best:  # each object with its own best family only (BEST, else its searched grasp)
        from trainer.grasps.families import best_variants

        groups = [(spec.partition(":")[0], spec.partition(":")[2] or "base", variant, names)
                  for spec, (variant, names) in best_variants(objects, objects).items()]
    else:
        groups = [(fam, v, family_variants(fam, [v])[v], objects) for fam, v in families]

    def batches():
        for config in configs:
            for fam, v, variant, names in groups:
                if args.over_family:  # the configuration's keys replace the variant's own
                    variant = dataclasses.replace(
                        variant, env=merge_overrides(variant.env, overrides(config)))
                yield from run_trials([(fam, v, variant)], names, args.trials, seeds, [config],
                                      args.config, hold=args.hold, **env)

    for batch in batches():
        name, seed, config = label(batch.config), batch.seed, batch.config
        for row in batch.rows:
            row.update(config=name, seed=seed, **{k: config.get(k, "") for k in keys})
        rows += batch.rows
        lifted, trials = batch.lifted, batch.trials
        done = totals.get(name, (0, 0))
        totals[name] = (done[0] + lifted, done[1] + trials)
        print(f"\n### {name}: {batch.family} {batch.variant}, seed {seed} ({lifted}/{trials} "
              f"lifted, {batch.seconds:.0f} s)\n")
        extra = HOLD_COLUMNS if args.hold else ()
        print("| object | lifted | dropped | no grip | pushed | upside down (lifted) |"
              + "".join(f" {c} |" for c in extra))
        print("|---|---:|---:|---:|---:|---:|" + "---:|" * len(extra))
        for r in batch.rows:
            print(f"| {r['object']} | {r['lifted']} | {r['dropped']} | {r['no_grip']} | "
                  f"{r['pushed']} | {r['upside_down']} ({r['upside_down_lifted']}) |"
                  + "".join(f" {r[c]} |" for c in extra))
        sys.stdout.flush()
        if args.out is not None:
            write_csv(args.out, rows, keys, args.hold)
        trials_so_far = trial_rows(rows)
        if args.hold_out is not None and trials_so_far:
            write_rows(args.hold_out, trials_so_far)

    if args.hold:
        print(f"\n## held trials pooled over seeds {','.join(map(str, seeds))} (pull ratio: "
              f"(weight + pull) / friction x the grip while holding; target {PULL_TARGET})\n")
        print("| config | family:variant | object | held / probed | pull ratio (median) | "
              f">= {PULL_TARGET} | slip mm/s | grip N (hold / at slip) | ratio at slip |")
        print("|---|---|---|---:|---:|---:|---:|---:|---:|")
        for p in pooled_holds(trial_rows(rows)):
            print(f"| {p['config']} | {p['family']}:{p['variant']} | {p['object']} | "
                  f"{p['held']} / {p['probed']} | {p['pull_ratio']} | {p['at_target']} | "
                  f"{p['slip_mm_s']} | {p['grip_n']} / {p['slip_grip_n']} | "
                  f"{p['slip_pull_ratio']} |")

    base = totals[label(configs[0])][0]
    print("\n## summary (lifted of all trials; ratio to the baseline, measured in this run)\n")
    print(f"baseline: {label(configs[0]) if configs[0] else 'the default configuration'}")
    for name, (lifted, trials) in totals.items():
        ratio = f"{lifted / base:.2f}x" if base else "n/a (baseline lifted 0)"
        print(f"{name}: {lifted}/{trials} lifted, {ratio} the baseline")
    if args.out is not None:
        print(f"\nrows: {args.out}")
    if args.hold_out is not None:
        print(f"probed trials: {args.hold_out}" if trial_rows(rows) else
              "probed trials: none (no trial ended lifted), so --hold-out was not written")


if __name__ == "__main__":
    main()
