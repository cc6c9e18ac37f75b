"""Scripted grasp families as package code: the registry and its one-line errors, the outcome
classification on synthetic recorded trajectories, and the one runner for every family."""

from __future__ import annotations

import csv
import dataclasses
import sys
from pathlib import Path

import pytest
import torch

import trainer.cli
from geomprep.config import Config
from trainer.errors import TrainerError
from trainer.grasps import (
    FAMILIES,
    OUTCOMES,
    GraspTrajectory,
    Pinch,
    TopGrasp,
    classify,
    family,
    family_variants,
    measure,
    outcome_rows,
    record_grasp,
    run_scripted_grasp,
)


def synthetic_trajectory() -> tuple[GraspTrajectory, int]:
    """Six trials over 10 steps, ``pushed_at`` = 4: one of each outcome, plus the edge cases
    (pushed only after ``pushed_at``: no grip; pushed and then rose: dropped)."""
    T, E, pushed_at = 10, 6, 4
    pos = torch.zeros(T, E, 3)
    pos[..., 2] = 0.05  # resting height
    steps = torch.arange(T, dtype=torch.float32)
    pos[:, 0, 2] += 0.03 * steps  # 0: rises 0.27 m, the env's success at step 7
    pos[:, 1, 2] += torch.where(steps < 5, 0.01 * steps, 0.0)  # 1: rose 4 cm, fell back
    pos[:, 2, 0] += 0.001 * steps  # 2: crept 9 mm, never rose: no grip
    pos[2:, 3, 1] += 0.03  # 3: knocked 3 cm before the grip, never rose: pushed
    pos[6:, 4, 0] += 0.05  # 4: knocked only after pushed_at: no grip
    pos[2:, 5, 0] += 0.03  # 5: knocked, then rose 2.5 cm: dropped
    pos[6:, 5, 2] += 0.025
    success = torch.zeros(T, E, dtype=torch.bool)
    success[7:, 0] = True
    pads = torch.full((T, E, 5), 0.05)
    pads[5:8, :, :2] = 0.004  # thumb and index pads low during the close (steps 5-7)
    distance = torch.full((E, 6), float("nan"))
    distance[0] = torch.tensor([0.03, 0.001, 0.0, 0.05, 0.05, 0.05])  # two pads on it: held
    start_up = torch.tensor([-1.0, 1.0, 1.0, -0.5, 1.0, 1.0])  # 0 and 3 start upside down
    width = torch.tensor([0.07, 0.16, 0.10, 0.12, 0.14, 0.15])  # m, as each rests
    return GraspTrajectory(pos, pads, success, distance, start_up, width), pushed_at


def test_classify_tells_each_outcome_from_the_trajectory() -> None:
    trajectory, pushed_at = synthetic_trajectory()
    codes = classify(trajectory, pushed_at)
    assert [OUTCOMES[c] for c in codes] == [
        "lifted", "dropped", "no_grip", "pushed", "no_grip", "dropped",
    ]
    # A rise of 2 cm is measured from the first step, not from the lowest point.
    lower = GraspTrajectory(trajectory.target_pos.clone(), trajectory.pad_height,
                            trajectory.success, trajectory.success_distance)
    lower.target_pos[0, 1, 2] -= 0.05
    assert OUTCOMES[classify(lower, pushed_at)[1]] == "dropped"
    with pytest.raises(ValueError, match="outside the 10 recorded steps"):
        classify(trajectory, 10)


def test_outcome_rows_count_per_object() -> None:
    trajectory, pushed_at = synthetic_trajectory()
    ids = torch.tensor([0, 0, 1, 1, 1, 0])
    rows = outcome_rows(["a", "b", "absent"], ids, trajectory, (5, 8), pushed_at,
                        family="top", variant="base")
    assert [r["object"] for r in rows] == ["a", "b"]  # no trial of "absent": no row
    a, b = rows
    assert (a["family"], a["variant"], a["trials"]) == ("top", "base", 3)
    assert [a[o] for o in OUTCOMES] == [1, 2, 0, 0]
    assert [b[o] for o in OUTCOMES] == [0, 0, 2, 1]
    assert a["max_rise_cm"] == 27.0 and a["median_rise_cm"] == 4.0
    assert a["thumb_pad_min_cm"] == 0.4 and a["index_pad_min_cm"] == 0.4
    assert a["held_lifts"] == 1 and a["nearest_pad_median_cm"] == 0.0
    assert b["held_lifts"] == 0 and b["nearest_pad_median_cm"] == ""
    assert (a["upside_down"], a["upside_down_lifted"]) == (1, 1)  # trial 0: lifted
    assert (b["upside_down"], b["upside_down_lifted"]) == (1, 0)  # trial 3: pushed
    # The widths the target rested with: a's lift at 70 mm, its failures at 160 and 150 mm.
    assert (a["rest_width_lifted_mm"], a["rest_width_failed_mm"]) == (70.0, 150.0)
    assert (b["rest_width_lifted_mm"], b["rest_width_failed_mm"]) == ("", 120.0)


def test_registry_and_its_one_line_errors() -> None:
    assert {"top", "pinch"} <= set(FAMILIES)
    assert family("top").variants["base"].script == TopGrasp()
    assert family("pinch").variants["base"].script == Pinch()
    noslip = family_variants("pinch", ["press6+handle+noslip"])["press6+handle+noslip"]
    assert noslip.script == Pinch(clearance=-0.006, handle=True)
    assert noslip.env == {"physics": {"noslip_iterations": 5}}
    # The top grid is results/scripted-table1/causes-grid.csv's: 108 geometries, named alike.
    grid = family_variants("top", grid=True)
    assert len(grid) == 108
    assert grid["d0.13_l-0.05_t0.4_c0.016"].script == TopGrasp(
        grasp_depth=0.13, lateral=-0.05, thumb_closed=0.4, palm_clearance=0.016
    )
    for call, text in [
        (lambda: family("palm"), "unknown grasp family 'palm': choose one of top, pinch"),
        (lambda: family_variants("pinch", ["base", "press7"]),
         "unknown variant 'press7' of grasp family 'pinch'"),
    ]:
        with pytest.raises(TrainerError) as info:
            call()
        assert str(info.value).startswith(text) and "\n" not in str(info.value)


@pytest.mark.parametrize(
    "argv, expected",
    [
        (["--family", "palm"], "error: unknown grasp family 'palm': choose one of top, pinch"),
        (["--objects", "builtin_nothing"], "error: "),
        (["--trials", "0"], "error: --trials 0: must be >= 1"),
    ],
)
def test_grasp_command_errors_are_one_line(
    argv: list[str], expected: str, builtin_data: Config, monkeypatch: pytest.MonkeyPatch,
    capsys,  # noqa: ANN001
) -> None:
    monkeypatch.setattr(sys, "argv", ["trainer", "grasp", "--data-dir",
                                      str(builtin_data.data_dir), *argv])
    with pytest.raises(SystemExit) as exit_info:
        trainer.cli.main()
    assert exit_info.value.code == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith(expected) and "\n" not in err
    if "builtin_nothing" in argv:
        assert "builtin_nothing" in err


def test_recording_does_not_change_the_run(builtin_data: Config) -> None:
    """One runner for every family: recording the trajectory changes nothing of the run (the
    same lifts as an unrecorded run of the same initial states), and a lift classifies as
    lifted, held by two pads."""
    from trainer.config import load_env_config
    from trainer.tasks import make_env

    cfg = load_env_config(num_envs=2, objects="builtin_cylinder", representation="com",
                          data_dir=builtin_data.data_dir)
    env = make_env(cfg, seed=11)
    plain = run_scripted_grasp(env, TopGrasp())
    qpos = env.backend.qpos.clone()
    env.close()
    env = make_env(cfg, seed=11)
    trajectory = record_grasp(env, TopGrasp())
    assert torch.equal(env.backend.qpos, qpos)
    env.close()
    T = TopGrasp().total_steps
    assert trajectory.target_pos.shape == (T, 2, 3) and trajectory.pad_height.shape == (T, 2, 5)
    assert torch.equal(trajectory.lifted, plain) and bool(plain.any())
    codes = classify(trajectory, TopGrasp().pushed_at)
    assert all(OUTCOMES[c] == "lifted" for c in codes[plain])
    assert not trajectory.success_distance[plain].isnan().any()
    assert torch.isnan(trajectory.success_distance[~plain]).all()
    # The scripts command absolute hand targets: a relative-action hand is refused in one line.
    relative = dataclasses.replace(
        cfg, robot=dataclasses.replace(cfg.robot, hand_action="relative")
    )
    env = make_env(relative, seed=11)
    with pytest.raises(TrainerError, match='hand_action = "absolute"'):
        run_scripted_grasp(env, TopGrasp())
    env.close()


def test_pinch_family_runs_and_writes_rows(builtin_data: Config, tmp_path: Path,
                                          monkeypatch: pytest.MonkeyPatch, capsys) -> None:  # noqa: ANN001
    """``trainer grasp --family pinch``: the pinch plans from the model's hand kinematics, runs
    in the same runner and classifies every trial once; the CSV has a row per object."""
    out = tmp_path / "pinch.csv"
    monkeypatch.setattr(sys, "argv", [
        "trainer", "grasp", "--family", "pinch", "--objects", "builtin_dice,builtin_box",
        "--trials", "2", "--data-dir", str(builtin_data.data_dir), "--out", str(out),
    ])
    trainer.cli.main()
    printed = capsys.readouterr().out
    assert "### pinch base (" in printed and "| builtin_dice |" in printed
    rows = list(csv.DictReader(out.read_text().splitlines()))
    assert [r["object"] for r in rows] == ["builtin_dice", "builtin_box"]
    for row in rows:
        assert row["family"] == "pinch" and row["variant"] == "base" and row["trials"] == "2"
        assert sum(int(row[o]) for o in OUTCOMES) == 2
    # The same trials again (seed 0): the same outcomes, from the function the command calls.
    again = measure("pinch", "base", family("pinch").variants["base"],
                    ["builtin_dice", "builtin_box"], 2, data_dir=builtin_data.data_dir)
    assert [[r[o] for o in OUTCOMES] for r in again] == [
        [int(r[o]) for o in OUTCOMES] for r in rows
    ]


def test_turned_pinch_rolls_the_lifted_hand_about_the_squeeze(builtin_data: Config) -> None:
    """``pinch:press6+turn``: after the lift the commanded palm turns -90 degrees about the
    world's horizontal squeeze direction (the hand is the same pinch until then), within its
    extra ``turn_steps`` actions."""
    import math

    from tensordict import TensorDict

    from geomgrasp.rotations import matrix_to_axis_angle
    from trainer.config import load_env_config
    from trainer.grasps.runner import episode_config
    from trainer.tasks import make_env

    script = family("pinch").variants["press6+turn"].script
    plain = dataclasses.replace(script, turn=0.0, turn_steps=0)
    assert script.total_steps == plain.total_steps + script.turn_steps > plain.total_steps
    cfg = load_env_config(num_envs=2, objects="builtin_dice", representation="com",
                          data_dir=builtin_data.data_dir)
    env = make_env(episode_config(cfg, script), seed=3)
    env.reset()
    plan: dict = {}
    lift_end = script.total_steps - script.turn_steps - script.hold_steps
    for step in range(script.total_steps):
        if step == lift_end:  # lifted, not yet turned: the plain pinch's orientation
            before = env.state["target_rot"].clone()
            assert torch.allclose(before, plan["rot"], atol=1e-4)
        action = script.action(env, step, plan)
        env.step(TensorDict({"action": action}, batch_size=env.batch_size))
    after = env.state["target_rot"]
    env.close()
    assert torch.allclose(after, plan["rot_turned"], atol=1e-4)
    turn = matrix_to_axis_angle(after @ before.transpose(1, 2))  # (E, 3) world axis x angle
    angle = turn.norm(dim=-1)
    assert torch.allclose(angle, torch.full_like(angle, math.pi / 2), atol=1e-3)
    axis = turn / angle[:, None]
    assert axis[:, 2].abs().max() < 1e-3  # a horizontal axis: the squeeze direction


def test_hold_probe_measures_a_held_grasp_and_a_free_fall(builtin_data: Config) -> None:
    """``measure(..., hold=True)``: a top grasp still lifted at its end is probed: it slips
    slowly, the hand presses on it, and a growing downward pull makes it slip before the pull's
    cap, at a load of the order of what friction times the grip allows. A target in free fall
    (no contact) has no grip and no capacity, so its pull ratio is NaN."""
    import math

    import mujoco

    from trainer.grasps.hold import MAX_PULL, measure_hold

    rows = measure("top", "base", family("top").variants["base"], ["builtin_cylinder"], 2,
                   data_dir=builtin_data.data_dir, hold=True, robot={"hand_forcerange": 0.75,
                                                                    "hand_joint_damping": 0.1})
    (row,) = rows
    assert row["held_end"] >= 1
    assert 0 <= row["slip_mm_s"] < 20 and row["grip_n"] > 1
    assert 0.05 < row["pull_ratio"] < 3
    assert row["slip_grip_n"] > 0 and 0.05 < row["slip_pull_ratio"] < 3
    assert 0 < row["slip_cone_min"] <= row["slip_cone_max"] <= 1.01
    model = mujoco.MjModel.from_xml_string(
        '<mujoco><worldbody><body name="palm"/><body name="ball" pos="0 0 1"><freejoint/>'
        '<geom size="0.02" mass="0.1"/></body></worldbody></mujoco>')
    data = mujoco.MjData(model)
    free = measure_hold(model, data, model.body("ball").id)
    assert not free.held and free.grip_n == 0 and free.capacity_n == 0
    assert math.isnan(free.pull_ratio) and math.isnan(free.slip_pull_ratio)
    assert math.isnan(free.slip_cone_min) and math.isnan(free.slip_cone_max)
    assert free.slip_mm_s > 1000 and free.pull_n < MAX_PULL
    assert free.weight_n == pytest.approx(0.1 * 9.81)
    # A ball resting on a hand geom: its support is the contact's normal force, its weight,
    # whichever geom MuJoCo lists first; pressed into the geom it moves only by penetration.
    palm = ('<body name="palm"><geom type="box" size="0.1 0.1 0.01" contype="8" '
            'conaffinity="2"/></body>')
    ball = ('<body name="ball" pos="0 0 0.03"><freejoint/><geom size="0.02" mass="0.1" '
            'contype="2" conaffinity="8"/></body>')
    for bodies in (palm + ball, ball + palm):
        model = mujoco.MjModel.from_xml_string(f"<mujoco><worldbody>{bodies}</worldbody></mujoco>")
        rest = measure_hold(model, mujoco.MjData(model), model.body("ball").id)
        assert rest.held and rest.slip_mm_s < 0.01
        assert rest.capacity_n == pytest.approx(0.1 * 9.81, rel=0.01)
        assert rest.pull_ratio > 5
        # Pressed down by the pull (until the soft contact let it sink 5 mm), the contact's
        # force, so its capacity, grew with the load.
        assert rest.slip_capacity_n == pytest.approx(0.1 * 9.81 + rest.pull_n, rel=0.05)
        assert rest.slip_capacity_n > 10 * rest.capacity_n
        assert rest.slip_cone_max < 0.01  # pressed straight down: no friction used
        assert rest.slip_pull_ratio == pytest.approx(1.0, rel=0.05)


def test_demo_runs_a_named_family_variant(builtin_data: Config, monkeypatch: pytest.MonkeyPatch,
                                          capsys) -> None:  # noqa: ANN001
    """``trainer demo --family pinch:noslip`` runs the pinch with its variant's physics (the
    no-slip solver) and prints one line per object; an unknown family is a one-line error."""
    monkeypatch.setattr(sys, "argv", [
        "trainer", "demo", "--family", "pinch:noslip", "--objects", "builtin_dice",
        "--trials", "1", "--video", "", "--data-dir", str(builtin_data.data_dir),
    ])
    trainer.cli.main()
    assert "builtin_dice  lifted " in capsys.readouterr().out
    monkeypatch.setattr(sys, "argv", ["trainer", "demo", "--family", "palm", "--data-dir",
                                      str(builtin_data.data_dir)])
    with pytest.raises(SystemExit) as exit_info:
        trainer.cli.main()
    assert exit_info.value.code == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: unknown grasp family 'palm'") and "\n" not in err


def test_slide_grasp_comes_palm_up_from_the_robots_side(builtin_data: Config) -> None:
    """The slide grasp's plan: the palm faces up (tilted toward the target by ``pitch``), the
    fingers point from the robot's base toward the target (horizontally) and down by ``pitch``,
    and the palm keypoint starts ``start`` short of the target's centre at ``height``."""
    import math

    from trainer.config import load_env_config
    from trainer.grasps.geometry import target_box
    from trainer.grasps.slide import SlideGrasp
    from trainer.tasks import make_env

    cfg = load_env_config(num_envs=3, objects="builtin_box", representation="com",
                          data_dir=builtin_data.data_dir)
    env = make_env(cfg, seed=2)
    env.reset()
    script = SlideGrasp()
    plan = script.plan(env)
    center = target_box(env)[0]
    env.close()
    rot = plan["rot"]
    torch.testing.assert_close(rot.transpose(1, 2) @ rot, torch.eye(3).expand(3, 3, 3),
                               atol=1e-5, rtol=0)
    assert torch.allclose(torch.linalg.det(rot), torch.ones(3), atol=1e-5)
    palmar, fingers = rot[..., 1], rot[..., 2]
    assert torch.allclose(palmar[:, 2], torch.full((3,), math.cos(script.pitch)), atol=1e-5)
    assert torch.allclose(fingers[:, 2], torch.full((3,), -math.sin(script.pitch)), atol=1e-5)
    away = center[:, :2] - torch.tensor(cfg.robot.base_pos[:2])
    away = away / away.norm(dim=-1, keepdim=True)
    torch.testing.assert_close(fingers[:, :2] / fingers[:, :2].norm(dim=-1, keepdim=True), away)
    torch.testing.assert_close(plan["inward"][:, :2], away)
    torch.testing.assert_close((center - plan["start"])[:, :2].norm(dim=-1),
                               torch.full((3,), script.start))
    assert torch.allclose(plan["start"][:, 2], torch.full((3,), script.height))


@pytest.mark.slow
def test_slide_grasp_tips_the_plate(ycb_data: Config) -> None:
    """The slide family's measured behaviour on the plate (results/graspability-plate-
    2026-11-26: no lift; the curl tips it, its centre rising 2-5 cm): over 10 trials, no lift,
    and most trials raise the plate >= 2 cm (``dropped``) before it falls back."""
    rows = measure("slide", "base", family("slide").variants["base"], ["029_plate"], 10,
                   data_dir=ycb_data.data_dir)
    (row,) = rows
    assert row["lifted"] == 0
    assert row["dropped"] >= 5


@pytest.mark.slow
def test_rim_pinch_lifts_the_upright_plate(ycb_data: Config) -> None:
    """``pinch:rim`` (results/graspability-plate-rim-2026-11-26: every upright plate of 50
    lifted, no upside-down one): over 10 trials, every trial that starts upright is lifted and
    held by two pads, at most one missed; the plain pinch (its pads at table height) lifts
    fewer."""
    (rim,) = measure("pinch", "rim", family("pinch").variants["rim"], ["029_plate"], 10,
                     data_dir=ycb_data.data_dir)
    upright = rim["trials"] - rim["upside_down"]
    assert upright >= 5  # the seed's initial states: most plates land face up
    assert rim["lifted"] - rim["upside_down_lifted"] >= upright - 1
    assert rim["held_lifts"] == rim["lifted"]
    (plain,) = measure("pinch", "base", family("pinch").variants["base"], ["029_plate"], 10,
                       data_dir=ycb_data.data_dir)
    assert plain["lifted"] < rim["lifted"]
