"""How a scripted grasp trial ended, told from its recorded trajectory (``GraspTrajectory``).

Each trial is exactly one of:

* ``lifted``: the env's success (the task's: raised by h_bar, held if the reward asks for it);
* ``dropped``: the target rose >= ``RISE`` above its height after the first action, but was not
  lifted (the grip slipped: friction, squeeze force, contact quality);
* ``pushed``: it never rose ``RISE`` and had moved > ``PUSH`` sideways by the script's
  ``pushed_at`` step (the hand knocked it: hand geometry or approach);
* ``no_grip``: it never rose ``RISE`` and was not pushed (the fingers closed without holding it).

Heights and displacements are measured from the first recorded step (the state after the first
action), as results/scripted-table1 measured them.
"""

from __future__ import annotations

import csv
from collections.abc import Sequence
from pathlib import Path

import torch

from geomgrasp.files import atomic_path
from trainer.grasps.runner import GraspTrajectory

OUTCOMES = ("lifted", "dropped", "no_grip", "pushed")
"""Outcome names, in the order of their codes (``classify``)."""
RISE = 0.02
"""m: a rise of at least this much means the hand held the target for a while."""
PUSH = 0.02
"""m: a sideways move beyond this before the grip means the hand knocked the target."""
HELD_PADS = 2
HELD_DISTANCE = 0.02
"""A success is *held* (not a toss) when >= HELD_PADS fingertip pads are within HELD_DISTANCE
(m) of the target's surface at that step (results/cpu-table1, "Tosses are not lifts")."""


def rise(trajectory: GraspTrajectory) -> torch.Tensor:
    """(E,) m: the target's highest rise above its height at the first step."""
    z = trajectory.target_pos[..., 2]
    return (z - z[0]).amax(0)


def classify(trajectory: GraspTrajectory, pushed_at: int) -> torch.Tensor:
    """(E,) long: each trial's outcome code, an index into ``OUTCOMES``. ``pushed_at``: the
    step whose sideways displacement tells *pushed* (``GraspScript.pushed_at``)."""
    pos = trajectory.target_pos
    if not 0 <= pushed_at < len(pos):
        raise ValueError(f"pushed_at {pushed_at}: outside the {len(pos)} recorded steps")
    pushed = (pos[pushed_at, :, :2] - pos[0, :, :2]).norm(dim=-1) > PUSH
    rose = rise(trajectory) >= RISE
    code = torch.full(rose.shape, OUTCOMES.index("no_grip"), dtype=torch.long)
    code[pushed] = OUTCOMES.index("pushed")
    code[rose] = OUTCOMES.index("dropped")
    code[trajectory.lifted] = OUTCOMES.index("lifted")
    return code


def held_at_success(trajectory: GraspTrajectory) -> torch.Tensor:
    """(E,) bool: succeeded with >= HELD_PADS pads within HELD_DISTANCE of the target."""
    pads = trajectory.success_distance[:, 1:]
    return trajectory.lifted & ((pads < HELD_DISTANCE).sum(-1) >= HELD_PADS)


def _cm(value: torch.Tensor) -> float:
    return round(float(value) * 100, 1)


def outcome_rows(
    names: Sequence[str], ids: torch.Tensor, trajectory: GraspTrajectory,
    close_window: tuple[int, int], pushed_at: int, **labels: str,
) -> list[dict]:
    """One row per object (``names``; ``ids`` (E,) each env's object index): ``labels`` (e.g.
    family, variant), the trials, the count of each outcome, the highest and median rise (cm),
    the lowest thumb and index pad (cm) during ``close_window`` [start, end) (steps), and of
    the lifts, how many were held by two pads within 2 cm (``held_lifts``) and the nearest pad's
    median distance at success (cm, empty without lifts); how many trials started with the
    target upside down (``GraspTrajectory.start_up``) and how many of those were lifted; the
    median width (mm) the target rested with (``GraspTrajectory.start_width``) over the lifted
    trials and over the others (empty where there are none): a grasp that lifts the target
    only where it rests narrow names its resting pose as the failure's cause."""
    ids = ids.cpu()
    code = classify(trajectory, pushed_at)
    up = rise(trajectory)
    start, end = close_window
    pads = trajectory.pad_height[start:end]  # (W, E, 5)
    held = held_at_success(trajectory)
    nearest = trajectory.success_distance[:, 1:].amin(-1)
    upside_down = (trajectory.start_up < 0 if trajectory.start_up is not None
                   else torch.zeros_like(trajectory.lifted))
    width = trajectory.start_width

    def median_mm(select: torch.Tensor) -> float | str:
        if width is None or not bool(select.any()):
            return ""
        return round(float(width[select].median()) * 1000, 1)

    rows = []
    for k, name in enumerate(names):
        m = ids == k
        if not bool(m.any()):
            continue
        lifts = m & trajectory.lifted
        row: dict = {**labels, "object": name, "trials": int(m.sum())}
        row.update({o: int((code[m] == i).sum()) for i, o in enumerate(OUTCOMES)})
        row.update({
            "max_rise_cm": _cm(up[m].max()),
            "median_rise_cm": _cm(up[m].median()),
            "thumb_pad_min_cm": _cm(pads[:, m, 0].min()),
            "index_pad_min_cm": _cm(pads[:, m, 1].min()),
            "held_lifts": int(held[m].sum()),
            "upside_down": int(upside_down[m].sum()),
            "upside_down_lifted": int((upside_down & trajectory.lifted)[m].sum()),
            "nearest_pad_median_cm": _cm(nearest[lifts].median()) if bool(lifts.any()) else "",
            "rest_width_lifted_mm": median_mm(lifts),
            "rest_width_failed_mm": median_mm(m & ~trajectory.lifted),
        })
        rows.append(row)
    return rows


def write_rows(path: Path, rows: Sequence[dict]) -> None:
    """``rows`` (dicts with the same keys) as a CSV at ``path``, written atomically."""
    with atomic_path(path) as tmp, open(tmp, "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
