"""Why the scripted top grasp fails on some of the paper's Table I objects: one knob at a time.

For every variant (the default physics and script, then one change each) and every object, 10
randomized trials of ``trainer.scripted.run_scripted_grasp`` (one batch, all objects), with the
target's trajectory recorded to tell the failures apart:

* ``pushed``: it never rose 2 cm and the hand had moved it > 2 cm sideways by the end of the
  close (the approach, descent or closing fingers knocked it: hand geometry or approach);
* ``no grip``: the object never rose 2 cm (the fingers closed without holding it);
* ``dropped``: it rose >= 2 cm but did not reach the lift height (the grip slipped: friction,
  squeeze force, contact quality);
* ``lifted``: lifted by 0.2 m (the env's success).

Run from the repository root with the Table I objects built in ``data/``:

    python results/scripted-table1/causes.py [--variants base,friction2,...] [--trials 10]

Prints a Markdown table per variant and writes ``causes.csv`` beside this file. With
``--grid``, instead scans the script's geometry (grasp depth, lateral offset, thumb closure, palm
clearance: 108 combinations, 6 trials each) for the objects the default fails on, and writes
``causes-grid.csv``.
"""

from __future__ import annotations

import argparse
import csv
import itertools
import time
import tomllib
from dataclasses import replace
from pathlib import Path

import torch

from trainer.config import load_env_config
from trainer.scripted import ScriptedGrasp, run_scripted_grasp
from trainer.tasks import make_env

# The paper's Table I objects, as the learning comparison names them.
with open(Path(__file__).parents[1] / "cpu-table1" / "table1.toml", "rb") as _f:
    OBJECTS = tuple(tomllib.load(_f)["objects"].split(","))
BASE = ScriptedGrasp()
# name -> (EnvConfig overrides, script); one change from the default each.
VARIANTS: dict[str, tuple[dict, ScriptedGrasp]] = {
    "base": ({}, BASE),
    "friction2": ({"physics": {"finger_friction": (2.0, 0.01, 0.0001)}}, BASE),
    "force0.75": ({"robot": {"hand_forcerange": 0.75}}, BASE),
    "force15": ({"robot": {"hand_forcerange": 15.0}}, BASE),
    "kp60": ({"robot": {"hand_kp": 60.0}}, BASE),
    "substeps20": ({"physics": {"substeps": 20}}, BASE),
    "deeper": ({}, replace(BASE, grasp_depth=0.19)),
    "shallower": ({}, replace(BASE, grasp_depth=0.13)),
    "thumb0.8": ({}, replace(BASE, thumb_closed=0.8)),
    # The grid's best geometry for the plate (fingertips at its rim), alone and with friction 2.
    "rim": ({}, replace(BASE, grasp_depth=0.22, lateral=0.0)),
    "rim+friction2": (
        {"physics": {"finger_friction": (2.0, 0.01, 0.0001)}},
        replace(BASE, grasp_depth=0.22, lateral=0.0),
    ),
    # Contact creep: MuJoCo's no-slip solver, or stiffer friction (impratio 10).
    "noslip": ({"physics": {"noslip_iterations": 5}}, BASE),
    "impratio10": ({"physics": {"impratio": 10.0}}, BASE),
}


HARD = ("029_plate", "032_knife", "062_dice", "072-a_toy_airplane", "007_tuna_fish_can",
        "053_mini_soccer_ball")
"""The objects the default script lifts <= 2 times in 10."""
GRID = {
    "grasp_depth": (0.13, 0.16, 0.19, 0.22),
    "lateral": (-0.05, -0.03, 0.0),
    "thumb_closed": (0.4, 0.8, 1.2),
    "palm_clearance": (0.016, 0.03, 0.05),
}


def outcome_rows(
    name: str, objects: tuple[str, ...], ids: torch.Tensor, pos: torch.Tensor,
    lifted: torch.Tensor, pushed_at: int,
) -> list[dict]:
    """One row per object: its trials classified from the target's positions ``pos`` (T, E, 3)
    and the env's ``lifted`` (E,); *pushed* looks at the sideways move by step ``pushed_at``."""
    start = pos[0]
    pushed = (pos[pushed_at, :, :2] - start[:, :2]).norm(dim=-1) > 0.02
    rise = (pos[:, :, 2] - start[:, 2]).amax(0)
    rose = rise >= 0.02
    rows = []
    for k, obj in enumerate(objects):
        m = ids == k
        rows.append({
            "variant": name, "object": obj, "trials": int(m.sum()),
            "lifted": int(lifted[m].sum()),
            "dropped": int((rose & ~lifted)[m].sum()),
            "no_grip": int((~rose & ~pushed)[m].sum()),
            "pushed": int((~rose & pushed)[m].sum()),
            "max_rise_cm": round(float(rise[m].max()) * 100, 1),
        })
    return rows


def write_rows(path: Path, rows: list[dict]) -> None:
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)


def run_variant(
    name: str, trials: int, data_dir: Path, objects: tuple[str, ...] = OBJECTS
) -> list[dict]:
    overrides, script = VARIANTS[name]
    cfg = load_env_config(
        num_envs=trials * len(objects), objects=",".join(objects), data_dir=data_dir,
        representation="com", **overrides,
    )
    env = make_env(cfg, seed=0)
    close_end = script.approach_steps + script.descend_steps + script.close_steps
    track: list[torch.Tensor] = []
    lifted = run_scripted_grasp(
        env, script, on_step=lambda _: track.append(env.target_pose()[0].clone())
    )
    pos = torch.stack(track)  # (T, E, 3)
    rows = outcome_rows(name, objects, env.target_objects(), pos, lifted, close_end - 1)
    env.close()
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--variants", default=",".join(VARIANTS))
    parser.add_argument("--trials", type=int, default=10)
    parser.add_argument("--data-dir", type=Path, default=Path("data"))
    parser.add_argument("--grid", action="store_true", help="scan the script's geometry")
    args = parser.parse_args()
    if args.grid:
        grid(args.data_dir)
        return
    out = Path(__file__).with_name("causes.csv")
    all_rows: list[dict] = []
    for name in args.variants.split(","):
        t = time.perf_counter()
        rows = run_variant(name, args.trials, args.data_dir)
        all_rows += rows
        total = sum(r["lifted"] for r in rows)
        print(f"\n### {name} ({total}/{sum(r['trials'] for r in rows)} lifted, "
              f"{time.perf_counter() - t:.0f} s)\n")
        print("| object | lifted | dropped | no grip | pushed | max rise cm |")
        print("|---|---:|---:|---:|---:|---:|")
        for r in rows:
            print(f"| {r['object']} | {r['lifted']} | {r['dropped']} | {r['no_grip']} | "
                  f"{r['pushed']} | {r['max_rise_cm']} |")
        write_rows(out, all_rows)


def grid(data_dir: Path, trials: int = 6) -> None:
    out = Path(__file__).with_name("causes-grid.csv")
    rows: list[dict] = []
    for values in itertools.product(*GRID.values()):
        params = dict(zip(GRID, values, strict=True))
        name = "_".join(f"{k}={v}" for k, v in params.items())
        VARIANTS[name] = ({}, replace(BASE, **params))
        batch = run_variant(name, trials, data_dir, HARD)
        rows += batch
        print(name, [r["lifted"] for r in batch], flush=True)
        write_rows(out, rows)


if __name__ == "__main__":
    main()
