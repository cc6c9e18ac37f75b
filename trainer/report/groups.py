"""Runs into arms: grouped by task, view, reward and robot, split where their configs differ in
more (see the package docstring), ordered as the paper's tables, labelled; per arm, the success
of each evaluated seed."""

from __future__ import annotations

import json
from collections import Counter
from collections.abc import Iterable, Sequence

import numpy as np

from trainer.errors import TrainerError
from trainer.report.paper import PAPER_ORDER
from trainer.report.runs import GroupKey, Run

REWARD_NOTES = {"com": "reward com", "none": "no shaping"}
"""How a label names a reward kind other than the paper's ``sdf``; ablations ordered thus."""


def group_label(key: GroupKey) -> str:
    task, view = key[0], key[1]
    return view if task == "lift" else f"{task}-{view}"


GROUP_FIELDS = frozenset({
    "env.task", "env.representation", "env.context", "env.bin.num_objects", "env.reward.kind",
    "env.robot.kind",
})
"""The config fields of the group key (``Run.group``): how arms differ by design."""


def _uncommon_settings(runs: Sequence[Run]) -> dict[int, set[str]]:
    """Per run (by id), the settings outside ``GROUP_FIELDS`` in which it differs from most of
    ``runs`` (the value most of them have; on a tie, every run's): an arm that ran with another
    network than the others (the authors' point-cloud encoder, say) is named so even alone."""
    out: dict[int, set[str]] = {id(r): set() for r in runs}
    fields = set().union(*(set(r.settings) for r in runs)) - GROUP_FIELDS
    for k in fields:
        having = [r for r in runs if k in r.settings]  # (a run may predate the field)
        counts = Counter(r.settings[k] for r in having)
        if len(counts) < 2:
            continue
        (_, top), *rest = counts.most_common()
        tied = rest[0][1] == top
        for r in having:
            if tied or counts[r.settings[k]] < top:
                out[id(r)].add(k)
    return out


def group_runs(runs: Iterable[Run]) -> dict[GroupKey, list[Run]]:
    """Runs by group key, groups in the paper's order (``arm_order``), runs within a group by
    seed. Runs of one ``Run.group`` whose settings differ are split: their representation gains
    `` [name=value, ...]`` for every setting that differs (see the module docstring), and for
    every setting in which a run differs from most of the runs (``_uncommon_settings``)."""
    runs = list(runs)
    uncommon = _uncommon_settings(runs)
    by_group: dict[GroupKey, list[Run]] = {}
    for run in runs:
        by_group.setdefault(run.group, []).append(run)
    groups: dict[GroupKey, list[Run]] = {}
    for key, members in by_group.items():
        shared = set.intersection(*(set(r.settings) for r in members))
        differ = {k for k in shared if len({r.settings[k] for r in members}) > 1}
        for run in members:
            variant = ", ".join(
                f"{k.rsplit('.', 1)[-1]}={json.loads(run.settings[k])}"
                for k in sorted(differ | (uncommon[id(run)] & shared))
            )
            split = (key[0], f"{key[1]} [{variant}]", *key[2:]) if variant else key
            groups.setdefault(split, []).append(run)
    for members in groups.values():
        members.sort(key=lambda r: (r.seed is None, r.seed if r.seed is not None else 0))
    # sorted() is stable: groups of one rank keep the order in which the runs came.
    return dict(sorted(groups.items(), key=lambda item: arm_order(item[1][0])))


def arm_order(run: Run) -> tuple[int, int]:
    """Where a run's group stands in the tables: the paper's arms in ``PAPER_ORDER``, then its
    representations with the ablated rewards (``com``, then ``none``), any other reward, and
    last everything else (bin tasks, context, another robot)."""
    if (run.task, run.context, run.robot) != ("lift", "none", "ur5e") or (
        run.representation not in PAPER_ORDER
    ):
        return len(REWARD_NOTES) + 2, 0
    rewards = ("sdf", *REWARD_NOTES)
    tier = rewards.index(run.reward) if run.reward in rewards else len(rewards)
    return tier, PAPER_ORDER.index(run.representation)


def group_labels(runs: Iterable[Run]) -> dict[GroupKey, str]:
    """A label per group: the task and view (``sq``, ``bin5-bbox``, ``bin5-bbox+ctx``), with
    what differs from the paper's reward and robot in brackets: ``bbox (reward com)``, ``bbox
    (no shaping)`` (reward kind ``none``), ``bbox (robot floating)``."""
    labels = {}
    for key in group_runs(runs):
        notes = [] if key[2] == "sdf" else [REWARD_NOTES.get(key[2], f"reward {key[2]}")]
        notes += [] if key[3] == "ur5e" else [f"robot {key[3]}"]
        labels[key] = group_label(key) + (f" ({'; '.join(notes)})" if notes else "")
    return labels


def resolve_group(runs: Sequence[Run], name: str) -> GroupKey:
    """The group a user names: by its label, else by its task and view (``bin5-bbox``) or its
    representation (``sq``) if that names one group."""
    labels = group_labels(runs)
    for key, label in labels.items():
        if label == name:
            return key
    known = ", ".join(labels.values())
    by_view = [k for k in labels if group_label(k) == name]
    for matches in (by_view, [k for k in labels if k[1] == name]):
        if len(matches) == 1:
            return matches[0]
        if matches:
            raise TrainerError(f"{name!r} names several groups; use one of the labels: {known}")
    raise TrainerError(f"no group named {name!r}; the runs' groups are: {known}")


def seed_rates(members: Sequence[Run]) -> list[dict[str, float]]:
    """Per evaluated run of a group: object -> successes / episodes (objects with episodes)."""
    return [
        {name: s / e for name, (e, s) in run.per_object.items() if e}
        for run in members
        if run.per_object is not None
    ]


def per_object_rates(members: Sequence[Run]) -> dict[str, float]:
    """Per object, the mean over seeds of each seed's successes / episodes (evaluated runs only)."""
    rates: dict[str, list[float]] = {}
    for seed in seed_rates(members):
        for name, rate in seed.items():
            rates.setdefault(name, []).append(rate)
    return {name: float(np.mean(values)) for name, values in rates.items()}


def overall_success(members: Sequence[Run]) -> list[float]:
    """Per evaluated run of a group, its mean success over the objects it was evaluated on (each
    object weighs the same, as in the paper's Table I); the mean of these is Table I's overall."""
    return [float(np.mean(list(seed.values()))) for seed in seed_rates(members) if seed]
