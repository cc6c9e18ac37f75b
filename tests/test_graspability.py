"""bench/graspability.py: its configurations (the baseline first, measured once), its value
parsing and its one-line errors (no trial runs in these tests)."""

from __future__ import annotations

import importlib.util
from dataclasses import asdict
from pathlib import Path

import pytest

from geomgrasp.errors import UserError
from trainer.config import load_env_config

_PATH = Path(__file__).resolve().parents[1] / "bench" / "graspability.py"
_SPEC = importlib.util.spec_from_file_location("graspability", _PATH)
graspability = importlib.util.module_from_spec(_SPEC)
_SPEC.loader.exec_module(graspability)


def test_configurations_put_the_baseline_first_and_span_the_grid() -> None:
    configs = graspability.configurations(
        ["robot.hand_kp=30"], ["robot.hand_geometry=capsules,hulls", "robot.hand_forcerange=5,0.75"]
    )
    assert configs[0] == {}
    assert len(configs) == 5
    assert configs[1] == {"robot.hand_kp": 30, "robot.hand_geometry": "capsules",
                          "robot.hand_forcerange": 5}
    assert graspability.overrides(configs[4]) == {
        "robot": {"hand_kp": 30, "hand_geometry": "hulls", "hand_forcerange": 0.75}}
    default = asdict(load_env_config())
    assert graspability.is_baseline({"robot.hand_geometry": "hulls"}, default)
    assert not graspability.is_baseline({"robot.hand_geometry": "capsules"}, default)
    assert not graspability.is_baseline(configs[1], default)  # hand_kp 30 is not today's


def test_values_parse_as_toml_and_bare_words_as_strings() -> None:
    assert graspability.parse_value("0.75") == 0.75
    assert graspability.parse_value("hulls") == "hulls"
    assert graspability.parse_value("[1.0, 0.5]") == [1.0, 0.5]
    with pytest.raises(UserError, match="KEY=VALUE"):
        graspability.configurations(["robot.hand_geometry"], [])


def test_seeds_parse_and_held_trials_pool_over_them() -> None:
    assert graspability.parse_seeds("0-2,5") == [0, 1, 2, 5]
    assert graspability.parse_seeds("3,3") == [3]
    nan = float("nan")

    def trial(seed: int, held: bool, ratio: float, slip_ratio: float = 0.9) -> dict:
        return {"config": "baseline", "family": "pinch", "variant": "press6+turn",
                "object": "062_dice", "seed": seed, "held": held, "pull_ratio": ratio,
                "slip_mm_s": 0.01, "grip_n": 20.0, "slip_grip_n": 25.0,
                "slip_pull_ratio": slip_ratio}

    trials = [trial(0, True, 0.7), trial(0, True, 1.2), trial(1, True, 0.9, nan),
              trial(1, False, 3.0), trial(2, True, nan)]
    (pooled,) = graspability.pooled_holds(trials)
    # Three seeds, five probed, four held; a dropped trial's ratio and a NaN count for nothing.
    assert (pooled["seeds"], pooled["probed"], pooled["held"]) == (3, 5, 4)
    assert pooled["pull_ratio"] == 0.9 and pooled["at_target"] == 2
    assert pooled["slip_pull_ratio"] == 0.9 and pooled["grip_n"] == 20.0


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--family", "grab"], "error: unknown grasp family 'grab': choose one of top, pinch"),
        (["--family", "pinch:squeeze"], "error: unknown variant 'squeeze' of grasp family"),
        (["--objects", "999_nothing"], "error: "),
        (["--hold", "--backend", "warp"], "error: --hold probes states copied out of the cpu"),
        (["--seed", "1-x"], "error: --seed '1-x': give seeds >= 0 as 3, 0,1,2 or 0-4"),
        (["--hold-out", "trials.csv"], "error: --hold-out writes the hold probe's trials: add"),
        (["--set", "robot.hand_geometry=spheres"],
         'error: --set robot.hand_geometry=spheres: must be one of "capsules", "hulls"'),
        (["--grid", "robot.hand_forcerange=5.0,-1"],
         "error: --grid robot.hand_forcerange=-1: must be > 0"),
        (["--set", "ppo.lr=0.1"], "error: --set ppo.lr=0.1: [ppo] configures training"),
        # A key the chosen variant fixes itself would leave the configurations identical.
        (["--family", "pinch:press6+noslip", "--grid", "physics.noslip_iterations=0,5"],
         "error: physics.noslip_iterations: the family pinch:press6+noslip fixes it"),
    ],
)
def test_unknown_names_are_one_line_errors(
    args: list[str], message: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as exc:
        graspability.main(["--data-dir", str(tmp_path), *args])
    assert exc.value.code == 1
    err = capsys.readouterr().err
    assert err.startswith(message) and err.count("\n") == 1, err


def test_over_family_lets_the_configuration_replace_the_variants_own_setting(
    builtin_data, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``--over-family``: a key the variant fixes is no error, and the configuration under
    test runs the variant with its value (the baseline with the variant's own); ``--family
    best`` tries each object with its own best family only."""
    import trainer.grasps.trials as trials

    seen = []

    def record(variants, objects, trials_per_object, seeds, configs, *args, **kwargs):
        (fam, name, variant), = variants
        seen.append((fam, name, variant.env["physics"]["noslip_iterations"], tuple(objects)))
        row = {"object": objects[0], "trials": 1, "lifted": 1, "dropped": 0, "no_grip": 0,
               "pushed": 0, "upside_down": 0, "upside_down_lifted": 0}
        return iter([trials.TrialBatch(fam, name, 0, [row], 0.0, configs[0])])

    monkeypatch.setattr(trials, "run_trials", record)
    graspability.main(["--data-dir", str(builtin_data.data_dir), "--objects", "builtin_box",
                       "--family", "pinch:press6+noslip", "--over-family",
                       "--grid", "physics.noslip_iterations=5,2"])
    assert seen == [("pinch", "press6+noslip", 5, ("builtin_box",)),
                    ("pinch", "press6+noslip", 2, ("builtin_box",))]
    seen.clear()
    import trainer.grasps.families as families

    monkeypatch.setattr(families, "BEST", {"builtin_box": "pinch:press6+noslip",
                                           "builtin_cylinder": "pinch:press6+noslip",
                                           "builtin_sphere": "top"})
    graspability.main(["--data-dir", str(builtin_data.data_dir), "--objects",
                       "builtin_box,builtin_sphere,builtin_cylinder", "--family", "best",
                       "--over-family", "--set", "physics.noslip_iterations=2"])
    both = ("builtin_box", "builtin_cylinder")
    assert sorted(seen) == [("pinch", "press6+noslip", 2, both),
                            ("pinch", "press6+noslip", 5, both),
                            ("top", "base", 2, ("builtin_sphere",)),
                            ("top", "base", 5, ("builtin_sphere",))]
