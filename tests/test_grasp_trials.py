"""trainer.grasps.trials.run_trials, the grasp-trial runner behind ``trainer grasp`` and
bench/graspability.py: every configuration, variant and seed in that order, each measured with
the configuration's overrides over the common ones (``measure`` itself is stubbed here; the
trials run in tests/test_grasps.py and tests/test_bench_smoke.py)."""

from __future__ import annotations

import pytest

import trainer.grasps.trials as trials
from trainer.grasps import family_variants


def test_batches_in_order_with_their_overrides(monkeypatch: pytest.MonkeyPatch) -> None:
    calls = []

    def measure(family, name, variant, objects, n, seed, config_path, hold=False, **env):  # noqa: ANN001, ANN003, ANN202
        calls.append((family, name, seed, env))
        return [{"object": o, "trials": n, "lifted": seed} for o in objects]

    monkeypatch.setattr(trials, "measure", measure)
    variants = [("top", v, family_variants("top", [v])[v]) for v in ("base",)]
    variants += [("pinch", "press6", family_variants("pinch", ["press6"])["press6"])]
    batches = list(trials.run_trials(
        variants, ["a", "b"], 3, seeds=[0, 1], configs=[{}, {"robot.hand_kp": 30}],
        data_dir="d", robot={"kind": "ur5e"}))
    assert [(b.family, b.variant, b.seed, dict(b.config)) for b in batches] == [
        (f, v, s, c) for c in ({}, {"robot.hand_kp": 30}) for f, v in
        (("top", "base"), ("pinch", "press6")) for s in (0, 1)]
    assert calls[0][3] == {"data_dir": "d", "robot": {"kind": "ur5e"}}
    # A configuration's section replaces the common one of the same name (as the bench did).
    assert calls[-1][3] == {"data_dir": "d", "robot": {"hand_kp": 30}}
    assert batches[1].trials == 6 and batches[1].lifted == 2 and batches[0].seconds >= 0
