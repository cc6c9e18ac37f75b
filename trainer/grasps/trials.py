"""Grasp trials over objects: every configuration, family variant and seed measured on the same
objects (``families.measure``: one batch of envs each), batch by batch. ``trainer grasp`` (the
variants of one family) and ``bench/graspability.py`` (configurations x families x seeds) run
their trials here and print and write what each batch gives."""

from __future__ import annotations

import itertools
import time
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from trainer.config import dotted_overrides
from trainer.grasps.families import Variant, measure


@dataclass(frozen=True)
class TrialBatch:
    """The trials of one configuration, family variant and seed: ``measure``'s rows, one per
    object (``object``, ``family``, ``variant``, ``trials``, ``lifted``, ``dropped``,
    ``no_grip``, ``pushed``, ...), and the seconds they took."""

    family: str
    variant: str
    seed: int
    rows: list[dict]
    seconds: float
    config: Mapping[str, Any] = field(default_factory=dict)
    """The configuration's dotted overrides (``robot.hand_kp`` -> 30; empty: the baseline)."""

    @property
    def lifted(self) -> int:
        """Trials that lifted, over every object."""
        return sum(row["lifted"] for row in self.rows)

    @property
    def trials(self) -> int:
        """Trials run, over every object."""
        return sum(row["trials"] for row in self.rows)


def run_trials(
    variants: Sequence[tuple[str, str, Variant]], objects: Sequence[str], trials: int,
    seeds: Sequence[int] = (0,), configs: Sequence[Mapping[str, Any]] = ({},),
    config_path: Path | None = None, hold: bool = False, **env: Any,
) -> Iterator[TrialBatch]:
    """For each configuration of ``configs`` (dotted overrides, ``{}``: the baseline), each
    (family, variant name, ``Variant``) of ``variants`` and each seed of ``seeds``, in that
    order: ``trials`` trials per object of ``objects`` (``measure``: the same initial states
    for every configuration and variant of a seed), as one ``TrialBatch`` as soon as it ran.

    ``env``: ``load_env_config`` overrides of every configuration (data_dir, backend, device,
    reward, ...); a configuration's own overrides replace a section of them it names.
    ``hold``: probe the trials still lifted at the script's end (``measure``)."""
    for config in configs:
        for (family, name, variant), seed in itertools.product(variants, seeds):
            start = time.perf_counter()
            rows = measure(family, name, variant, objects, trials, seed, config_path, hold=hold,
                           **{**env, **dotted_overrides(config)})
            yield TrialBatch(family, name, seed, rows, time.perf_counter() - start, config)
