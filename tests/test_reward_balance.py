"""bench/reward_balance.py: discounting, and lift vs rest rollouts on a built-in object (the
lift's episode ends at its success with the bonus; the rest runs to max_steps without it)."""

from __future__ import annotations

import csv
import importlib.util
from pathlib import Path

import pytest
import torch

from geomprep.config import Config

_PATH = Path(__file__).resolve().parents[1] / "bench" / "reward_balance.py"
_SPEC = importlib.util.spec_from_file_location("reward_balance", _PATH)
reward_balance = importlib.util.module_from_spec(_SPEC)
_SPEC.loader.exec_module(reward_balance)


def test_discounted_weights_each_step_by_gamma_to_its_index() -> None:
    rewards = torch.tensor([[1.0, 0.0], [1.0, 2.0], [1.0, 0.0]])
    torch.testing.assert_close(reward_balance.discounted(rewards, 0.5),
                               torch.tensor([1.75, 1.0], dtype=torch.float64))


def test_lift_ends_with_the_bonus_and_rest_runs_to_the_end(builtin_data: Config,
                                                           tmp_path: Path) -> None:
    out = tmp_path / "balance.csv"
    reward_balance.main(["--objects", "builtin_cylinder", "--trials", "2", "--max-steps", "160",
                         "--data-dir", str(builtin_data.data_dir), "--out", str(out)])
    lift, rest = list(csv.DictReader(out.read_text().splitlines()))
    assert (lift["script"], rest["script"]) == ("lift", "rest")
    assert int(lift["lifted"]) >= 1 and float(lift["sum_success"]) == pytest.approx(
        5000.0 * int(lift["lifted"]) / 2)
    assert float(lift["steps"]) < 160 and float(rest["steps"]) == 160
    assert int(rest["lifted"]) == 0 and float(rest["sum_success"]) == 0
    assert float(rest["sum_contact"]) > float(lift["sum_contact"]) > 0
