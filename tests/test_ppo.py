"""PPO training, resume, evaluation and the command line on tiny configs (few envs, few steps)."""

from __future__ import annotations

import csv
import dataclasses
import json
import math
import os
import shutil
import signal
import sys
from pathlib import Path

import pytest
import torch
from click.testing import CliRunner
from torchrl.collectors import Collector
from torchrl.envs.utils import ExplorationType, set_exploration_type
from torchrl.objectives import ClipPPOLoss

from geomgrasp.machine import code_version, cpu_model
from geomprep.config import Config
from trainer.cli import cli
from trainer.cli import main as trainer_main
from trainer.config import RewardConfig, load_train_config
from trainer.errors import TrainerError
from trainer.evaluation import evaluate
from trainer.models import Agent, RunningNorm
from trainer.ppo import minibatch_size, train, train_run, warmup_config
from trainer.session import run_episodes
from trainer.tasks import make_env, observation_spec
from trainer.training.checkpoint import agent_part, copy_agent_parts, load_agent
from trainer.training.curriculum import LiftCurriculum
from trainer.training.outcomes import ObjectOutcomes
from trainer.training.run_dir import read_launches
from trainer.training.stop import StopSignals

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
    env = make_env(cfg.env, seed=0)
    agent = Agent(env.observation_spec, cfg.ppo)
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        td = env.step(agent.actor(env.reset()))
    hand = td["action"][:, 6:]
    torch.testing.assert_close(hand, torch.tensor([[1.0, -1, -1, -1, -1]]).expand(4, 5),
                               atol=0.2, rtol=0)
    actuators = env.robot.hand.actuators
    targets = env.state["ctrl"][:, actuators]
    home = env.home_ctrl[0, actuators].expand(4, 5)
    torch.testing.assert_close(targets, home, atol=0.2, rtol=0)
    env.close()


def test_per_action_initial_std(builtin_data: Config) -> None:
    # init_log_std per action: the untrained policy explores the hand pose with one std and
    # the hand with another; sampled actions spread by exactly those.
    cfg = tiny_config(builtin_data.data_dir)
    log_std = (math.log(0.3),) * 6 + (math.log(0.05),) * 5
    cfg = dataclasses.replace(cfg, ppo=dataclasses.replace(cfg.ppo, init_log_std=log_std))
    env = make_env(cfg.env, seed=0)
    agent = Agent(env.observation_spec, cfg.ppo)
    torch.manual_seed(0)
    td = env.reset()
    with set_exploration_type(ExplorationType.RANDOM):
        actions = torch.cat([agent.actor(td.clone())["action"] for _ in range(500)])
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        mean = agent.actor(td.clone())["action"].repeat(500, 1)
    spread = (actions - mean).std(0)
    torch.testing.assert_close(spread[:6], torch.full((6,), 0.3), atol=0.03, rtol=0)
    torch.testing.assert_close(spread[6:], torch.full((5,), 0.05), atol=0.005, rtol=0)
    env.close()


def test_state_dependent_std_learns_where_noise_pays(builtin_data: Config) -> None:
    # [ppo] state_dependent_std: untrained, every state explores with init_log_std's std; then
    # a policy-gradient signal that pays small noise in one kind of state (holding a grasp) and
    # large noise in another (reaching) sets the two apart, which one learned vector cannot.
    cfg = tiny_config(builtin_data.data_dir)
    cfg = dataclasses.replace(cfg, ppo=dataclasses.replace(cfg.ppo, state_dependent_std=True))
    env = make_env(cfg.env, seed=0)
    policy = Agent(env.observation_spec, cfg.ppo).policy_net
    torch.manual_seed(0)
    proprio = torch.randn(2048, *env.observation_spec["proprio"].shape[1:])
    obj = torch.randn(2048, *env.observation_spec["object"].shape[1:])
    env.close()
    holding = torch.arange(2048) < 1024
    proprio[holding] += 3.0  # two clusters of states the features tell apart
    _, scale = policy(proprio, obj)
    torch.testing.assert_close(scale, torch.full_like(scale, math.exp(-0.5)))
    optimizer = torch.optim.Adam(policy.parameters(), lr=1e-3)
    for _ in range(200):
        loc, scale = policy(proprio, obj)
        action = (loc + scale * torch.randn_like(loc)).detach()
        dist = torch.distributions.Normal(loc, scale)
        noise = ((action - loc) / scale).detach().pow(2)
        advantage = torch.where(holding[:, None], 1.0 - noise, noise - 1.0)
        loss = -(advantage * dist.log_prob(action)).mean()
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    _, scale = policy(proprio, obj)
    holding_std, reaching_std = float(scale[holding].mean()), float(scale[~holding].mean())
    assert holding_std < 0.5 * math.exp(-0.5) and holding_std < 0.7 * reaching_std


def test_running_norm_matches_batch_statistics() -> None:
    norm = RunningNorm((3,))
    data = torch.randn(1000, 3) * torch.tensor([1.0, 5.0, 0.1]) + torch.tensor([2.0, -1.0, 0.0])
    for chunk in data.split(137):
        norm.update(chunk)
    torch.testing.assert_close(norm.mean, data.mean(0), atol=1e-4, rtol=0)
    torch.testing.assert_close(norm.var, data.var(0, unbiased=False), atol=1e-3, rtol=1e-4)
    torch.testing.assert_close(norm.denormalize(norm(data[:5])), data[:5], atol=1e-4, rtol=0)


@pytest.mark.parametrize(("representation", "hidden"), [("pc32", (16, 24)), ("pc128", (16, 24)),
                                                      ("pc32", (8, 64))])
def test_point_encoder_equals_activation_on_every_point_then_max(
    representation: str, hidden: tuple[int, int],
) -> None:
    # The encoder activates after the max over points, runs the points in chunks and, with
    # more points than channels, gives the gradient only to each channel's argmax point: all
    # that must be the PointNet of an activation on every point followed by a max, in values
    # and gradients, for batches of any shape (the update's (B,), GAE's (E, T)).
    from trainer.models import max_pooled_points
    from trainer.tasks.spec import observation_spec

    cfg = load_train_config(env={"representation": representation},
                            ppo={"pointnet_hidden": hidden})
    spec = observation_spec(cfg.env, num_envs=6)["observation"]
    # In double precision: a weight's gradient sums ~10^5 terms that mostly cancel, so float32's
    # summation order alone (it differs between CPUs' kernels) moved it by 5e-4 relative; the
    # test is about which point each channel's gradient reaches, not about rounding.
    encoder = Agent(spec, cfg.ppo).policy_net.encoder.double()
    n = int(representation[2:])
    torch.manual_seed(0)
    # 2,100 samples: several chunks of POINTS_PER_CHUNK
    points = torch.randn(3, 700, n, 3, dtype=torch.float64)
    weights = torch.randn(3, 700, hidden[-1], dtype=torch.float64)

    def reference(x: torch.Tensor) -> torch.Tensor:
        per_point = torch.nn.functional.elu(encoder.points(x))
        return per_point.amax(dim=-2)

    ours = encoder.points_activation(max_pooled_points(encoder.points, points))
    theirs = reference(points)
    torch.testing.assert_close(ours, theirs, rtol=1e-12, atol=1e-12)
    with torch.no_grad():
        torch.testing.assert_close(max_pooled_points(encoder.points, points),
                                   encoder.points(points).max(dim=-2).values, rtol=0, atol=1e-12)
    grads = []
    for out in (ours, theirs):
        encoder.zero_grad()
        (out * weights).sum().backward()
        grads.append([p.grad.clone() for p in encoder.points.parameters()])
    for a, b in zip(*grads, strict=True):
        torch.testing.assert_close(a, b, rtol=1e-10, atol=1e-10)
    # a checkpoint of the per-point MLP with its last ELU (the earlier form) loads as is
    keys = set(encoder.points.state_dict())
    assert keys == {"0.weight", "0.bias", "2.weight", "2.bias"}


def test_shared_encoder_runs_once_per_minibatch_and_learns_from_both_losses() -> None:
    # [ppo] shared_encoder: PPO's loss encodes a minibatch once (the actor writes it, the value
    # head reads it); the value and policy equal the networks' own on the observations, and
    # the critic's loss alone trains the shared encoder (its gradient reaches the point MLP).
    from tensordict import TensorDict

    from trainer.tasks.spec import observation_spec

    cfg = load_train_config(env={"representation": "pc32"},
                            ppo={"pointnet_hidden": (16, 24), "shared_encoder": True})
    spec = observation_spec(cfg.env, num_envs=8)["observation"]
    agent = Agent(spec, cfg.ppo)
    assert agent.value_net.encoder is agent.policy_net.encoder
    torch.manual_seed(0)
    obs = {k: torch.randn(8, *spec[k].shape[1:]) for k in ("proprio", "object")}
    data = TensorDict(obs, batch_size=[8])
    with torch.no_grad():
        data = agent.actor(data)
        agent.critic_denorm(data)
    data["advantage"] = torch.randn(8, 1)
    data["value_target"] = torch.randn(8, 1)
    data = data.exclude(Agent.ENCODED)
    calls = []
    agent.policy_net.encoder.register_forward_hook(lambda *_: calls.append(1))
    loss = ClipPPOLoss(agent.actor, agent.critic, entropy_coeff=0.0)
    out = loss(data)
    assert len(calls) == 1
    loc, _ = agent.policy_net(obs["proprio"], obs["object"])
    value = agent.value_net(obs["proprio"], obs["object"])
    torch.testing.assert_close(agent.critic(agent.actor(data.clone()))["state_value"], value)
    torch.testing.assert_close(agent.actor(data.clone())["loc"], loc)
    agent.zero_grad()
    out["loss_critic"].backward()
    grad = agent.policy_net.encoder.points[0].weight.grad
    assert grad is not None and grad.abs().sum() > 0
    assert agent.policy_net.loc.weight.grad is None  # the critic's loss does not reach the policy


@pytest.mark.parametrize(("representation", "shared"), [("bbox", False), ("pc32", True)])
def test_rollout_values_are_gaes_and_run_each_observation_once(
    builtin_data: Config, representation: str, shared: bool
) -> None:
    """``rollout_values`` writes the values TorchRL's GAE with the value network computes (float
    rounding apart: other batch shapes), but runs the network on the next observations only
    where an episode ended and at the rollout's last step; with the shared encoder, the
    rollout's observations are not encoded again (the policy encoded them as it collected)."""
    from torchrl.objectives.value import GAE

    from trainer.ppo import rollout_values

    cfg = tiny_config(builtin_data.data_dir, representation=representation)
    cfg = dataclasses.replace(cfg, env=dataclasses.replace(cfg.env, max_steps=6),
                              ppo=dataclasses.replace(cfg.ppo, shared_encoder=shared))
    env = make_env(cfg.env, seed=0)
    agent = Agent(env.observation_spec, cfg.ppo)
    data = next(iter(Collector(env, agent.actor, frames_per_batch=4 * 16, total_frames=-1,
                               auto_register_policy_transforms=False)))
    ended = data["next", "done"].squeeze(-1)
    assert ended[:, :-1].any()  # episodes of 6 steps end inside a rollout of 16
    expected = data.clone()
    with torch.no_grad():
        GAE(gamma=0.99, lmbda=0.95, value_network=agent.critic_denorm)(expected)
    encoded: list[int] = []
    agent.value_net.encoder.register_forward_hook(
        lambda _module, inputs, _out: encoded.append(math.prod(inputs[0].shape[:-1])))
    rollout_values(agent, data)
    with torch.no_grad():
        GAE(gamma=0.99, lmbda=0.95, value_network=None)(data)
    for key in ("state_value", ("next", "state_value"), "advantage", "value_target"):
        torch.testing.assert_close(data[key], expected[key], rtol=1e-5, atol=1e-5)
    runs_of_next = int(ended[:, :-1].sum()) + 4
    assert sum(encoded) == (runs_of_next if shared else 4 * 16 + runs_of_next)
    env.close()


def test_loss_sees_updated_normalizers(builtin_data: Config) -> None:
    """The collected log-probs and the loss's log-probs come from the same policy even after the
    observation statistics move (the loss module holds references to the buffers)."""
    cfg = tiny_config(builtin_data.data_dir)
    env = make_env(cfg.env)
    agent = Agent(env.observation_spec, cfg.ppo)
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


@pytest.mark.parametrize("representation", ["com", "pc32", "pc32-shared"])
def test_train_writes_run_directory(builtin_data: Config, tmp_path: Path, representation: str) -> None:  # noqa: E501
    representation, _, shared = representation.partition("-")
    cfg = tiny_config(builtin_data.data_dir, representation=representation)
    if shared:
        cfg = dataclasses.replace(cfg, ppo=dataclasses.replace(cfg.ppo, shared_encoder=True))
    run = train(cfg, tmp_path / "run", progress=False)
    if shared:  # it resumes from its checkpoint (the shared weights load into one encoder)
        more = dataclasses.replace(cfg, run=dataclasses.replace(cfg.run, total_steps=128))
        train(more, run.path, resume=True, progress=False)
        rows = list(csv.DictReader(run.metrics.read_text().splitlines()))
        assert [int(r["iteration"]) for r in rows] == [1, 2, 3, 4]
        return
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


def with_curriculum(cfg, start: float, increment: float, per_object: bool = False):  # noqa: ANN001, ANN201, E501
    # hold_tips = 0: a target below the start (start < 0) is then reached at every step with
    # nothing held, which these tests use to drive the curriculum.
    reward = dataclasses.replace(
        cfg.env.reward, h_bar_start=start, h_bar_increment=increment, h_bar_promote=0.5,
        hold_tips=0, curriculum_per_object=per_object,
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
    assert all(float(r["object_success_rate"]) == 0.0 for r in rows)
    assert torch.load(run.last, weights_only=False)["h_bar"] == pytest.approx(0.2)
    # Evaluation uses the task's h_bar, not the curriculum's.
    _, agent = load_agent(run.path)
    env = make_env(dataclasses.replace(cfg.env, num_envs=4), seed=1)
    assert env.h_bar.tolist() == pytest.approx([0.2] * len(env.objects.names))
    success, _, _ = run_episodes(env, agent.actor)
    assert not success.any()


@pytest.mark.parametrize("per_object", [False, True], ids=["one-target", "per-object"])
def test_resume_continues_bit_for_bit(
    builtin_data: Config, tmp_path: Path, per_object: bool
) -> None:
    # With a lift curriculum, whose target(s) are part of the state to restore.
    cfg = with_curriculum(
        tiny_config(builtin_data.data_dir, iterations=4), -1.0, 0.3, per_object=per_object
    )
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
    assert a["object_outcomes"] == b["object_outcomes"] and a["object_outcomes"]
    assert a["h_bar"] == b["h_bar"] and a["target_outcomes"] == b["target_outcomes"]
    assert [r["object_success_rate"] for r in rows] == [
        r["object_success_rate"] for r in straight_rows
    ]
    # each launch recorded its machine from the iteration it trained first (the killed one's
    # iteration 3 was redone by the resume)
    launches = read_launches(killed)
    assert [int(r["first_iteration"]) for r in launches] == [1, 3]
    assert launches[1]["cpu"] == cpu_model() and launches[1]["processes"] == "1"
    assert launches[1]["code"] == code_version()  # (this checkout's commit)


def test_object_success_rate_weighs_objects_equally() -> None:
    """A lifted object ends many short episodes, an object never lifted few long ones: over all
    ended episodes the rate is 0.9, the paper's mean over objects is 0.5."""
    outcomes = ObjectOutcomes(window=100)
    outcomes.extend([0] * 90 + [1] * 10, [True] * 90 + [False] * 10)
    assert outcomes.rate() == pytest.approx(0.5)
    outcomes.extend([1] * 100, [True] * 100)  # object 1's window is its last 100 episodes
    assert outcomes.rate() == pytest.approx(1.0)
    restored = ObjectOutcomes(window=100)
    restored.load_state_dict(outcomes.state_dict())
    assert restored.state_dict() == outcomes.state_dict() and restored.rate() == outcomes.rate()
    assert math.isnan(ObjectOutcomes(window=4).rate())


@pytest.mark.parametrize("fixed_drops", [False, True])
def test_bin_run_with_context_resumes_bit_for_bit(
    builtin_data: Config, tmp_path: Path, fixed_drops: bool
) -> None:
    """The bin task (5 of the built-in objects, the target's box, the other objects' boxes as
    context): a killed and resumed run ends exactly where an uninterrupted one does, targets,
    clutter and context encoder included; with ``[run] fixed_drops`` as well (the envs then
    keep their settled states: the resumed run's must be the same)."""
    cfg = load_train_config(
        env={"num_envs": 4, "task": "bin", "objects": "builtin", "context": "bbox",
             "data_dir": builtin_data.data_dir, "max_steps": 10,
             "bin": {"num_objects": 5, "layouts": 2, "bank_size": 4}},
        ppo={"frames_per_env": 8, "minibatches": 2, "min_minibatch": 1, "epochs": 2,
             "hidden": (32, 32, 32), "context_hidden": (16, 16)},
        run={"total_steps": 4 * 8 * 4, "checkpoint_every": 2, "seed": 3,
             "fixed_drops": fixed_drops},
    )
    assert cfg.env.representation == "bbox"  # the bin task's default
    straight = train(cfg, tmp_path / "straight", progress=False)
    killed = train(cfg, tmp_path / "killed", progress=False, stop_after=3)
    train(None, tmp_path / "killed", resume=True, progress=False)  # type: ignore[arg-type]
    a = torch.load(straight.checkpoints / "iter_000004.pt", weights_only=False)
    b = torch.load(killed.checkpoints / "iter_000004.pt", weights_only=False)
    assert any("context" in key for key in a["agent"])
    for key, value in a["agent"].items():
        assert torch.equal(value, b["agent"][key]), key
    assert (a["env"]["backend"]["state"] == b["env"]["backend"]["state"]).all()
    for key, value in a["env"]["state"].items():
        assert torch.equal(value, b["env"]["state"][key]), key
    assert a["env"]["state"]["target_slot"].max() < 5


def test_eval_counts_match_a_manual_count(builtin_data: Config, tmp_path: Path) -> None:
    cfg = tiny_config(builtin_data.data_dir, iterations=2)
    run = train(cfg, tmp_path / "run", progress=False)
    result = evaluate(run.path, episodes_per_object=3, seed=5)
    assert result.names == OBJECTS.split(",") and result.episodes == [3, 3]
    # The same episodes by hand: same seed, same deterministic policy.
    _, agent = load_agent(run.path)
    env = make_env(dataclasses.replace(cfg.env, num_envs=6), seed=5)
    success, length, _ = run_episodes(env, agent.actor)
    ids = env.target_objects()
    assert result.successes == [int(success[ids == k].sum()) for k in range(2)]
    assert (length <= cfg.env.max_steps).all() and (length >= 1).all()
    rows = list(csv.DictReader((run.path / "eval" / "per_object.csv").read_text().splitlines()))
    assert [r["object"] for r in rows] == result.names
    table = (run.path / "eval" / "table.md").read_text()
    assert "| **all (6 episodes)** |" in table
    # the machine and code that evaluated: another CPU model can end episodes differently
    from geomgrasp.machine import code_version, cpu_model
    assert table.splitlines()[-1].startswith(
        f"Evaluated on {cpu_model()} with code {code_version()}, 20")


def test_eval_of_a_chosen_checkpoint_and_success_criterion(
    builtin_data: Config, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys  # noqa: ANN001
) -> None:
    """--iteration evaluates that checkpoint, --hold-tips and --h-bar replace the run's success
    criterion, --out writes elsewhere than eval/; each bad value is a one-line error."""
    cfg = tiny_config(builtin_data.data_dir, iterations=3)  # checkpoints of iterations 2 and 3
    run = train(cfg, tmp_path / "run", progress=False)
    result = evaluate(run.path, episodes_per_object=3, seed=5, iteration=2, hold_tips=0,
                      h_bar=0.01, out="eval-it2")
    _, agent = load_agent(run.path, iteration=2)
    stored = torch.load(run.checkpoints / "iter_000002.pt", weights_only=False)["agent"]
    last = torch.load(run.last, weights_only=False)["agent"]
    for key, value in agent.state_dict().items():
        assert torch.equal(value, stored[key]), key
    assert any(not torch.equal(stored[k], last[k]) for k in stored)  # a different policy
    # The same episodes by hand, with any rise by 1 cm as success.
    reward = dataclasses.replace(cfg.env.reward, hold_tips=0, h_bar=0.01, h_bar_start=0.01)
    env_cfg = dataclasses.replace(cfg.env, num_envs=6, reward=reward)
    env = make_env(env_cfg, seed=5)
    success, _, _ = run_episodes(env, agent.actor)
    ids = env.target_objects()
    assert result.successes == [int(success[ids == k].sum()) for k in range(2)]
    table = (run.path / "eval-it2" / "table.md").read_text()
    assert "the checkpoint of iteration 2" in table
    assert "lifted by 0.01 m (held or not)" in table
    assert not (run.path / "eval").exists()
    code, out, _ = main(["eval", str(run.path), "--episodes-per-object", "1"], monkeypatch,
                        capsys)
    assert code == 0 and "while held" in out
    assert "the last checkpoint" in (run.path / "eval" / "table.md").read_text()
    code, out, _ = main(["eval", str(run.path), "--episodes-per-object", "1",
                         "--lift-clearance", "0.01", "--out", "eval-clear"], monkeypatch, capsys)
    assert code == 0 and "lifted by 0.2 m (its lowest point by 0.01 m) while held" in out
    for argv, expected in [
        (["--iteration", "7"], f"error: {run.path}: no checkpoint of iteration 7 (it has "
                               "iterations 2, 3)"),
        (["--iteration", "-1"], "error: --iteration -1: must be >= 0"),
        (["--iteration", "0"], f"error: {run.path} started from a fresh agent"),
        (["--hold-tips", "9"], "error: hold_tips = 9: must be >= 0 and <= 5"),
        (["--h-bar", "0"], "error: h_bar = 0"),
        (["--lift-clearance", "-0.01"], "error: lift_clearance = -0.01: must be >= 0"),
        (["--out", "../elsewhere"], "error: out '../elsewhere': give a folder name"),
    ]:
        code, _, err = main(["eval", str(run.path), *argv], monkeypatch, capsys)
        assert code == 1 and err.startswith(expected) and err.count("\n") == 1, err


@pytest.mark.slow
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
    held = "the target lifted by 0.2 m while held (2 or more fingertip pads"
    assert f"success: {held}" in result.output
    assert f"Success: {held}" in (run_dir / "eval" / "table.md").read_text()
    video = tmp_path / "play.gif"
    result = runner.invoke(cli, ["play", str(run_dir), "--object", "builtin_sphere",
                                 "--video", str(video), "--tries", "3"])
    assert result.exit_code == 0, result.output
    assert "builtin_sphere: success " in result.output and "/3, " in result.output
    assert video.stat().st_size > 1000
    result = runner.invoke(cli, ["report", str(run_dir), "--out", str(tmp_path / "report")])
    assert result.exit_code == 0, result.output
    assert "| sq | 1 |" in (tmp_path / "report" / "report.md").read_text()
    result = runner.invoke(cli, ["run", "--resume", str(tmp_path / "nothing")])
    assert result.exit_code != 0


# ---- resuming, rerunning and extending runs through the command line --------------------------


def main(argv: list[str], monkeypatch: pytest.MonkeyPatch, capsys) -> tuple[int, str, str]:  # noqa: ANN001
    """The real entry point, as the installed ``trainer`` script runs it: (exit code, stdout,
    stderr). Unlike click's test runner it does not turn an EOFError into "Aborted!" itself."""
    monkeypatch.setattr(sys, "argv", ["trainer", *argv])
    try:
        trainer_main()
        code = 0
    except SystemExit as exc:
        code = int(exc.code or 0)
    out = capsys.readouterr()
    return code, out.out, out.err


def metrics_iterations(run_dir: Path) -> list[int]:
    rows = csv.DictReader((run_dir / "metrics.csv").read_text().splitlines())
    return [int(r["iteration"]) for r in rows]


@pytest.fixture(scope="module")
def killed_run(builtin_data: Config, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 4-iteration run killed during iteration 4 (checkpoints at 2: iter_000002.pt, last.pt;
    metrics rows 1-3). Tests copy it."""
    path = tmp_path_factory.mktemp("killed") / "run"
    train(tiny_config(builtin_data.data_dir, iterations=4), path, progress=False, stop_after=3)
    return path


def test_init_agent_starts_from_another_runs_networks_and_normalizers(
    killed_run: Path, builtin_data: Config, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
    capsys,  # noqa: ANN001
) -> None:
    source = killed_run / "checkpoints" / "iter_000002.pt"
    before = torch.load(source, weights_only=False)["agent"]
    cfg = tiny_config(builtin_data.data_dir, iterations=1)
    cfg = dataclasses.replace(cfg, run=dataclasses.replace(cfg.run, seed=4))  # (not the source's)
    fresh = train(cfg, tmp_path / "fresh", progress=False)
    started = train(
        dataclasses.replace(cfg, run=dataclasses.replace(cfg.run, init_agent=str(source))),
        tmp_path / "started", progress=False,
    )
    after = {name: torch.load(run.last, weights_only=False)["agent"]
             for name, run in (("fresh", fresh), ("started", started))}
    # The normalizers continue the source's statistics: its count plus one iteration's.
    for key in ("obs_norm.proprio.count", "value_norm.count"):
        assert after["started"][key] == before[key] + after["fresh"][key], key
    # One update moves the weights a little: they stay near the source's, unlike a fresh run's.
    weights = [k for k, v in before.items() if v.dtype.is_floating_point and v.dim() == 2]
    assert weights
    for key in weights:
        moved = (after["started"][key] - before[key]).norm()
        assert moved < 0.5 * (after["fresh"][key] - before[key]).norm(), key
    assert json.loads(started.config.read_text())["run"]["init_agent"] == str(source)
    # The command line takes a run directory (its last checkpoint); a misfit is one line and
    # leaves no run behind.
    code, _, err = main(["run", "--init-agent", str(killed_run), "--objects", OBJECTS,
                         "--num-envs", "4", "--data-dir", str(builtin_data.data_dir),
                         "--steps", "32", "--run-dir", str(tmp_path / "cli")],
                        monkeypatch, capsys)
    assert code == 1 and err.startswith(f"error: init_agent {killed_run}: its agent does not "
                                        "fit this run's (")
    assert "network sizes" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "cli").exists()
    code, _, err = main(["run", "--init-agent", str(tmp_path / "nothing"), "--objects", OBJECTS,
                         "--data-dir", str(builtin_data.data_dir), "--run-dir",
                         str(tmp_path / "cli")], monkeypatch, capsys)
    assert code == 1 and "no such checkpoint file or run directory" in err


def test_iteration_0_is_the_agent_a_run_started_from(
    killed_run: Path, builtin_data: Config, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
    capsys,  # noqa: ANN001
) -> None:
    """``--iteration 0`` evaluates the agent a run started from (its init_agent, before any
    update), into eval-start/; a run that started fresh has none: one line."""
    from trainer.training.checkpoint import load_agent

    source = killed_run / "checkpoints" / "iter_000002.pt"
    cfg = tiny_config(builtin_data.data_dir, iterations=1)
    started = train(
        dataclasses.replace(cfg, run=dataclasses.replace(cfg.run, init_agent=str(source))),
        tmp_path / "started", progress=False,
    )
    _, agent = load_agent(started.path, "cpu", iteration=0)
    before = torch.load(source, weights_only=False)["agent"]
    assert all(torch.equal(v, before[k]) for k, v in agent.state_dict().items())
    _, trained = load_agent(started.path, "cpu")
    assert not all(torch.equal(v, before[k]) for k, v in trained.state_dict().items())
    code, out, _ = main(["eval", str(started.path), "--iteration", "0",
                         "--episodes-per-object", "1"], monkeypatch, capsys)
    assert code == 0 and "overall" in out
    table = (started.path / "eval-start" / "table.md").read_text()
    assert "the agent the run started from" in table
    assert not (started.path / "eval").exists()
    fresh = train(cfg, tmp_path / "fresh", progress=False)
    code, _, err = main(["eval", str(fresh.path), "--iteration", "0"], monkeypatch, capsys)
    assert code == 1 and "started from a fresh agent" in err and len(err.strip().splitlines()) == 1


def test_copy_agent_parts_takes_only_the_named_parts(builtin_data: Config) -> None:
    cfg = tiny_config(builtin_data.data_dir)
    spec = observation_spec(cfg.env, 1)["observation"]
    torch.manual_seed(0)
    source = Agent(spec, cfg.ppo)
    with torch.no_grad():  # normalizers and std that differ from a fresh agent's
        for key, value in source.state_dict().items():
            if agent_part(key) != "networks":
                value.add_(1.0)
    torch.manual_seed(1)
    target = Agent(spec, cfg.ppo)
    fresh = {k: v.clone() for k, v in target.state_dict().items()}
    copy_agent_parts(source, target, ("networks", "normalizers"))
    theirs, after = source.state_dict(), target.state_dict()
    parts = {agent_part(key) for key in after}
    assert parts == {"networks", "action_std", "normalizers"}
    for key, value in after.items():
        expected = fresh[key] if agent_part(key) == "action_std" else theirs[key]
        assert torch.equal(value, expected), key
    # Every key naming one tensor (the actor's and the policy net's std, ...) stays consistent.
    assert torch.equal(after["policy_net.log_std"], after["actor.module.0.module.log_std"])
    assert torch.equal(after["obs_norm.proprio.mean"],
                      after["critic.module.encoder.norm.proprio.mean"])
    assert agent_part("critic_denorm.module.value_norm.count") == "normalizers"
    assert agent_part("critic_denorm.module.value_net.body.0.weight") == "networks"


@pytest.mark.parametrize("representation", ["bbox", "pc32"])
def test_silence_unseen_features_keeps_the_agent_and_ignores_what_it_never_saw_vary(
    representation: str,
) -> None:
    # An agent trained on one object has seen its bbox extents only as one constant: the
    # normalizer maps them to 0 and their first-layer weights never train. Silenced, the agent
    # computes exactly what it did on its own observations and nothing from those features.
    from trainer.tasks.spec import observation_spec

    cfg = load_train_config(env={"representation": representation, "num_envs": 4},
                            ppo={"hidden": (32, 32, 32), "pointnet_hidden": (16, 16)})
    spec = observation_spec(cfg.env, num_envs=64)["observation"]
    torch.manual_seed(0)
    agent = Agent(spec, cfg.ppo)
    assert agent.silence_unseen_features() == 0  # fresh normalizers: nothing seen, nothing known
    proprio = torch.randn(64, *spec["proprio"].shape[1:])
    obj = torch.randn(64, *spec["object"].shape[1:])
    constant = [7, 8, 9] if representation == "bbox" else [2]  # extents / every point's z
    obj[..., constant] = 0.3
    agent.obs_norm.update(proprio, obj)
    before = (agent.policy_net(proprio, obj)[0], agent.value_net(proprio, obj))
    assert agent.silence_unseen_features() == len(constant)
    after = (agent.policy_net(proprio, obj)[0], agent.value_net(proprio, obj))
    for a, b in zip(before, after, strict=True):
        torch.testing.assert_close(a, b, rtol=0, atol=0)
    other = obj.clone()
    other[..., constant] = 2.0  # another object: clipped to +5 by the normalizer
    assert agent.obs_norm.object(other)[..., constant].eq(5.0).all()
    for a, b in zip(after, (agent.policy_net(proprio, other)[0], agent.value_net(proprio, other)),
                    strict=True):
        torch.testing.assert_close(a, b, rtol=0, atol=0)
    # A feature it saw vary still matters.
    varied = obj.clone()
    varied[..., 0] += 1.0
    assert not torch.equal(agent.policy_net(proprio, varied)[0], after[0])


def test_init_agent_unseen_silence_is_a_config_of_a_started_run(
    killed_run: Path, builtin_data: Config, tmp_path: Path, capsys  # noqa: ANN001
) -> None:
    cfg = tiny_config(builtin_data.data_dir, iterations=1)
    source = killed_run / "checkpoints" / "iter_000002.pt"
    silenced = dataclasses.replace(cfg.run, init_agent=str(source), init_agent_unseen="silence")
    train(dataclasses.replace(cfg, run=silenced), tmp_path / "started", progress=False)
    out, err = capsys.readouterr()
    assert "observation features it never saw vary silenced" in out + err
    with pytest.raises(TrainerError, match="init_agent_unseen.*set init_agent or warmup_objects"):
        dataclasses.replace(cfg.run, init_agent_unseen="silence")
    with pytest.raises(TrainerError, match="init_agent_unseen.*keep networks and normalizers"):
        dataclasses.replace(silenced, init_agent_parts=("networks", "action_std"))
    with pytest.raises(TrainerError, match="init_agent_unseen"):
        dataclasses.replace(silenced, init_agent_unseen="zero")


def test_a_policy_without_context_starts_a_run_with_context_unchanged() -> None:
    """``with_context_added``: a lift policy (no context) grafted onto the same agent with
    context computes the same actions and values whatever the context holds, and the context's
    inputs train from the first update; any other difference is not grafted."""
    from torchrl.data import Composite, Unbounded

    from trainer.config import PPOConfig
    from trainer.training.checkpoint import with_context_added

    def spec(context: bool) -> Composite:
        parts = {"proprio": Unbounded((4, 20)), "object": Unbounded((4, 10))}
        if context:
            parts |= {"context": Unbounded((4, 3, 10)),
                      "context_mask": Unbounded((4, 3), dtype=torch.bool)}
        return Composite(parts, shape=(4,))

    torch.manual_seed(0)
    lift, bin_agent = Agent(spec(False), PPOConfig()), Agent(spec(True), PPOConfig())
    with torch.no_grad():  # a trained policy's normalizers, not the identity
        lift.obs_norm.proprio.update(torch.randn(64, 20) * 3 + 1)
        lift.obs_norm.object.update(torch.randn(64, 10) * 0.1)
    grafted = with_context_added(bin_agent.state_dict(), lift.state_dict())
    assert grafted is not None
    bin_agent.load_state_dict(grafted)
    proprio, obj = torch.randn(8, 20), torch.randn(8, 10)
    context, mask = torch.randn(8, 3, 10) * 5, torch.rand(8, 3) > 0.3
    loc, scale = bin_agent.policy_net(proprio, obj, context, mask)
    torch.testing.assert_close((loc, scale), lift.policy_net(proprio, obj))
    torch.testing.assert_close(bin_agent.value_net(proprio, obj, context, mask),
                               lift.value_net(proprio, obj))
    loc.square().sum().backward()
    first = bin_agent.policy_net.body[0].weight
    width = PPOConfig().context_hidden[-1]
    assert first.grad[:, first.shape[1] - width:].abs().sum() > 0  # the context's columns learn
    # Not a context added: no graft (init_agent_from's one-line misfit error then).
    assert with_context_added(lift.state_dict(), bin_agent.state_dict()) is None
    assert with_context_added(lift.state_dict(), lift.state_dict()) is None
    wider = Agent(spec(True), PPOConfig(hidden=(128, 128, 64)))
    assert with_context_added(wider.state_dict(), lift.state_dict()) is None


def test_init_agent_parts_keeps_the_runs_own_fresh_normalizers(
    killed_run: Path, builtin_data: Config, tmp_path: Path, capsys  # noqa: ANN001
) -> None:
    source = killed_run / "checkpoints" / "iter_000002.pt"
    before = torch.load(source, weights_only=False)["agent"]
    cfg = tiny_config(builtin_data.data_dir, iterations=1)
    cfg = dataclasses.replace(cfg, run=dataclasses.replace(cfg.run, seed=4))
    fresh = train(cfg, tmp_path / "fresh", progress=False)
    networks_only = dataclasses.replace(cfg.run, init_agent=str(source),
                                        init_agent_parts=("networks",))
    started = train(dataclasses.replace(cfg, run=networks_only), tmp_path / "started",
                    progress=False)
    after = {name: torch.load(run.last, weights_only=False)["agent"]
             for name, run in (("fresh", fresh), ("started", started))}
    # Its normalizers are its own, fresh ones (their counts a fresh run's, not the source's
    # plus those), its weights near the source's.
    for key in ("obs_norm.proprio.count", "value_norm.count"):
        assert after["started"][key] == after["fresh"][key] < before[key], key
    key = "policy_net.body.0.weight"
    moved = (after["started"][key] - before[key]).norm()
    assert moved < 0.5 * (after["fresh"][key] - before[key]).norm()
    out, err = capsys.readouterr()
    assert "its networks only" in out + err
    with pytest.raises(TrainerError, match="init_agent_parts"):
        dataclasses.replace(cfg.run, init_agent_parts=("networks", "weights"))


def test_warmup_trains_its_objects_first_then_the_run_from_that_agent(
    builtin_data: Config, tmp_path: Path, capsys  # noqa: ANN001
) -> None:
    cfg = tiny_config(builtin_data.data_dir, iterations=2)
    cfg = dataclasses.replace(
        cfg, env=dataclasses.replace(cfg.env, objects="builtin_sphere"),
        run=dataclasses.replace(cfg.run, warmup_objects="builtin_cylinder", warmup_steps=3 * 32),
    )
    run = train_run(cfg, tmp_path / "warmed", progress=False)
    warm = json.loads((run.warmup / "config.json").read_text())
    assert warm["env"]["objects"] == "builtin_cylinder" and warm["run"]["total_steps"] == 96
    assert warm["run"]["warmup_steps"] == 0
    assert metrics_iterations(run.warmup) == [1, 2, 3] and metrics_iterations(run.path) == [1, 2]
    # The run's clock goes on from the warmup's (its time budget counts both).
    warm_rows = list(csv.DictReader((run.warmup / "metrics.csv").read_text().splitlines()))
    rows = list(csv.DictReader(run.metrics.read_text().splitlines()))
    assert float(rows[0]["wall_time_s"]) > float(warm_rows[-1]["wall_time_s"])
    assert f"agent: initialised from {run.warmup} (iteration 3)" in capsys.readouterr().out
    # Exactly the two runs by hand: the warmup's config, then the run started from its agent.
    by_hand = train(warmup_config(cfg), tmp_path / "by-hand-warmup", progress=False)
    plain = dataclasses.replace(cfg.run, warmup_objects="", warmup_steps=0,
                                init_agent=str(by_hand.path))
    then = train(dataclasses.replace(cfg, run=plain), tmp_path / "by-hand", progress=False)
    a = torch.load(run.last, weights_only=False)["agent"]
    b = torch.load(then.last, weights_only=False)["agent"]
    assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)
    # A run stopped while warming up (its time budget) resumes there, then runs on: the same.
    short = dataclasses.replace(cfg, run=dataclasses.replace(cfg.run, max_minutes=1e-6))
    stopped = train_run(short, tmp_path / "stopped", progress=False)
    assert metrics_iterations(stopped.warmup) == [1] and not stopped.has_checkpoint()
    assert "stopped while warming up" in capsys.readouterr().out
    longer = dataclasses.replace(cfg, run=dataclasses.replace(cfg.run, max_minutes=60.0))
    train_run(longer, stopped.path, resume=True, progress=False)
    c = torch.load(stopped.last, weights_only=False)["agent"]
    assert all(torch.equal(a[k], c[k]) for k in a)
    with pytest.raises(TrainerError, match="warmup_steps"):
        dataclasses.replace(cfg.run, warmup_steps=0)
    with pytest.raises(TrainerError, match="drop one of the two"):
        dataclasses.replace(cfg.run, init_agent="runs/x")


def test_a_warmup_stopped_by_a_signal_names_its_run_to_resume(
    builtin_data: Config, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys  # noqa: ANN001
) -> None:
    class TermAtOnce(StopSignals):
        """SIGTERM arrives in the first iteration of the (warmup's) training loop."""

        def __enter__(self) -> StopSignals:
            super().__enter__()
            os.kill(os.getpid(), signal.SIGTERM)
            return self

    delivered: list[int] = []  # (the re-raised SIGTERM lands here instead of ending pytest)
    previous = signal.signal(signal.SIGTERM, lambda signum, frame: delivered.append(signum))
    monkeypatch.setattr("trainer.ppo.StopSignals", TermAtOnce)
    try:
        cfg = tiny_config(builtin_data.data_dir, iterations=2)
        cfg = dataclasses.replace(
            cfg, env=dataclasses.replace(cfg.env, objects="builtin_sphere"),
            run=dataclasses.replace(cfg.run, warmup_objects="builtin_cylinder",
                                    warmup_steps=3 * 32),
        )
        run = train_run(cfg, tmp_path / "warmed", progress=False)
    finally:
        signal.signal(signal.SIGTERM, previous)
    assert delivered == [signal.SIGTERM]
    assert metrics_iterations(run.warmup) == [1] and not run.has_checkpoint()
    out, err = capsys.readouterr()
    hints = [line for line in (out + err).splitlines() if "--resume" in line]
    # Resuming the warmup's folder would train the warmup alone and never reach the run.
    assert hints and all(line.rstrip().endswith(f"--resume {run.path}") for line in hints), hints
    assert all(f"--resume {run.warmup}" not in line for line in hints), hints


@pytest.mark.parametrize("damage", ["empty", "truncated"])
def test_resume_falls_back_from_an_unreadable_last_checkpoint(
    killed_run: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys, damage: str  # noqa: ANN001
) -> None:
    run_dir = tmp_path / "run"
    shutil.copytree(killed_run, run_dir)
    last = run_dir / "checkpoints" / "last.pt"
    data = last.read_bytes()
    last.write_bytes(b"" if damage == "empty" else data[: len(data) // 2])
    # An empty last.pt used to end as "aborted" (click's reading of an EOFError, as Ctrl-C).
    code, _, err = main(["run", "--resume", str(run_dir)], monkeypatch, capsys)
    assert code == 0, err
    warning = next(line for line in err.splitlines() if line.startswith("warning:"))
    assert "unreadable last.pt" in warning and "using iter_000002.pt (iteration 2)" in warning
    assert metrics_iterations(run_dir) == [1, 2, 3, 4]
    assert torch.load(last, weights_only=False)["iteration"] == 4


def test_resume_without_a_readable_checkpoint_is_one_line(
    killed_run: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys  # noqa: ANN001
) -> None:
    run_dir = tmp_path / "run"
    shutil.copytree(killed_run, run_dir)
    for path in (run_dir / "checkpoints").iterdir():
        path.write_bytes(b"")
    code, _, err = main(["run", "--resume", str(run_dir)], monkeypatch, capsys)
    assert code == 1 and err.strip() == (
        f"error: {run_dir / 'checkpoints'}: no readable checkpoint (last.pt (EOFError), "
        "iter_000002.pt (EOFError)): start the run again with --overwrite"
    )


def test_rerun_is_refused_and_overwrite_starts_clean(
    killed_run: Path, builtin_data: Config, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
    capsys,  # noqa: ANN001
) -> None:
    run_dir = tmp_path / "run"
    shutil.copytree(killed_run, run_dir)
    shutil.rmtree(run_dir / "checkpoints")  # killed before its first checkpoint
    config = tmp_path / "tiny.toml"
    config.write_text(
        "max_steps = 20\n[ppo]\nframes_per_env = 8\nminibatches = 2\nmin_minibatch = 1\n"
        "epochs = 1\nhidden = [32, 32, 32]\n"
    )
    argv = ["run", "--repr", "com", "--objects", OBJECTS, "--num-envs", "4", "--steps", "32",
            "--run-dir", str(run_dir), "--config", str(config), "--data-dir",
            str(builtin_data.data_dir)]
    code, _, err = main(argv, monkeypatch, capsys)
    # Rerunning used to append a second run's rows to metrics.csv.
    assert code == 1 and err.strip() == (
        f"error: {run_dir} already holds a run: start it afresh with --overwrite, or choose "
        "another --run-dir or --seed"
    )
    assert metrics_iterations(run_dir) == [1, 2, 3]
    code, _, err = main([*argv, "--overwrite"], monkeypatch, capsys)
    assert code == 0, err
    assert metrics_iterations(run_dir) == [1]
    assert json.loads((run_dir / "config.json").read_text())["env"]["representation"] == "com"
    # One 8-step iteration of 20-step episodes: no episode ended, so no success rate yet.
    assert "success=-" in err and "nan" not in err


def test_resume_with_steps_extends_the_run(
    killed_run: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys  # noqa: ANN001
) -> None:
    run_dir = tmp_path / "run"
    shutil.copytree(killed_run, run_dir)
    code, out, err = main(["run", "--resume", str(run_dir), "--steps", "160"], monkeypatch, capsys)
    assert code == 0, err
    assert "total steps 160, was 128" in out
    assert metrics_iterations(run_dir) == [1, 2, 3, 4, 5]
    assert json.loads((run_dir / "config.json").read_text())["run"]["total_steps"] == 160
    code, _, err = main(["run", "--resume", str(run_dir)], monkeypatch, capsys)
    assert code == 1 and err.strip() == (
        f"error: {run_dir} is complete (160 steps of 160): pass --steps with more than 160 to "
        "extend it"
    )


def test_time_budget_stops_with_a_checkpoint_and_resume_extends_it(
    builtin_data: Config, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys  # noqa: ANN001
) -> None:
    cfg = tiny_config(builtin_data.data_dir, iterations=4)
    cfg = dataclasses.replace(cfg, run=dataclasses.replace(cfg.run, max_minutes=1e-6))
    run = train(cfg, tmp_path / "run", progress=False)
    # The first iteration ends past 0.06 ms: stopped there, its checkpoint written (not only
    # every checkpoint_every = 2 iterations).
    assert metrics_iterations(run.path) == [1]
    assert torch.load(run.last, weights_only=False)["iteration"] == 1
    code, _, err = main(["run", "--resume", str(run.path)], monkeypatch, capsys)
    assert code == 1 and err.count("\n") == 1, err
    assert err.startswith(f"error: {run.path} has used its time budget (0.0 of 1e-06 minutes): "
                          "pass --minutes with more than 0.0 to extend it"), err
    code, out, err = main(["run", "--resume", str(run.path), "--minutes", "60"], monkeypatch,
                          capsys)
    assert code == 0, err
    assert "time budget 60 min, was 1e-06" in out
    assert metrics_iterations(run.path) == [1, 2, 3, 4]  # on to total_steps
    assert json.loads(run.config.read_text())["run"]["max_minutes"] == 60


def test_eval_and_play_bad_input_is_one_line(
    killed_run: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys  # noqa: ANN001
) -> None:
    run_dir = str(killed_run)
    for argv, expected in [
        (["play", run_dir, "--object", "no_such_object"], "error: unknown object"),
        (["play", run_dir, "--object", OBJECTS], f"error: --object {OBJECTS}: names several"),
        (["eval", run_dir, "--objects", "no_such_object"], "error: unknown object"),
    ]:
        code, _, err = main(argv, monkeypatch, capsys)
        assert code == 1 and err.startswith(expected) and err.count("\n") == 1, err
    # A run directory killed before its first checkpoint has nothing to evaluate.
    empty = tmp_path / "run"
    empty.mkdir()
    shutil.copy(killed_run / "config.json", empty)
    code, _, err = main(["eval", str(empty)], monkeypatch, capsys)
    assert code == 1 and err.startswith(f"error: {empty}: no checkpoint yet"), err


def test_per_object_curriculum_promotes_each_object_on_its_own_success() -> None:
    """Object 0 succeeds, object 1 does not: only object 0's target rises, and its window
    starts again; the state survives a checkpoint round trip."""
    reward = RewardConfig(
        h_bar_start=0.03, h_bar_increment=0.02, h_bar_promote=0.5, curriculum_per_object=True
    )
    curriculum = LiftCurriculum(reward, num_objects=3, window=64)
    assert curriculum.window == 22  # 64 episodes over 3 objects
    curriculum.record([0] * 21 + [1] * 22, [True] * 21 + [False] * 22)
    assert not curriculum.promote()  # object 0's window is not full yet
    curriculum.record([0], [True])
    assert curriculum.promote()
    assert curriculum.h_bars == pytest.approx([0.05, 0.03, 0.03])
    assert curriculum.targets() == pytest.approx([0.05, 0.03, 0.03])
    assert not curriculum.by_object.by_object[0]  # a new window at the new target
    assert curriculum.rate() == 0.0  # object 1's 0 of 22 (object 0 has no episode yet)
    restored = LiftCurriculum(reward, num_objects=3, window=64)
    restored.load_state_dict(curriculum.state_dict())
    assert restored.h_bars == curriculum.h_bars
    assert restored.by_object.state_dict() == curriculum.by_object.state_dict()
    # A checkpoint with one target for all objects does not resume a per-object run.
    with pytest.raises(TrainerError, match="curriculum_per_object"):
        restored.load_state_dict({"h_bar": 0.05, "target_outcomes": []})
    # Small windows are floored (16 episodes), and the global rule is unchanged.
    assert LiftCurriculum(reward, num_objects=10, window=64).window == 16
    single = LiftCurriculum(dataclasses.replace(reward, curriculum_per_object=False), 3, 4)
    single.record([0, 1, 2, 2], [True, True, False, False])
    assert single.promote() and single.targets() == pytest.approx(0.05)


def test_lift_targets_per_object_decide_success(builtin_data: Config) -> None:
    """Each env succeeds at its own object's target: a target below the start is reached at
    once (nothing held needed: hold_tips = 0), one 1 m up is not."""
    cfg = tiny_config(builtin_data.data_dir, iterations=1)
    reward = dataclasses.replace(cfg.env.reward, hold_tips=0)
    env = make_env(dataclasses.replace(cfg.env, reward=reward, num_envs=8), seed=0)
    names = env.objects.names
    targets = [-1.0 if k % 2 == 0 else 1.0 for k in range(len(names))]
    env.set_lift_target(targets)
    td = env.reset()
    td = env.step(td.set("action", env.hold_action()))["next"]
    object_id = td["object_id"][:, 0]
    assert len(set(object_id.tolist())) > 1
    assert td["success"][:, 0].tolist() == [k % 2 == 0 for k in object_id.tolist()]
    with pytest.raises(TrainerError, match="lift targets"):
        env.set_lift_target(targets[:-1])


def test_resume_refuses_a_run_that_predates_the_held_criterion(
    builtin_data: Config, tmp_path: Path
) -> None:
    """A run written before reward.hold_tips trained with any rise as success: resuming it with
    today's default would change its task mid-run, so it is refused until the value it ran
    with is written into its config.json."""
    cfg = tiny_config(builtin_data.data_dir, iterations=2)
    run = train(cfg, tmp_path / "old", progress=False, stop_after=2)
    values = json.loads(run.config.read_text())
    del values["env"]["reward"]["hold_tips"]
    run.config.write_text(json.dumps(values))
    extended = dataclasses.replace(cfg, run=dataclasses.replace(cfg.run, total_steps=4 * 8 * 3))
    with pytest.raises(TrainerError, match=r'predates env.reward.hold_tips.*"hold_tips": 0'):
        train(extended, run.path, resume=True, progress=False)
    values["env"]["reward"]["hold_tips"] = 0
    run.config.write_text(json.dumps(values))
    held_off = dataclasses.replace(
        extended, env=dataclasses.replace(
            cfg.env, reward=dataclasses.replace(cfg.env.reward, hold_tips=0)
        ),
    )
    train(held_off, run.path, resume=True, progress=False)
    rows = list(csv.DictReader(run.metrics.read_text().splitlines()))
    assert [int(r["iteration"]) for r in rows] == [1, 2, 3]


def test_stagger_episodes_spreads_the_first_episode_ends(builtin_data: Config) -> None:
    # ppo.stagger_episodes: the first episode of each env starts at a random step, so the
    # envs reach max_steps (20) in different steps; every later reset starts at step 0.
    cfg = tiny_config(builtin_data.data_dir)
    env = make_env(dataclasses.replace(cfg.env, num_envs=8), seed=0)
    env.stagger_next_reset()
    td = env.reset()
    start = env.state["step_count"].clone()
    assert ((start >= 0) & (start < 20)).all() and len(set(start.tolist())) > 2
    ended_at = torch.full((8,), -1)
    for step in range(1, 21):
        td = env.step(td.set("action", env.hold_action()))["next"]
        first = td["done"][:, 0] & (ended_at < 0)
        ended_at[first] = step
        td = env.reset(td.set("_reset", td["done"]))
    # Nothing is lifted by holding still: every env is cut at max_steps, after its own share.
    assert ended_at.tolist() == (20 - start).tolist()
    env.reset()
    assert (env.state["step_count"] == 0).all()
    env.close()


def test_training_staggers_only_a_fresh_run(builtin_data: Config, tmp_path: Path) -> None:
    cfg = tiny_config(builtin_data.data_dir, iterations=2)
    for stagger in (False, True):
        run_cfg = dataclasses.replace(
            cfg, ppo=dataclasses.replace(cfg.ppo, stagger_episodes=stagger)
        )
        run = train(run_cfg, tmp_path / str(stagger), progress=False)
        counts = torch.load(run.last, weights_only=False)["env"]["state"]["step_count"]
        # 16 steps of 20-step episodes: in lock step without staggering.
        assert (len(set(counts.tolist())) > 1) == stagger
