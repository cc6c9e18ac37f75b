"""bench/reward_balance.py: discounting, and lift vs rest rollouts on a built-in object (the
lift's episode ends at its success with the bonus; the rest runs to max_steps without it)."""

from __future__ import annotations

import csv
import importlib.util
import re
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
    # The scripts command absolute hand targets, so a config with relative hand actions is
    # measured with the very same rollouts (the reward does not depend on the action mode).
    relative = tmp_path / "relative.csv"
    reward_balance.main(["--objects", "builtin_cylinder", "--trials", "2", "--max-steps", "160",
                         "--set", "robot.hand_action=relative",
                         "--data-dir", str(builtin_data.data_dir), "--out", str(relative)])
    assert relative.read_text() == out.read_text()


def test_family_picks_the_script_and_its_rest_runs_to_the_end(
        builtin_data: Config, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``--family pinch:press6``: the fingertip pinch (closed after 130 actions) and its rest;
    the episode's lift target as ``--set`` gives it; an episode shorter than the script's lift
    (190 actions) is said to cut it short."""
    out = tmp_path / "pinch.csv"
    reward_balance.main(["--objects", "builtin_box", "--trials", "1", "--max-steps", "140",
                         "--family", "pinch:press6", "--set", "reward.h_bar=0.03",
                         "--set", "reward.h_bar_start=0.03",
                         "--data-dir", str(builtin_data.data_dir), "--out", str(out)])
    lift, rest = list(csv.DictReader(out.read_text().splitlines()))
    assert float(lift["steps"]) <= 140 and float(rest["steps"]) == 140
    assert int(rest["lifted"]) == 0 and float(rest["sum_success"]) == 0
    assert float(rest["sum_contact"]) > 0
    printed = capsys.readouterr()
    assert "lifts until action 190; episodes of 140 actions cut its lift short" in printed.err
    # The ratio to the baseline measured in the same run: rest over lift, per gamma.
    lines = printed.out.splitlines()
    assert lines[-2].startswith("rest / lift, mean discounted return")
    assert re.fullmatch(r"builtin_box: γ 0\.99: -?[0-9.]+x, γ 0\.998: -?[0-9.]+x", lines[-1])


@pytest.mark.parametrize(("family", "message"), [
    ("grip", "unknown grasp family 'grip'"),
    ("pinch:tight", "unknown variant 'tight' of grasp family 'pinch'"),
])
def test_unknown_family_or_variant_is_a_one_line_error(
        family: str, message: str, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_info:
        reward_balance.main(["--family", family, "--objects", "builtin_box"])
    assert exit_info.value.code == 1
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1


def test_a_script_longer_than_the_episode_is_refused(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        reward_balance.main(["--family", "pinch:press6", "--max-steps", "100",
                             "--objects", "no_such_object"])  # refused before any object
    assert "closes only after 130 actions" in capsys.readouterr().err
