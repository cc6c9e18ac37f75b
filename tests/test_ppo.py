"""PPO training, resume, evaluation and the command line on tiny configs (few envs, few steps)."""

from __future__ import annotations

import csv
import dataclasses
import json
import math
from pathlib import Path

import pytest
import torch
from click.testing import CliRunner
from torchrl.collectors import Collector
from torchrl.envs.utils import ExplorationType, set_exploration_type
from torchrl.objectives import ClipPPOLoss

from geomprep.config import Config
from trainer.cli import cli
from trainer.config import load_train_config
from trainer.env import GraspEnv
from trainer.evaluation import evaluate, run_episodes
from trainer.models import Agent, RunningNorm
from trainer.ppo import load_agent, minibatch_size, train

OBJECTS = "builtin_cylinder,builtin_sphere"


def tiny_config(data_dir: Path, iterations: int = 3, representation: str = "com"):  # noqa: ANN201
    return load_train_config(
        env={"num_envs": 4, "objects": OBJECTS, "representation": representation,
             "data_dir": data_dir, "max_steps": 20},
        ppo={"frames_per_env": 8, "minibatches": 2, "min_minibatch": 1, "epochs": 2,
             "hidden": (32, 32, 32),
             "pointnet_hidden": (16, 16)},
        run={"total_steps": 4 * 8 * iterations, "checkpoint_every": 2, "seed": 3},
    )


def test_minibatch_size_scales_with_env_count() -> None:
    def size(num_envs: int) -> int:
        return minibatch_size(load_train_config(env={"num_envs": num_envs}))

    assert size(16384) == 32768  # the paper: 16 minibatches of 32,768
    assert size(1024) == 2048  # 16 minibatches
    assert size(64) == 1024  # 2 minibatches: at least min_minibatch frames
    assert size(16) == 512  # never more than the rollout


def test_untrained_policy_mean_action(builtin_data: Config) -> None:
    # init_action_mean = the home posture (hand pose still, thumb opposed, fingers open): the
    # env then holds the home hand targets (up to the 1 % weight of the observation).
    cfg = tiny_config(builtin_data.data_dir)
    home = (0.0,) * 6 + (1.0, -1.0, -1.0, -1.0, -1.0)
    cfg = dataclasses.replace(cfg, ppo=dataclasses.replace(cfg.ppo, init_action_mean=home))
    env = GraspEnv(cfg.env, seed=0)
    agent = Agent(cfg.env.representation, cfg.ppo)
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        td = env.step(agent.actor(env.reset()))
    hand = td["action"][:, 6:]
    torch.testing.assert_close(hand, torch.tensor([[1.0, -1, -1, -1, -1]]).expand(4, 5),
                               atol=0.2, rtol=0)
    targets = env.ctrl[:, env.hand_act]
    torch.testing.assert_close(targets, env.home_ctrl[env.hand_act].expand(4, 5), atol=0.2,
                               rtol=0)
    env.close()


def test_running_norm_matches_batch_statistics() -> None:
    norm = RunningNorm((3,))
    data = torch.randn(1000, 3) * torch.tensor([1.0, 5.0, 0.1]) + torch.tensor([2.0, -1.0, 0.0])
    for chunk in data.split(137):
        norm.update(chunk)
    torch.testing.assert_close(norm.mean, data.mean(0), atol=1e-4, rtol=0)
    torch.testing.assert_close(norm.var, data.var(0, unbiased=False), atol=1e-3, rtol=1e-4)
    torch.testing.assert_close(norm.denormalize(norm(data[:5])), data[:5], atol=1e-4, rtol=0)


def test_loss_sees_updated_normalizers(builtin_data: Config) -> None:
    """The collected log-probs and the loss's log-probs come from the same policy even after the
    observation statistics move (the loss module holds references to the buffers)."""
    cfg = tiny_config(builtin_data.data_dir)
    env = GraspEnv(cfg.env)
    agent = Agent("com", cfg.ppo)
    loss = ClipPPOLoss(agent.actor, agent.critic, entropy_coeff=0.0)
    collector = Collector(env, agent.actor, frames_per_batch=32, total_frames=-1,
                          auto_register_policy_transforms=False)
    for k, data in enumerate(collector):
        if k == 2:
            break
        agent.obs_norm.update(data["proprio"], data["object"])
    flat = data.reshape(-1)
    flat["advantage"] = torch.randn(flat.shape[0], 1)
    flat["value_target"] = torch.zeros(flat.shape[0], 1)
    with torch.no_grad():
        out = loss(flat)
    collector.shutdown()
    assert float(out["kl_approx"].abs()) < 1e-6
    assert float(out["clip_fraction"]) == 0.0


@pytest.mark.parametrize("representation", ["com", "pc32"])
def test_train_writes_run_directory(builtin_data: Config, tmp_path: Path, representation: str) -> None:  # noqa: E501
    cfg = tiny_config(builtin_data.data_dir, representation=representation)
    run = train(cfg, tmp_path / "run", progress=False)
    config = json.loads(run.config.read_text())
    assert config["env"]["representation"] == representation
    rows = list(csv.DictReader(run.metrics.read_text().splitlines()))
    assert [int(r["iteration"]) for r in rows] == [1, 2, 3]
    assert [int(r["env_steps"]) for r in rows] == [32, 64, 96]
    for key in ("loss_objective", "loss_critic", "kl_approx", "action_std", "fps"):
        assert all(math.isfinite(float(r[key])) for r in rows), key
    assert sorted(p.name for p in run.checkpoints.iterdir()) == [
        "iter_000002.pt", "iter_000003.pt", "last.pt"
    ]
    assert any((run.path / "tb").iterdir())
    # 20-step episodes over 96 steps of 4 envs: at least 4 episodes ended and were counted.
    assert sum(int(r["episodes"]) for r in rows) >= 4


def with_curriculum(cfg, start: float, increment: float):  # noqa: ANN001, ANN201
    reward = dataclasses.replace(
        cfg.env.reward, h_bar_start=start, h_bar_increment=increment, h_bar_promote=0.5
    )
    return dataclasses.replace(cfg, env=dataclasses.replace(cfg.env, reward=reward))


def test_lift_curriculum_promotes_and_counts_task_success(
    builtin_data: Config, tmp_path: Path
) -> None:
    # A target 1 m below the start: every env "succeeds" at its first step, so the running
    # success at the target is 1 and the target rises by 0.6 per full window (4 episodes),
    # up to, never past, h_bar = 0.2.  Success at the task's 0.2 m stays 0 (nothing is lifted).
    cfg = with_curriculum(tiny_config(builtin_data.data_dir, iterations=4), -1.0, 0.6)
    run = train(cfg, tmp_path / "run", progress=False)
    rows = list(csv.DictReader(run.metrics.read_text().splitlines()))
    assert [round(float(r["h_bar"]), 6) for r in rows[:3]] == [-1.0, -0.4, 0.2]
    assert float(rows[0]["target_success_rate"]) == 1.0
    assert all(float(r["success_rate"]) == 0.0 for r in rows)
    assert torch.load(run.last, weights_only=False)["h_bar"] == pytest.approx(0.2)
    # Evaluation uses the task's h_bar, not the curriculum's.
    _, agent = load_agent(run.path)
    env = GraspEnv(dataclasses.replace(cfg.env, num_envs=4), seed=1)
    assert float(env.h_bar) == pytest.approx(0.2)
    success, _ = run_episodes(env, agent.actor)
    assert not success.any()


def test_resume_continues_bit_for_bit(builtin_data: Config, tmp_path: Path) -> None:
    # With a lift curriculum, whose target is part of the state to restore.
    cfg = with_curriculum(tiny_config(builtin_data.data_dir, iterations=4), -1.0, 0.3)
    straight = train(cfg, tmp_path / "straight", progress=False)
    # A run killed after iteration 3 (its last checkpoint is iteration 2), then resumed.
    killed = train(cfg, tmp_path / "killed", progress=False, stop_after=3)
    assert not (killed.checkpoints / "iter_000004.pt").exists()
    with pytest.raises(Exception, match="resume"):
        train(cfg, tmp_path / "killed", progress=False)
    train(None, tmp_path / "killed", resume=True, progress=False)  # type: ignore[arg-type]
    a = torch.load(straight.checkpoints / "iter_000004.pt", weights_only=False)
    b = torch.load(killed.checkpoints / "iter_000004.pt", weights_only=False)
    for key, value in a["agent"].items():
        assert torch.equal(value, b["agent"][key]), key
    assert (a["env"]["backend"]["state"] == b["env"]["backend"]["state"]).all()
    rows = list(csv.DictReader(killed.metrics.read_text().splitlines()))
    assert [int(r["iteration"]) for r in rows] == [1, 2, 3, 4]
    straight_rows = list(csv.DictReader(straight.metrics.read_text().splitlines()))
    assert [r["h_bar"] for r in rows] == [r["h_bar"] for r in straight_rows]
    assert float(rows[-1]["h_bar"]) > -1.0


def test_eval_counts_match_a_manual_count(builtin_data: Config, tmp_path: Path) -> None:
    cfg = tiny_config(builtin_data.data_dir, iterations=2)
    run = train(cfg, tmp_path / "run", progress=False)
    result = evaluate(run.path, episodes_per_object=3, seed=5)
    assert result.names == OBJECTS.split(",") and result.episodes == [3, 3]
    # The same episodes by hand: same seed, same deterministic policy.
    _, agent = load_agent(run.path)
    env = GraspEnv(dataclasses.replace(cfg.env, num_envs=6), seed=5)
    success, length = run_episodes(env, agent.actor)
    ids = env.env_object
    assert result.successes == [int(success[ids == k].sum()) for k in range(2)]
    assert (length <= cfg.env.max_steps).all() and (length >= 1).all()
    rows = list(csv.DictReader((run.path / "eval" / "per_object.csv").read_text().splitlines()))
    assert [r["object"] for r in rows] == result.names
    assert "| **all (6 episodes)** |" in (run.path / "eval" / "table.md").read_text()


def test_cli_run_eval_play_report(builtin_data: Config, tmp_path: Path) -> None:
    config = tmp_path / "tiny.toml"
    config.write_text(
        "max_steps = 20\n[ppo]\nframes_per_env = 8\nminibatches = 2\nmin_minibatch = 1\n"
        "epochs = 1\n"
        "hidden = [32, 32, 32]\n[run]\ncheckpoint_every = 1\n"
    )
    runner = CliRunner()
    common = ["--data-dir", str(builtin_data.data_dir), "--config", str(config)]
    run_dir = tmp_path / "runs" / "sq"
    result = runner.invoke(cli, ["run", "--repr", "sq", "--objects", OBJECTS, "--num-envs", "4",
                                 "--steps", "64", "--run-dir", str(run_dir), "--no-compile",
                                 *common])
    assert result.exit_code == 0, result.output
    result = runner.invoke(cli, ["eval", str(run_dir), "--episodes-per-object", "2"])
    assert result.exit_code == 0, result.output
    assert "overall" in result.output
    video = tmp_path / "play.gif"
    result = runner.invoke(cli, ["play", str(run_dir), "--object", "builtin_sphere",
                                 "--video", str(video)])
    assert result.exit_code == 0, result.output
    assert video.stat().st_size > 1000
    result = runner.invoke(cli, ["report", str(run_dir), "--out", str(tmp_path / "report")])
    assert result.exit_code == 0, result.output
    assert "| sq | sdf | ur5e | 1 |" in (tmp_path / "report" / "report.md").read_text()
    result = runner.invoke(cli, ["run", "--resume", str(tmp_path / "nothing")])
    assert result.exit_code != 0
