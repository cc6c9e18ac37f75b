"""scripts/graspability_table.py (issue 62): the reason rules on synthetic attributes, the hand
limits measured from its model, the rows and the table it writes, a rerun that measures only
the objects without a row, and its one-line errors."""

from __future__ import annotations

import csv
import importlib.util
import json
import sys
from pathlib import Path

import pytest

from geomprep.config import Config
from tests.tiny_runs import own_data_dir
from trainer.config import load_env_config
from trainer.grasps import trials as trials_module
from trainer.grasps.keyframes import PARAMS, top_grasp_theta
from trainer.robots import sih

_PATH = Path(__file__).resolve().parents[1] / "scripts" / "graspability_table.py"
_SPEC = importlib.util.spec_from_file_location("graspability_table", _PATH)
table = importlib.util.module_from_spec(_SPEC)
sys.modules[_SPEC.name] = table  # its dataclass looks its module up there
_SPEC.loader.exec_module(table)

HAND = table.HandLimits(span_m=0.17, thumb_lever_m=0.064, torque_nm=0.75, friction=1.0)


def test_reasons_follow_the_rules() -> None:
    """Each physical limit is named when the attributes break it, all of them when several
    do; otherwise the dominant failing outcome (ties: dropped, no_grip, pushed)."""
    holdable = HAND.holdable_kg
    assert holdable == pytest.approx(2 * 0.75 / 0.064 * table.LOAD_SHARE / 9.81)
    fails = {"dropped": 2, "no_grip": 5, "pushed": 1}
    light = 0.5 * holdable
    assert table.reasons([0.18, 0.2, 0.3], light, HAND, fails) == "beyond span"
    assert table.reasons([0.05, 0.06, 0.07], 1.5 * holdable, HAND, fails) == "too heavy"
    assert table.reasons([0.008, 0.1, 0.2], light, HAND, fails) == "too thin/flat"
    assert table.reasons([0.2, 0.2, 0.3], 2 * holdable, HAND, fails) == "beyond span, too heavy"
    assert table.reasons([0.05, 0.06, 0.07], light, HAND, fails) == "no_grip"
    assert table.reasons([0.05, 0.06, 0.07], light, HAND, {"dropped": 3, "pushed": 3}) == \
        "dropped"
    assert table.reasons([0.05, 0.06, 0.07], light, HAND, {"pushed": 4}) == "pushed"
    assert table.dominant({"dropped": 0, "no_grip": 0, "pushed": 0}) == ""
    # Resting wide: the failures rested >= 0.9 of the span (153 mm of 170) and the lifts
    # narrower, or there were none; not when the lifts rested as wide (the width is not why).
    box = [0.072, 0.164, 0.214]
    assert table.reasons(box, light, HAND, fails, {"rest_width_failed_mm": 169.0,
                                                   "rest_width_lifted_mm": 82.0}) == "rests wide"
    assert table.reasons(box, light, HAND, fails, {"rest_width_failed_mm": 169.0,
                                                   "rest_width_lifted_mm": ""}) == "rests wide"
    assert table.reasons(box, light, HAND, fails, {"rest_width_failed_mm": 165.0,
                                                   "rest_width_lifted_mm": 163.0}) == "no_grip"
    assert table.reasons(box, light, HAND, fails, {"rest_width_failed_mm": 150.0,
                                                   "rest_width_lifted_mm": ""}) == "no_grip"
    assert table.reasons(box, light, HAND, fails, {}) == "no_grip"  # a row from before widths
    assert table.reasons([0.18, 0.2, 0.3], light, HAND, fails,
                         {"rest_width_failed_mm": 200.0}) == "beyond span"
    # The thin threshold is the finger links' radius it says it is.
    assert table.THIN_M == sih.FINGER_RADIUS


def test_hand_limits_are_measured_from_the_hand_model() -> None:
    """The default hand opens 16-18 cm thumb pad to finger pad, its thumb presses with its
    0.75 N·m over a 6-7 cm lever (~11-12 N: the dice's measured two-pad grips were 20-23 N),
    and a stronger servo holds proportionally more."""
    hand = table.hand_limits(load_env_config())
    assert 0.16 < hand.span_m < 0.18
    assert 0.06 < hand.thumb_lever_m < 0.07
    assert hand.torque_nm == 0.75 and hand.friction == 1.0
    assert 20 < 2 * hand.grip_n < 25
    strong = table.hand_limits(load_env_config(robot={"hand_forcerange": 1.5}))
    assert strong.span_m == pytest.approx(hand.span_m)
    assert strong.holdable_kg == pytest.approx(2 * hand.holdable_kg)


def _stub_search(calls: list[str]):  # noqa: ANN202
    """A ``find_grasps`` that returns the top grasp's parameters at once (a real search takes
    minutes per object), recording each object asked for."""

    def find_grasps(cfg, names, settings=None, echo=print):  # noqa: ANN001, ANN202, ARG001
        calls.extend(names)
        theta = dict(zip(PARAMS, top_grasp_theta().tolist(), strict=True))
        return {n: {"theta": theta, "lifted": 3, "final_trials": 4} for n in names}

    return find_grasps


def test_rows_and_table_are_written_and_a_rerun_measures_only_new_objects(
    builtin_data: Config, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
    capsys,  # noqa: ANN001
) -> None:
    """Each object's row is written with every grasp's outcome counts, the best and the
    attributes; the CSV and table.md hold every row and the summary; a rerun with one more
    object measures only that one (its search and trials), and --minutes stops before an
    object once the time is spent."""
    data_dir = own_data_dir(builtin_data, tmp_path / "data")
    out = tmp_path / "table"
    searched: list[str] = []
    measured: list[tuple[str, tuple[str, ...]]] = []
    real_measure = trials_module.measure

    def counting_measure(family, variant_name, variant, objects, *args, **kwargs):  # noqa: ANN001, ANN202
        measured.append((family, tuple(objects)))
        return real_measure(family, variant_name, variant, objects, *args, **kwargs)

    monkeypatch.setattr("trainer.grasps.search.find_grasps", _stub_search(searched))
    monkeypatch.setattr(trials_module, "measure", counting_measure)
    argv = ["--out", str(out), "--data-dir", str(data_dir), "--trials", "2", "--families",
            "top", "--set", "nthread=1"]
    table.main([*argv, "--objects", "builtin_box,builtin_sphere"])
    first = capsys.readouterr().out
    assert searched == ["builtin_box", "builtin_sphere"]
    assert measured == [("top", ("builtin_box",)), ("searched", ("builtin_box",)),
                        ("top", ("builtin_sphere",)), ("searched", ("builtin_sphere",))]
    assert "[1/2] builtin_box: top " in first and "[2/2] builtin_sphere: " in first
    row = json.loads((out / "rows" / "builtin_sphere.json").read_text())
    assert set(row["grasps"]) == {"top", "searched"}
    for counts in row["grasps"].values():
        assert counts["trials"] == 2
        assert sum(counts[o] for o in ("lifted", "dropped", "no_grip", "pushed")) == 2
    assert row["source"] == "searched now" and row["search_lifted"] == 3
    assert row["extents_mm"] == sorted(row["extents_mm"])
    assert row["extents_mm"][0] == pytest.approx(71.7, abs=0.5)
    assert row["mass_kg"] == pytest.approx(0.15, abs=0.01)
    assert row["best_rate"] == max(g["lifted"] / 2 for g in row["grasps"].values())
    assert row["lifts"] == (row["best_rate"] >= table.LIFTS)
    assert (row["reason"] == "") == row["lifts"]
    with open(out / "graspability.csv") as handle:
        lines = list(csv.DictReader(handle))
    assert [line["object"] for line in lines] == ["builtin_box", "builtin_sphere"]
    assert lines[1]["searched_lifted"] == str(row["grasps"]["searched"]["lifted"])
    md = (out / "table.md").read_text()
    assert "2 objects: the search lifts >= 60% of its trials on " in md
    assert "| builtin_sphere |" in md

    # The rerun: the two rows kept as they are, only the knife measured, the table remade.
    before = (out / "rows" / "builtin_box.json").read_bytes()
    table.main([*argv, "--objects", "builtin_box,builtin_sphere,builtin_knife"])
    second = capsys.readouterr().out
    assert "2 of 3 objects already measured" in second
    assert searched[2:] == ["builtin_knife"]
    assert [m[1] for m in measured[4:]] == [("builtin_knife",)] * 2
    assert (out / "rows" / "builtin_box.json").read_bytes() == before
    with open(out / "graspability.csv") as handle:
        assert len(list(csv.DictReader(handle))) == 3
    knife = json.loads((out / "rows" / "builtin_knife.json").read_text())
    if not knife["lifts"]:  # the built-in knife is 8 mm thin
        assert "too thin/flat" in knife["reason"]
    # Everything measured: nothing runs; with no time left, nothing begins.
    table.main([*argv, "--objects", "builtin_knife"])
    assert "0 to go" in capsys.readouterr().out and len(searched) == 3
    table.main([*argv, "--objects", "builtin_dice", "--minutes", "1e-9"])
    assert "stopped after 1e-09 minutes: 1 objects left" in capsys.readouterr().out
    assert len(searched) == 3 and not (out / "rows" / "builtin_dice.json").exists()

    # --remake measures nothing and makes each row's best and reason again from its counts:
    # the box's grasps made to fail where it rested 169 mm wide become "rests wide".
    row = json.loads((out / "rows" / "builtin_box.json").read_text())
    for counts in row["grasps"].values():
        counts.update(lifted=0, no_grip=2, dropped=0, pushed=0, rest_width_lifted_mm="",
                      rest_width_failed_mm=169.0)
    row["reason"] = "stale"
    (out / "rows" / "builtin_box.json").write_text(json.dumps(row))
    table.main([*argv, "--remake"])
    assert "3 rows made again by today's rules" in capsys.readouterr().out
    assert len(searched) == 3 and len(measured) == 6
    box = json.loads((out / "rows" / "builtin_box.json").read_text())
    assert (box["lifts"], box["best_rate"], box["reason"]) == (False, 0.0, "rests wide")
    assert "| builtin_box |" in (out / "table.md").read_text()
    assert "resting 169 mm wide" in (out / "table.md").read_text()


@pytest.mark.parametrize(("extra", "message"), [
    (["--objects", "no_such_thing"], "unknown object 'no_such_thing'"),
    (["--trials", "0"], "--trials 0: must be at least 1"),
    (["--trials", "many"], "argument --trials: invalid int value: 'many'"),
    (["--families", "searched"], "--families searched: the searched grasp is measured"),
    (["--families", "pinch:nope"], "unknown variant 'nope' of grasp family 'pinch'"),
    (["--set", "robot.no_such_key=1"], "robot.no_such_key"),
])
def test_bad_input_is_one_line(
    builtin_data: Config, tmp_path: Path, capsys, extra: list[str],  # noqa: ANN001
    message: str,
) -> None:
    """Bad input is one ``error:`` line and exit status 1, before anything is measured."""
    with pytest.raises(SystemExit) as info:
        table.main(["--out", str(tmp_path / "t"), "--data-dir", str(builtin_data.data_dir),
                    "--objects", "builtin_box", *extra])
    err = capsys.readouterr().err
    assert info.value.code == 1
    assert err.startswith("error: ") and err.count("\n") == 1 and message in err
    assert not (tmp_path / "t").exists()


def test_rows_of_other_settings_are_refused(
    builtin_data: Config, tmp_path: Path, capsys,  # noqa: ANN001
) -> None:
    """A folder whose rows were measured with other trials is refused in one line, not
    mixed into one table."""
    out = tmp_path / "t"
    (out / "rows").mkdir(parents=True)
    settings = {"trials": 5, "seed": 0, "families": ["top"], "config": "", "set": []}
    (out / "rows" / "builtin_box.json").write_text(
        json.dumps({"object": "builtin_box", "settings": settings}))
    with pytest.raises(SystemExit):
        table.main(["--out", str(out), "--data-dir", str(builtin_data.data_dir), "--objects",
                    "builtin_box", "--trials", "2", "--families", "top"])
    err = capsys.readouterr().err
    assert "holds rows measured otherwise (builtin_box: trials 5)" in err
    assert err.count("\n") == 1


def test_without_ycb_objects_the_default_set_is_one_line(
    builtin_data: Config, tmp_path: Path, capsys,  # noqa: ANN001
) -> None:
    """The default objects are the built YCB ones: a data directory without any says so."""
    with pytest.raises(SystemExit):
        table.main(["--out", str(tmp_path / "t"), "--data-dir", str(builtin_data.data_dir)])
    err = capsys.readouterr().err
    assert "the object set 'ycb' is empty" in err and err.count("\n") == 1
