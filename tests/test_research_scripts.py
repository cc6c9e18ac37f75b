"""Research scripts: scripts/home_heights.py (the per-object home heights of ``[robot]
home_above_objects``), scripts/early_lifts.py (what the initial policy's low lifts are),
scripts/policy_probe.py (what a trained policy does over an episode) and
scripts/object_curriculum.py (each object's curriculum target over a run),
scripts/start_noise.py (how much exploration noise grasp starts survive),
scripts/start_vs_home.py (an object's success from home, its grasp starts, the closed grasp),
scripts/observed_size.py (an object's success when the policy is told another size),
scripts/episode_outcomes.py (how each evaluation episode ends), scripts/metrics_blocks.py (a
training curve in blocks of env steps), scripts/eval_upright.py (an evaluation split by how
the targets start), scripts/grasp_offset.py (where a policy holds each object) and
scripts/bin_diagnosis.py (each target's best scripted grasp in clutter, and why it fails),
scripts/video_frames.py (a video's contact sheet), scripts/paired_evals.py (two evaluations
of the same episodes compared), scripts/budget_gains.py (each run extended to a larger budget
against itself at the budget), scripts/run_status.py (where each run stands) and
scripts/object_correlation.py (which objects succeed together across runs)."""

from __future__ import annotations

from pathlib import Path

import pytest

from geomprep.config import Config
from tests.tiny_runs import script, tiny_dice_mug_run, tiny_grasp_start_config, tiny_run
from trainer.training.run_dir import RunDir


def test_home_heights_lists_each_object(builtin_data: Config) -> None:
    home_heights = script("scripts", "home_heights")
    lines = home_heights.main(["builtin_dice,builtin_cylinder", str(builtin_data.data_dir)])
    rows = {line.split(" | ")[0]: line.split(" | ") for line in lines[2:]}
    assert rows["builtin_dice"][1] == "0"  # a lying dice never reaches the hand at 0.14 m
    assert int(rows["builtin_cylinder"][1]) > 0  # a standing cylinder does: raised
    low, _, high = (float(x) for x in rows["builtin_cylinder"][2].split(" / "))
    assert low >= 0.14 and high > 0.14


def test_tilt_between_orientations() -> None:
    """scripts/early_lifts.py measures how far an object turned: a quarter turn about any axis
    is 90 degrees, no turn 0."""
    import math

    import torch

    tilt_degrees = script("scripts", "early_lifts").tilt_degrees

    half = math.sqrt(0.5)
    before = torch.tensor([[1.0, 0, 0, 0], [1.0, 0, 0, 0], [half, 0, half, 0]])
    after = torch.tensor([[half, half, 0, 0], [1.0, 0, 0, 0], [half, 0, half, 0]])
    torch.testing.assert_close(tilt_degrees(before, after), torch.tensor([90.0, 0.0, 0.0]),
                               atol=1e-3, rtol=0)



def test_early_lifts_runs_the_initial_policy(
    builtin_data: Config, capsys: pytest.CaptureFixture[str]
) -> None:
    """scripts/early_lifts.py: the untrained policy's held successes (none in a few steps on the
    dice), counted over every env and step."""
    early_lifts = script("scripts", "early_lifts")

    events = early_lifts.early_lifts("builtin_dice", str(builtin_data.data_dir), envs=4,
                                     steps=8, h_bar=0.03)
    assert all(0 <= step < 8 and tilt >= 0 for step, tilt, _ in events)
    early_lifts.main(["builtin_dice", str(builtin_data.data_dir), "--envs", "4", "--steps", "8"])
    assert capsys.readouterr().out.startswith(
        f"held successes at 0.03 m (lift_clearance 0 m) in 8 steps x 4 envs: {len(events)}")


@pytest.fixture(scope="module")
def box_run(builtin_data: Config, tmp_path_factory: pytest.TempPathFactory) -> RunDir:
    """One PPO iteration on the built-in box (4 envs, 12-action episodes): a run directory
    with a checkpoint, for the scripts that read one."""
    return tiny_run(builtin_data, tmp_path_factory.mktemp("box") / "run", "builtin_box")


def test_policy_probe_follows_an_episode(box_run: RunDir) -> None:
    """scripts/policy_probe.py on a tiny trained run: one row per action of a whole episode,
    the target starting on the table (no rise at the first action), the hand's 5 servo targets
    in each row, and the printed table's rows every ``--every`` actions plus the last."""
    policy_probe = script("scripts", "policy_probe")

    run = box_run
    rows, success, earned = policy_probe.probe(run.path, envs=3, h_bar=0.05, gammas=(0.9, 1.0))
    assert len(rows) == 12 and 0.0 <= success <= 1.0
    # the discounted return weighs later rewards less; with gamma 1 it is the plain sum, the
    # sum of the terms (the sdf reward's lift, success and contact terms)
    assert earned["G_0.9"] < earned["G_1.0"] == pytest.approx(earned["return"], rel=1e-6)
    assert earned["return"] == pytest.approx(
        earned["sum_lift"] + earned["sum_success"] + earned["sum_contact"], rel=1e-4)
    assert earned["steps"] <= 12
    assert abs(rows[0]["centre_rise"]) < 0.01 and abs(rows[0]["lowest_rise"]) < 0.01
    assert all(len(row["hand"]) == 5 and row["palm_z"] > 0.0 for row in rows)
    # the std columns: the policy's own (state-independent here: the same in every row)
    from trainer.training.checkpoint import load_agent

    std = load_agent(run.path)[1].policy_net.log_std.detach().exp()
    assert all(row["std_pose"] == pytest.approx(float(std[:6].mean()), rel=1e-5)
               and row["std_hand"] == pytest.approx(float(std[6:].mean()), rel=1e-5)
               for row in rows)
    lines = policy_probe.main([str(run.path), "--envs", "3", "--every", "5"])
    assert lines[1].startswith("action palm_z") and len(lines) == 2 + 3 + 1 + 1  # 0, 5, 10, 11
    assert lines[-1].startswith("earned") and "G_0.998" in lines[-1]


def test_training_with_grasp_starts_and_probing_them(
    builtin_data: Config, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A run with ``[run] grasp_starts`` (the top grasp on the built-in cylinder, which it
    lifts in most trials) trains and logs like any other, and keeps the recorded states, which
    a resume loads instead of recording them again; ``policy_probe --grasp-starts`` averages
    over the envs whose scripted grasp lifted and says how many there were."""
    import dataclasses

    import torch

    import trainer.ppo
    from trainer.ppo import train
    from trainer.tasks.starts import GraspStarts

    policy_probe = script("scripts", "policy_probe")

    cfg = tiny_grasp_start_config(builtin_data, checkpoint_every=1)
    run = train(cfg, tmp_path / "run", progress=False)
    assert len(run.metrics.read_text().splitlines()) == 2  # the header and one iteration
    recorded = GraspStarts.load(run.grasp_starts)
    assert recorded.valid.shape[0] == 4 and bool(recorded.valid.any())

    def record_again(*args: object, **kwargs: object) -> None:
        raise AssertionError("a resume recorded the grasp starts again")

    monkeypatch.setattr(trainer.ppo, "record_grasp_starts", record_again)
    longer = dataclasses.replace(cfg, run=dataclasses.replace(cfg.run, total_steps=64))
    train(longer, run.path, resume=True, progress=False)
    assert len(run.metrics.read_text().splitlines()) == 3
    torch.testing.assert_close(GraspStarts.load(run.grasp_starts).qpos, recorded.qpos)
    rows, success, earned = policy_probe.probe(run.path, envs=4, h_bar=0.05, grasp_starts=True)
    assert 1 <= earned["envs"] <= 4 and 0.0 <= success <= 1.0 and len(rows) >= 1
    lines = policy_probe.main([str(run.path), "--envs", "4", "--h-bar", "0.05", "--grasp-starts"])
    assert f"{earned['envs']:.0f} of 4 envs from grasp starts" in lines[0]


def test_object_curriculum_reads_each_kept_checkpoint(builtin_data: Config, tmp_path: Path) -> None:
    """scripts/object_curriculum.py: one row per kept checkpoint (every iteration here), each
    object's target within the curriculum's range and its held rate a fraction; ``--final``
    sets the last target beside the evaluation and groups the pairs by where their target
    ended; ``--left`` says from the run's curriculum.csv when each target left the first rung
    (a float32 first rung is still the first rung); a run without a per-object curriculum is
    a one-line error."""
    import json

    from trainer.config import config_dict, load_train_config
    from trainer.ppo import train

    object_curriculum = script("scripts", "object_curriculum")

    cfg = load_train_config(
        env={"num_envs": 4, "objects": "builtin_box,builtin_dice", "representation": "bbox",
             "data_dir": builtin_data.data_dir, "max_steps": 6, "compile": False,
             "reward": {"h_bar_start": 0.03, "h_bar_increment": 0.02,
                        "curriculum_per_object": True}},
        ppo={"frames_per_env": 6, "minibatches": 2, "min_minibatch": 1, "epochs": 1,
             "hidden": (16, 16)},
        run={"total_steps": 72, "checkpoint_every": 1, "seed": 0},
    )
    run = train(cfg, tmp_path / "run", progress=False)
    rows = object_curriculum.main([str(run.path), "--csv", str(tmp_path / "c.csv")])
    assert [r["iteration"] for r in rows] == [1, 2, 3]
    assert rows[-1]["env_steps"] == 72
    for row in rows:
        for name in ("builtin_box", "builtin_dice"):
            assert 0.03 <= row[name] <= 0.2
            held = row[f"{name}_held"]
            assert held != held or 0.0 <= held <= 1.0  # nan before the object's first episode
    assert (tmp_path / "c.csv").read_text().startswith("iteration,env_steps,minutes,builtin_box,")
    assert (tmp_path / "c.png").stat().st_size > 1000

    # --final: the last targets beside the evaluation, grouped by where they ended.
    (run.path / "eval").mkdir()
    (run.path / "eval" / "per_object.csv").write_text(
        "object,episodes,successes,success_rate\nbuiltin_box,50,40,0.8\nbuiltin_dice,50,3,0.06\n")
    lines = object_curriculum.main([str(run.path), "--final", "--objects", "builtin_dice"])
    assert lines[2] == f"| run | builtin_dice | {rows[-1]['builtin_dice']:.2f} | " \
        f"{rows[-1]['builtin_dice_held']:.2f} | 3/50 |" and len(lines) == 3 + 3 + 1
    with pytest.raises(SystemExit, match="no object 'builtin_mug'"):
        object_curriculum.main([str(run.path), "--final", "--objects", "builtin_mug"])
    with pytest.raises(SystemExit):
        object_curriculum.main([str(run.path), str(run.path)])  # several runs need --final
    pairs = [{"target": target, "start": 0.03, "h_bar": 0.2, "successes": held, "episodes": 50,
              "held": 0.5, "run": run.path, "object": "o"}
             for target, held in ((0.03, 2), (0.0300001, 4), (0.03, None), (0.05, 15),
                                  (0.199, 30), (0.2, 12), (0.2, 43))]
    assert [object_curriculum.rung(p) for p in pairs] == [
        "first rung", "first rung", "first rung", "between", "at h_bar", "at h_bar", "at h_bar"]
    summary = object_curriculum.final_table(pairs)[-3:]
    assert summary == ["| first rung | 2 | 3 (2-4) |", "| between | 1 | 15 (15-15) |",
                       "| at h_bar | 3 | 30 (12-43) |"]

    # --left: when each object's target left the first rung, from the run's curriculum.csv.
    with pytest.raises(SystemExit, match="no curriculum.csv in .*run: write it"):
        object_curriculum.main([str(run.path), "--left"])
    history = ("iteration,env_steps,minutes,builtin_box,builtin_box_held,builtin_dice,"
               "builtin_dice_held\n10,100,1,0.03,0.5,0.03,0.1\n20,200,2,0.0300001,0.7,0.03,0.1\n"
               "30,300,3,0.05,0.2,0.03,0.2\n40,400,4,0.07,0.3,0.03,0.1\n")
    (run.path / "curriculum.csv").write_text(history)
    lines = object_curriculum.main([str(run.path), "--left"])
    # a float32 0.03 is still the first rung; the box left at 300 env steps, the dice never
    assert lines[2:4] == ["| run | builtin_box | 0.00 | — | 0.07 | 40/50 |",
                          "| run | builtin_dice | not by 0.00 | — | 0.03 | 3/50 |"]
    assert lines[7:9] == ["| builtin_box | 1 of 1 | 0.00 (0.00-0.00) | 0 |",
                          "| builtin_dice | 0 of 1 | — | 0 |"]
    assert lines[-2:] == ["| 0-2.5 | 1 | 40 (40-40) |", "| not at all | 1 | 3 (3-3) |"]
    with pytest.raises(SystemExit):
        object_curriculum.main([str(run.path), "--left", "--edges", "3.5,2.5"])  # not rising
    left = object_curriculum.left_rows([run.path])
    assert [(r["object"], r["left"], r["top"], r["target"], r["successes"]) for r in left] == [
        ("builtin_box", 300.0, None, 0.07, 40), ("builtin_dice", None, None, 0.03, 3)]
    (run.path / "curriculum.csv").write_text(history + "50,500,5,0.2,0.5,0.03,0.1\n")
    assert object_curriculum.left_rows([run.path])[0]["top"] == 500.0  # at the task's h_bar
    summary = object_curriculum.left_table([
        {"run": run.path, "object": "o", "left": 2.0e6, "top": 3.0e6, "first": 0.1e6,
         "last": 4.6e6, "target": 0.2, "successes": 30, "episodes": 50},
        {"run": run.path, "object": "o", "left": 0.5e6, "top": 1.0e6, "first": 0.5e6,
         "last": 4.6e6, "target": 0.2, "successes": 40, "episodes": 50},  # off at its first row
        {"run": run.path, "object": "o", "left": 3.5e6, "top": None, "first": 0.1e6,
         "last": 4.6e6, "target": 0.1, "successes": 10, "episodes": 50},
        {"run": run.path, "object": "o", "left": None, "top": None, "first": 0.1e6,
         "last": 4.6e6, "target": 0.03, "successes": None, "episodes": None}])
    assert summary[3] == "| run | o | by 0.50 | 1.00 | 0.20 | 40/50 |"
    assert summary[5] == "| run | o | not by 4.60 | — | 0.03 | — |"
    assert summary[9] == "| o | 3 of 4 | 2.00 (0.50-3.50) | 2 |"
    # by when they left: 3.5 falls after the last edge; the pair not evaluated is left out
    assert summary[-2:] == ["| 0-2.5 | 2 | 35 (30-40) |", "| after 3.5 | 1 | 10 (10-10) |"]
    with pytest.raises(SystemExit, match="no object 'builtin_mug'"):
        object_curriculum.main([str(run.path), "--left", "--objects", "builtin_mug"])
    (run.path / "curriculum.csv").write_text(history + "60,600,6,high,0.5,0.03,0.1\n")
    with pytest.raises(SystemExit, match="curriculum.csv: unreadable"):
        object_curriculum.main([str(run.path), "--left"])

    plain = tmp_path / "plain"
    plain.mkdir()
    (plain / "config.json").write_text(json.dumps(config_dict(load_train_config())))
    with pytest.raises(SystemExit, match="not a per-object curriculum run"):
        object_curriculum.main([str(plain)])


def test_start_noise_replays_the_same_starts_per_setting(
    builtin_data: Config, tmp_path: Path
) -> None:
    """scripts/start_noise.py on a tiny run with grasp starts: one row per noise setting over
    the envs that start along a grasp; the noise-free setting is deterministic (the same starts
    and draws each time), and a run without recorded starts is a one-line error."""

    from trainer.config import load_train_config
    from trainer.ppo import train

    start_noise = script("scripts", "start_noise")

    cfg = load_train_config(
        env={"num_envs": 4, "objects": "builtin_cylinder", "representation": "bbox",
             "data_dir": builtin_data.data_dir, "max_steps": 12,
             "robot": {"home_above_objects": True, "hand_action": "relative"}},
        ppo={"frames_per_env": 8, "minibatches": 2, "min_minibatch": 1, "epochs": 1,
             "hidden": (16, 16)},
        run={"total_steps": 32, "seed": 0, "grasp_starts": 0.5, "grasp_start_family": "top",
             "grasp_start_rounds": 1},
    )
    run = train(cfg, tmp_path / "run", progress=False)
    quiet, noisy = start_noise.parse_sigma("0/0"), start_noise.parse_sigma("0.6/0.05")
    assert noisy.tolist() == pytest.approx([0.6] * 6 + [0.05] * 5)
    envs, rows = start_noise.survive(run.path, [quiet, noisy, quiet], hold=2, h_bar=0.01)
    assert 1 <= envs <= 4 and len(rows) == 3
    assert rows[0] == rows[2]
    assert all(0.0 <= r["success"] <= r["rose"] + 1e-9 <= 1.0 + 1e-9 for r in rows)
    lines = start_noise.main([str(run.path), "--sigma", "0/0", "--sigma", "0.6/0.6",
                              "--hold", "2"])
    assert lines[0].startswith(f"{envs} envs from grasp starts") and len(lines) == 4
    with pytest.raises(SystemExit, match="--sigma 1/2/3: write POSE/HAND"):
        start_noise.parse_sigma("1/2/3")
    (run.path / "grasp_starts.pt").unlink()
    with pytest.raises(SystemExit, match="has no grasp_starts.pt"):
        start_noise.survive(run.path, [quiet])


def test_start_vs_home_counts_each_kind_of_episode(builtin_data: Config, tmp_path: Path) -> None:
    """scripts/start_vs_home.py on a tiny run with grasp starts: every env plays each round from
    home, only the envs with a recorded start below the target play from starts and from the
    closed grasp (each env's last such start, and only it); the same seed
    gives the same counts; a run without recorded starts is a one-line error."""
    import torch

    from trainer.ppo import train
    from trainer.tasks.starts import GraspStarts

    start_vs_home = script("scripts", "start_vs_home")
    run = train(tiny_grasp_start_config(builtin_data), tmp_path / "run", progress=False)
    starts = GraspStarts.load(run.grasp_starts)
    h_bar = 0.03
    with_start = int((starts.valid & (starts.lift < h_bar)).any(1).sum())
    assert with_start >= 1
    # the closed grasp: each env's last usable capture, and only that one
    closed = start_vs_home.closed_starts(starts, torch.full((4,), h_bar)).valid
    usable = starts.valid & (starts.lift < h_bar)
    for env in range(4):
        picked = closed[env].nonzero().flatten().tolist()
        assert picked == ([usable[env].nonzero().max().item()] if usable[env].any() else [])
    table = start_vs_home.start_vs_home(run.path, h_bar=h_bar, rounds=2)
    assert list(table["builtin_cylinder"]) == ["home", "starts", "closed"]
    (home_s, home_n), (start_s, start_n), (closed_s, closed_n) = (
        table["builtin_cylinder"].values())
    assert home_n == 2 * 4 and start_n == closed_n == 2 * with_start
    assert 0 <= home_s <= home_n and 0 <= start_s <= start_n and 0 <= closed_s <= closed_n
    assert start_vs_home.start_vs_home(run.path, h_bar=h_bar, rounds=2) == table
    lines = start_vs_home.main([str(run.path), "--rounds", "1"])
    assert lines[-1].startswith("| run | builtin_cylinder | ") and "/4 (" in lines[-1]
    (run.path / "grasp_starts.pt").unlink()
    with pytest.raises(SystemExit, match="has no grasp_starts.pt"):
        start_vs_home.start_vs_home(run.path)


def test_episode_outcomes_puts_each_episode_in_one_class(box_run: RunDir) -> None:
    """scripts/episode_outcomes.py: the classes from the centre rise (a success whatever its
    rise; never up 1 cm; up then 3 cm below the peak at the end; up and staying), and on a tiny
    trained run one line per env whose counts add up to the envs."""
    import torch

    eo = script("scripts", "episode_outcomes")

    up_and_down = torch.tensor([0.0, 0.05, 0.10, 0.04])
    assert eo.classify(up_and_down, True, 0.01, 0.03) == "success"
    assert eo.classify(torch.tensor([0.0, 0.004, 0.002]), False, 0.01, 0.03) == "never lifted"
    assert eo.classify(up_and_down, False, 0.01, 0.03) == "dropped"
    assert eo.classify(torch.tensor([0.0, 0.05, 0.04]), False, 0.01, 0.03) == "stalled"

    run = box_run
    episodes = eo.outcomes(run.path, envs=3, h_bar=0.05)
    assert len(episodes) == 3
    for ep in episodes:
        assert ep.outcome in eo.CLASSES and 1 <= ep.length <= 12
        assert 0 <= ep.peak_action < ep.length and ep.peak_rise >= ep.end_rise
        assert len(ep.hand_at_peak) == len(ep.hand_after) == 5
    lines = eo.main([str(run.path), "--envs", "3", "--h-bar", "0.05"])
    counts = [int(part.rsplit(" ", 1)[1]) for part in lines[0].split(" (of")[0].split(" | ")]
    assert sum(counts) == 3 and len(lines) == 2 + 3


def test_metrics_blocks_weights_rates_by_episodes(tmp_path: Path) -> None:
    """A block's held rate is over the episodes that ended in it, not a mean of iterations: an
    iteration with 30 episodes at 0.5 and one with 10 at 0.1 make 0.4, not 0.3; the next block
    starts after 250,000 env steps, and unstable resets add up."""
    metrics_blocks = script("scripts", "metrics_blocks")

    header = ("iteration,env_steps,wall_time_s,episodes,target_success_rate,object_success_rate,"
              "episode_return,h_bar,action_std,unstable_resets")
    rows = ["1,125000,60,30,0.5,0.0,100,0.03,0.6,1",
            "2,250000,120,10,0.1,0.0,200,0.05,0.4,2",
            "3,375000,240,0,nan,nan,nan,0.07,0.3,0"]
    (tmp_path / "metrics.csv").write_text("\n".join([header, *rows]) + "\n")
    first, second = metrics_blocks.blocks(metrics_blocks.read_rows(tmp_path), 250_000)
    assert first["target_success_rate"] == pytest.approx(0.4)
    assert first["episode_return"] == pytest.approx(125.0)
    assert first["h_bar"] == pytest.approx(0.04) and first["unstable_resets"] == 3
    assert first["minutes"] == pytest.approx(2.0)
    assert second["start"] == 250_000 and second["minutes"] == pytest.approx(4.0)
    assert second["target_success_rate"] != second["target_success_rate"]  # no episode: nan
    lines = metrics_blocks.main([str(tmp_path / "metrics.csv")])
    assert lines[4].startswith("| 0.00-0.25 M | 0.400 |") and len(lines) == 7
    with pytest.raises(SystemExit, match="no metrics.csv"):
        metrics_blocks.main([str(tmp_path / "missing")])


@pytest.fixture(scope="module")
def dice_mug(builtin_data: Config, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A tiny untrained run on the built-in dice and mug (both land either way up)."""
    return tiny_dice_mug_run(builtin_data, tmp_path_factory.mktemp("dice-mug") / "run").path


def test_closest_approach_keeps_each_episodes_nearest_palm(dice_mug: Path) -> None:
    """scripts/closest_approach.py: per env the nearest palm distance over the steps and the
    palm's height above the centre at that step (not at another), the pads' placement at their
    closest; on a tiny run one row per object whose episodes and successes are trainer eval's."""
    import torch

    from trainer.evaluation import evaluate

    ca = script("scripts", "closest_approach")
    approach = ca.ClosestApproach()
    approach.parts.append((torch.full((2,), float("inf")), torch.zeros(2)))
    approach.update(torch.tensor([0.05, 0.02]), torch.tensor([0.10, 0.03]))
    approach.update(torch.tensor([0.03, 0.04]), torch.tensor([0.06, 0.09]))
    distance, above = approach.results()
    assert distance.tolist() == pytest.approx([0.03, 0.02])
    assert above.tolist() == pytest.approx([0.06, 0.03])

    # Pads: counted at the step of their smallest summed distance, not at a later one; a pad
    # 1 cm or more away is not touching; a touching pad is on top where the normal points up.
    placement = ca.PadPlacement()
    placement.parts.append((torch.full((1,), float("inf")), torch.zeros(1), torch.zeros(1)))
    up, side = torch.tensor([[0.9, 0.0, 0.9, 0.0, -1.0]]), torch.zeros(1, 5)
    placement.update(torch.tensor([[0.0, 0.005, -0.002, 0.02, 0.001]]), up)  # sum 0.026
    placement.update(torch.tensor([[0.05, 0.05, 0.0, 0.0, 0.0]]), side)  # sum 0.1: not kept
    pad_sum, on_top, on_side = placement.results()
    assert pad_sum.tolist() == pytest.approx([0.026])
    assert on_top.tolist() == [2.0] and on_side.tolist() == [2.0]
    placement.update(torch.tensor([[0.0, 0.0, 0.0, 0.009, 0.03]]), side)  # sum 0.039: not kept
    placement.update(torch.tensor([[0.0, 0.0, 0.0, 0.009, 0.01]]), side)  # sum 0.019: kept
    assert [float(part[0]) for part in placement.results()] == pytest.approx([0.019, 0, 4])

    result = evaluate(dice_mug, episodes_per_object=3, out="eval-approach")
    lines = ca.main([str(dice_mug), "--episodes-per-object", "3"])
    assert len(lines) == 2 + 2 + 1 + 2 + 2
    assert lines[0].startswith("| object | episodes | successes |") and lines[4] == ""
    for line in lines[7:]:  # the pads' table: a sum >= 0, at most 5 pads on top and sides
        cells = [c.strip() for c in line.strip("|").split("|")]
        for pad_sum, top, side in (cells[1:4], cells[4:7]):
            assert pad_sum == top == side == "—" or (
                float(pad_sum) >= 0 and 0 <= float(top) + float(side) <= 5)
        assert cells[1] != "—" or cells[4] != "—"
    for k, line in enumerate(lines[2:4]):
        cells = [c.strip() for c in line.strip("|").split("|")]
        assert cells[0] == result.names[k] and int(cells[1]) == 3
        assert int(cells[2]) == result.successes[k]
        assert int(cells[3]) == result.endings["never reached"][k]
        failed = cells[4]  # an untrained policy: some episode fails, its palm short of inside
        assert failed == "—" or float(failed) >= 0
    with pytest.raises(SystemExit):
        ca.main([str(dice_mug), "--episodes-per-object", "0"])


def test_eval_upright_splits_exactly_the_episodes_of_trainer_eval(dice_mug: Path) -> None:
    """scripts/eval_upright.py replays trainer eval's episodes: per object its upright and
    upside-down episodes add up to the eval's episodes, their held ones to its successes."""
    from trainer.evaluation import evaluate

    eval_upright = script("scripts", "eval_upright")

    result = evaluate(dice_mug, episodes_per_object=12)
    rows = eval_upright.split_by_start_up(dice_mug, episodes_per_object=12)
    assert [row[0] for row in rows] == result.names
    assert [row[1] + row[3] for row in rows] == result.episodes == [12, 12]
    assert [row[2] + row[4] for row in rows] == result.successes
    # Both ways up occur (a dice or mug reset lands on any side), so the split is exercised.
    assert all(row[1] > 0 and row[3] > 0 for row in rows)
    lines = eval_upright.main([str(dice_mug), "--episodes-per-object", "12"])
    assert lines[2] == f"| builtin_dice | {rows[0][2]}/{rows[0][1]} | {rows[0][4]}/{rows[0][3]} | "\
        f"{result.successes[0]}/12 |" and len(lines) == 4


def test_observed_size_scales_the_told_shapes_and_replays_the_same_episodes(
    dice_mug: Path, builtin_data: Config, tmp_path: Path
) -> None:
    """scripts/observed_size.py: a scale multiplies the box extents, the superquadric's
    semi-axes and the points' offsets from the box centre and nothing else; every scale plays
    each object's share of the envs, the same episodes for the same seed whatever the other
    scales; a run whose representation tells no size is a one-line error."""
    import torch

    from trainer.session import EvalSession

    observed_size = script("scripts", "observed_size")
    session = EvalSession.load(dice_mug)
    env = session.env(4, 0, compile=False, quiet=True)
    objects = env.objects
    env.close()
    twice = observed_size.scaled_shapes(objects, 2.0)
    torch.testing.assert_close(twice.bbox_extents, 2 * objects.bbox_extents)
    torch.testing.assert_close(twice.sq_params[:, 2:5], 2 * objects.sq_params[:, 2:5])
    torch.testing.assert_close(twice.sq_params[:, :2], objects.sq_params[:, :2])
    torch.testing.assert_close(twice.sq_params[:, 5:], objects.sq_params[:, 5:])
    center = objects.bbox_center[:, None]
    torch.testing.assert_close(twice.points - center, 2 * (objects.points - center))
    assert twice.bbox_center is objects.bbox_center and twice.sdf is objects.sdf

    names = ["builtin_dice", "builtin_mug"]
    table = observed_size.observed_size(dice_mug, names, [3.0, 1.0], envs=6, rounds=2)
    assert list(table) == names
    for row in table.values():
        assert [n for _, n in row.values()] == [6, 6]  # 3 envs x 2 rounds
    alone = observed_size.observed_size(dice_mug, names, [1.0], envs=6, rounds=2)
    assert {n: row[1.0] for n, row in table.items()} == {n: row[1.0] for n, row in alone.items()}
    lines = observed_size.main([str(dice_mug), "--objects", "builtin_dice", "--scales", "1,2",
                                "--envs", "2"])
    with pytest.raises(SystemExit):
        observed_size.main([str(dice_mug), "--objects", "builtin_dice", "--scales", "1,1"])
    assert lines[2] == "| run | object | x1 | x2 |"
    assert lines[-1].startswith("| run | builtin_dice | ")
    com = tiny_run(builtin_data, tmp_path / "com", "builtin_dice", representation="com")
    with pytest.raises(SystemExit, match="tells the policy no size"):
        observed_size.observed_size(com.path, ["builtin_dice"], [1.0])


def test_grasp_offset_measures_the_pads_in_the_object_box_frame(dice_mug: Path) -> None:
    """scripts/grasp_offset.py: the pads' centroid in the box frame (a turned, shifted box), and
    per object the episodes trainer eval runs (an untrained policy holds none: no offset)."""
    import math

    import torch

    from trainer.evaluation import evaluate

    grasp_offset = script("scripts", "grasp_offset")

    # A box 0.2 x 0.1 x 0.04 m, its centre 0.05 m along the object's x axis, the object turned
    # 90 degrees about z and standing at (1, 0, 0): the box's x axis points along the world's y.
    quat = torch.tensor([[math.cos(math.pi / 4), 0.0, 0.0, math.sin(math.pi / 4)]])
    centre = torch.tensor([[1.0, 0.05, 0.0]])  # the box centre in the world
    spread = torch.randn(1, 5, 3) * 0.01  # five pads around their centroid, 8 cm along the box
    tips = centre[:, None] + torch.tensor([0.0, 0.08, 0.0]) + spread - spread.mean(1, keepdim=True)
    distance, fraction = grasp_offset.box_frame_offset(
        tips, torch.tensor([[1.0, 0.0, 0.0]]), quat, torch.tensor([[0.05, 0.0, 0.0]]),
        torch.eye(3)[None], torch.tensor([[0.2, 0.1, 0.04]]),
    )
    assert distance.item() == pytest.approx(0.08, abs=1e-6)
    assert fraction.item() == pytest.approx(0.08 / 0.1, abs=1e-5)  # along the box's long axis

    result = evaluate(dice_mug, episodes_per_object=6)
    rows = grasp_offset.grasp_offsets(dice_mug, episodes_per_object=6)
    assert [row[0] for row in rows] == result.names
    assert [row[1] for row in rows] == result.episodes
    assert [row[2] for row in rows] == result.successes
    assert all(math.isnan(row[3]) for row in rows if row[2] == 0)
    lines = grasp_offset.main([str(dice_mug), "--episodes-per-object", "6", "--objects",
                               "builtin_mug"])
    assert lines[2] == "| builtin_mug | 0/6 | nan | nan |" and len(lines) == 3  # none held


def test_bin_diagnosis_runs_each_targets_grasp_in_clutter_and_names_each_failure(
    builtin_data: Config, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    # scripts/bin_diagnosis.py: every counted trial is a target its family serves, with its
    # place in the bin measured, and each failure named by the first of its mechanisms. The
    # built-in objects have no best family: the top grasp serves them all here (no search).
    import csv

    from trainer.grasps.families import variants

    diagnosis = script("scripts", "bin_diagnosis")
    names = ["builtin_box", "builtin_cylinder", "builtin_sphere"]
    monkeypatch.setattr(diagnosis, "object_grasps",
                        lambda cfg, family: {n: {"family": "top"} for n in names})
    monkeypatch.setattr(diagnosis, "best_variants",
                        lambda names, searched: {"top": (variants("top")["base"], list(names))})
    out = tmp_path / "diag"
    diagnosis.main(["--objects", ",".join(names), "--bin-objects", "3", "--trials", "6",
                    "--data-dir", str(builtin_data.data_dir), "--out", str(out)])
    rows = list(csv.DictReader((out / "trials.csv").open()))
    assert len(rows) == 6 and {r["target"] for r in rows} <= set(names)
    for r in rows:
        gap = float(r["wall_gap"])
        assert -0.01 < gap < 0.2  # inside the 40 cm bin (a sample may touch the wall)
        assert (r["at_wall"] == "True") == (gap < diagnosis.WALL_GAP)
        assert (r["mechanism"] == "lifted") == (r["outcome"] == "lifted")
    printed = capsys.readouterr().out
    assert "| overall | 6 |" in printed and "| where the target lay | trials | lifted |" in printed
    assert (out / "table.md").read_text().count("\n") >= 8
    # The mechanism's order: covered before the wall before the outcome.
    assert diagnosis.mechanism("no_grip", True, True) == "covered"
    assert diagnosis.mechanism("pushed", False, True) == "at wall"
    assert diagnosis.mechanism("dropped", False, False) == "dropped"
    assert diagnosis.mechanism("lifted", True, True) == "lifted"
    with pytest.raises(SystemExit, match="--video needs --out"):
        diagnosis.main(["--objects", "builtin_box", "--video"])


def test_video_frames_stacks_the_frames_at_even_times(tmp_path: Path) -> None:
    """scripts/video_frames.py: a 3 s video whose frames change colour each second gives a sheet
    whose rows are its first, middle and last frames, in that order, each scaled to the
    sheet's width."""
    import imageio_ffmpeg
    import numpy as np
    from PIL import Image

    colours = [(250, 0, 0), (0, 250, 0), (0, 0, 250)]
    video = tmp_path / "three.mp4"
    writer = imageio_ffmpeg.write_frames(str(video), (64, 32), fps=10, macro_block_size=1)
    writer.send(None)
    for colour in colours:
        for _ in range(10):
            writer.send(np.full((32, 64, 3), colour, np.uint8).tobytes())
    writer.close()

    video_frames = script("scripts", "video_frames")
    picked, fps, total = video_frames.read_frames(video, count=3)
    assert ([index for index, _ in picked], fps, total) == ([0, 14, 29], 10.0, 30)  # 14.5 -> 14
    sheet = np.asarray(video_frames.contact_sheet(picked, fps, width=128))
    assert sheet.shape == (3 * 64, 128, 3)
    for row, colour in enumerate(colours):
        centre = sheet[row * 64 + 40, 64].astype(int)  # below the time label
        assert np.abs(centre - colour).max() < 40, (row, centre)
    out = tmp_path / "sheet.jpg"
    with pytest.raises(SystemExit) as done:
        video_frames.main([str(video), "--frames", "2", "--width", "64", "--out", str(out)])
    assert done.value.code == 0 and Image.open(out).size == (64, 64)


def _eval_folder(path: Path, rows: dict[str, tuple[int, int]]) -> Path:
    """A trainer eval folder: per_object.csv and endings.csv (the failures all never lifted)."""
    path.mkdir()
    per_object = ["object,episodes,successes,success_rate,task,bin_objects,context,representation"]
    endings = ["object,episodes,success,never_lifted,dropped,stalled,knocked_off"]
    for name, (episodes, successes) in rows.items():
        rate = f"{successes / episodes:.4f}" if episodes else ""
        per_object.append(f"{name},{episodes},{successes},{rate},bin,5,none,bbox")
        endings.append(f"{name},{episodes},{successes},{episodes - successes},0,0,0")
    (path / "per_object.csv").write_text("\n".join(per_object) + "\n")
    (path / "endings.csv").write_text("\n".join(endings) + "\n")
    return path


def test_paired_evals_compares_the_same_episodes_by_object(tmp_path: Path) -> None:
    from click.testing import CliRunner

    paired = script("scripts", "paired_evals")
    base = _eval_folder(tmp_path / "base", {"a": (20, 10), "b": (20, 4), "c": (0, 0)})
    other = _eval_folder(tmp_path / "other", {"a": (20, 14), "b": (20, 6), "c": (0, 0)})
    done = CliRunner().invoke(paired.main, [str(base), str(other)])
    assert done.exit_code == 0, done.output
    lines = done.output.splitlines()
    assert lines[0] == ("| evaluation | episodes | held | never lifted | dropped | stalled "
                        "| knocked off |")
    assert lines[2] == f"| {base} | 40 | 0.350 | 0.650 | 0.000 | 0.000 | 0.000 |"
    assert lines[3] == f"| {other} | 40 | 0.500 | 0.500 | 0.000 | 0.000 | 0.000 |"
    # differences +0.2 and +0.1 (c has no episodes): mean 0.15, standard error 0.05
    assert lines[4] == (f"{other} over {base}: +0.150 ± 0.050 by object (2 objects: 2 up, "
                        f"0 down): beyond two standard errors")
    # Another number of episodes is not the same episodes: refused in one line.
    fewer = _eval_folder(tmp_path / "fewer", {"a": (10, 5), "b": (20, 4)})
    done = CliRunner().invoke(paired.main, [str(base), str(fewer)])
    assert done.exit_code == 1 and "a: 20 episodes against 10: not the same episodes" in \
        done.output


def test_budget_gains_pairs_each_extension_with_its_run_at_the_budget(tmp_path: Path) -> None:
    """Each evaluated ext-ARM is set against cmp-ARM (or the run --base names) on the same
    episodes; an extension still running is listed, not tabled; a missing base is one line."""
    from click.testing import CliRunner

    gains = script("scripts", "budget_gains")
    runs = tmp_path / "runs"
    for name, rows in {"cmp-sq-sdf-s0": {"a": (20, 10), "b": (20, 4)},
                       "ext-sq-sdf-s0": {"a": (20, 14), "b": (20, 6)},
                       "elsewhere": {"a": (20, 20), "b": (20, 0)},
                       "ext-bbox-sdf-s0": {"a": (20, 20), "b": (20, 2)}}.items():
        (runs / name).mkdir(parents=True)
        _eval_folder(runs / name / "eval", rows)
    (runs / "ext-com-sdf-s1").mkdir()  # copied, not evaluated yet
    (runs / "ext-sdf-sdf-s0.partial").mkdir()  # an interrupted copy: not a run
    done = CliRunner().invoke(gains.main, [str(runs), "--objects", "b",
                                           "--base", f"bbox-sdf-s0={runs / 'elsewhere'}"])
    assert done.exit_code == 0, done.output
    lines = done.output.splitlines()
    assert lines[0] == "| run | at the budget | extended | by object (paired) | b |"
    # bbox: a +0, b +0.1: mean +0.05 ± 0.05, inside two standard errors
    assert lines[2] == ("| bbox-sdf-s0 | 0.500 | **0.550** | +0.050 ± 0.050 (1 up, 0 down; noise) "
                        "| 0 -> 2 |")
    # sq: +0.2 and +0.1, mean +0.15 ± 0.05: beyond
    assert lines[3] == "| sq-sdf-s0 | 0.350 | **0.500** | +0.150 ± 0.050 (2 up, 0 down) | 4 -> 6 |"
    assert lines[-1] == "not evaluated yet: com-sdf-s1"
    done = CliRunner().invoke(gains.main, [str(runs)])
    assert done.exit_code == 1
    assert "bbox-sdf-s0: " in done.output and "--base bbox-sdf-s0=RUN" in done.output


def test_paired_evals_folds_never_reached_into_never_lifted_beside_an_older_eval(
    tmp_path: Path,
) -> None:
    """An evaluation from before never reached was recorded counts those episodes as never
    lifted: compared with it, a newer one's never reached are folded back into never lifted
    (the same episodes, counted the same way); two newer ones keep the column."""
    from click.testing import CliRunner

    paired = script("scripts", "paired_evals")
    old = _eval_folder(tmp_path / "old", {"a": (20, 10)})
    new = tmp_path / "new"
    new.mkdir()
    (new / "per_object.csv").write_text(
        "object,episodes,successes,success_rate,task,bin_objects,context,representation\n"
        "a,20,12,0.6000,lift,,none,bbox\n")
    (new / "endings.csv").write_text(
        "object,episodes,success,never_reached,never_lifted,dropped,stalled,knocked_off\n"
        "a,20,12,5,3,0,0,0\n")
    done = CliRunner().invoke(paired.main, [str(old), str(new)])
    assert done.exit_code == 0, done.output
    lines = done.output.splitlines()
    assert "never reached" not in lines[0]
    assert lines[3] == f"| {new} | 20 | 0.600 | 0.400 | 0.000 | 0.000 | 0.000 |"
    done = CliRunner().invoke(paired.main, [str(new), str(new)])
    assert done.output.splitlines()[0] == (
        "| evaluation | episodes | held | never reached | never lifted | dropped | stalled "
        "| knocked off |")
    assert done.output.splitlines()[2] == (
        f"| {new} | 20 | 0.600 | 0.250 | 0.150 | 0.000 | 0.000 | 0.000 |")


def test_run_status_tables_each_run_where_it_stands(tmp_path: Path, capsys) -> None:  # noqa: ANN001
    """scripts/run_status.py: one row per run in the report's arm order and names, its env steps
    of its budget, minutes, machines and evaluated held rate; a missing run is one line."""
    import json

    from tests.test_report import _write_run
    from trainer.training.run_dir import record_launch

    status = script("scripts", "run_status")
    sq = _write_run(tmp_path, "sq", 0, 60, [0.1, 0.5], {"cube": (10, 7)})
    com = _write_run(tmp_path, "com", 1, 30, [0.1, 0.2, 0.3], None)
    config = json.loads((com / "config.json").read_text())
    config["ppo"]["lr"] = 1e-3
    (com / "config.json").write_text(json.dumps(config))
    record_launch(RunDir(com), {"first_iteration": 2, "started": "2026-11-30T05:00:00Z",
                                "code": "abc", "cpu": "AMD EPYC", "cores": 2, "nice": 5,
                                "device": "cpu", "processes": 1, "sim_threads": 1,
                                "torch_threads": 1})
    status.main([str(sq), str(com)])
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == "| arm | seed | env steps (M) | minutes | machines | held (eval) |"
    assert lines[2] == ("| com [lr=0.001] | 1 | 0.30 of 1.00 | 2 | not recorded; AMD EPYC, "
                        "2 cores, nice 5 | — |")
    assert lines[3] == "| sq [lr=0.0003] | 0 | 0.20 of 1.00 | 2 | not recorded | **0.700** |"
    with pytest.raises(SystemExit, match="run_status: .*none"):
        status.main([str(tmp_path / "none")])


def test_object_correlation_ranks_successes_across_runs(tmp_path: Path) -> None:
    """scripts/object_correlation.py: Spearman's rho of two objects' evaluation successes over
    the runs (+1 where they rise together, -1 against each other, "—" for a constant object);
    a run without an evaluation, or without an object, is a one-line error."""
    object_correlation = script("scripts", "object_correlation")
    counts = {"a": (3, 40, 7), "b": (10, 2, 9), "c": (5, 30, 45)}  # knife, plate, dice
    runs = []
    for name, (knife, plate, dice) in counts.items():
        (tmp_path / name / "eval").mkdir(parents=True)
        (tmp_path / name / "eval" / "per_object.csv").write_text(
            "object,episodes,successes,success_rate\n"
            f"knife,50,{knife},0\nplate,50,{plate},0\ndice,50,{dice},0\ncube,50,50,1\n")
        runs.append(str(tmp_path / name))
    lines = object_correlation.main([*runs, "--objects", "knife,dice,plate,cube"])
    assert lines[2:5] == ["| a | 3 | 7 | 40 | 50 |", "| b | 10 | 9 | 2 | 50 |",
                          "| c | 5 | 45 | 30 | 50 |"]
    # knife ranks a<c<b, dice a<b<c: rho 0.5; plate b<c<a against knife: -1
    assert lines[-4:] == ["| knife | +1.00 | +0.50 | -1.00 | — |",
                          "| dice | +0.50 | +1.00 | -0.50 | — |",
                          "| plate | -1.00 | -0.50 | +1.00 | — |",
                          "| cube | — | — | — | — |"]
    with pytest.raises(SystemExit, match="no mug; its objects"):
        object_correlation.main([*runs, "--objects", "knife,mug"])
    (tmp_path / "d").mkdir()
    with pytest.raises(SystemExit, match="per_object.csv: missing; evaluate"):
        object_correlation.main([*runs, str(tmp_path / "d"), "--objects", "knife,dice"])
    with pytest.raises(SystemExit):
        object_correlation.main([*runs[:2], "--objects", "knife,dice"])  # two runs: too few
