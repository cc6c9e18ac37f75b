"""A run spread over processes (torchrun; ``trainer.training.distributed``), on the CPU with gloo
and two processes: the averaged update is the one-process update of the whole batch, the
normalizers are the same on every rank, a two-rank run writes a run directory as one process
does and resumes under torchrun, and resuming with another number of processes is refused."""

from __future__ import annotations

import csv
import json
import os
import socket
import subprocess
import sys
from pathlib import Path

import pytest
import torch
import torch.distributed as dist
import torch.multiprocessing as mp
from tensordict import TensorDict

from geomprep.config import Config
from trainer.config import load_train_config
from trainer.errors import TrainerError
from trainer.models import Agent
from trainer.ppo import PPOUpdate, train
from trainer.randomness import RandomStreams
from trainer.tasks import make_env
from trainer.tasks.spec import observation_spec
from trainer.training import distributed

ROOT = Path(__file__).resolve().parents[1]
FRAMES = 64


def _agent_and_batch() -> tuple[Agent, PPOUpdate, TensorDict, torch.Tensor]:
    """An agent, its update (one minibatch of ``FRAMES``), a batch of ``FRAMES`` frames as the
    loss reads them, and observations for the normalizers: the same in every process."""
    cfg = load_train_config(env={"representation": "bbox"}, ppo={"hidden": (16, 16)})
    spec = observation_spec(cfg.env, num_envs=FRAMES)["observation"]
    torch.manual_seed(0)
    agent = Agent(spec, cfg.ppo)
    obs = {k: torch.randn(FRAMES, *spec[k].shape[1:]) * 2 + 1 for k in ("proprio", "object")}
    with torch.no_grad():
        batch = agent.actor(TensorDict(obs, batch_size=[FRAMES]))
    batch["action"] = batch["action"] + 0.3 * torch.randn_like(batch["action"])  # (off-policy)
    batch["advantage"] = torch.randn(FRAMES, 1) * 3 + 0.5
    batch["value_target"] = torch.randn(FRAMES, 1)
    update = PPOUpdate.build(agent, cfg.ppo, FRAMES)
    return agent, update, batch, obs["proprio"]


def _rank_update(rank: int, port: int, out: str) -> None:
    """Process ``rank`` of two: half the batch, averaged update; its agent's state to ``out``."""
    dist.init_process_group("gloo", init_method=f"tcp://127.0.0.1:{port}", rank=rank,
                            world_size=2)
    torch.set_num_threads(1)
    agent, update, batch, proprio = _agent_and_batch()
    update = PPOUpdate.build(agent, update.ppo, FRAMES // 2, distributed=True)
    half = slice(rank * FRAMES // 2, (rank + 1) * FRAMES // 2)
    for _ in range(3):
        update.step(batch[half].clone())
    agent.obs_norm.proprio.update(proprio[half], distributed.pool_moments)
    # a rank with no finite sample still joins the pooling
    empty = proprio[half] if rank == 0 else proprio[half] * float("nan")
    agent.value_norm.update(empty[:, :1], distributed.pool_moments)
    torch.save(agent.state_dict(), f"{out}/rank{rank}.pt")
    dist.destroy_process_group()


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_averaged_update_equals_one_process_update_of_the_whole_batch(tmp_path: Path) -> None:
    # Two ranks each with half of a minibatch: gradients averaged, advantages normalized over
    # both halves; three steps must land where one process lands on the whole minibatch, and
    # both ranks on the same parameters and normalizers, bit for bit.
    mp.spawn(_rank_update, args=(_free_port(), str(tmp_path)), nprocs=2, join=True)
    ranks = [torch.load(tmp_path / f"rank{r}.pt") for r in range(2)]
    for key, value in ranks[0].items():
        assert torch.equal(value, ranks[1][key]), key
    agent, update, batch, proprio = _agent_and_batch()
    before = {k: v.clone() for k, v in agent.state_dict().items()}
    for _ in range(3):
        update.step(batch.clone())
    agent.obs_norm.proprio.update(proprio)
    agent.value_norm.update(proprio[: FRAMES // 2, :1])
    moved = 0
    for key, value in agent.state_dict().items():
        torch.testing.assert_close(ranks[0][key], value, rtol=1e-4, atol=1e-5, msg=key)
        moved += int(not torch.equal(value, before[key]))
    assert moved > 10  # the steps and the normalizers did change the agent


def test_per_rank_streams_and_env_slices(builtin_data: Config) -> None:
    # Rank 0's streams are a one-process run's; rank 1's differ, except the layouts (every rank
    # places the objects alike); each rank's envs hold the objects of its slice of the
    # one-process run's envs.
    one, r0, r1 = RandomStreams(3), RandomStreams(3, rank=0), RandomStreams(3, rank=1)
    assert r0.seed_of("resets") == one.seed_of("resets")
    assert r1.seed_of("resets") != one.seed_of("resets")
    assert r1.seed_of("layouts") == one.seed_of("layouts")
    cfg = load_train_config(env={"num_envs": 6, "objects": "builtin_cylinder,builtin_sphere,"
                                 "builtin_dice", "representation": "com",
                                 "data_dir": builtin_data.data_dir, "max_steps": 20})
    whole = make_env(cfg.env, seed=one).target_objects().tolist()
    halves = []
    for rank in range(2):
        env = make_env(cfg.env, seed=RandomStreams(3, rank=rank), shard=(rank, 2))
        assert env.num_envs == 3 and env.run_envs == 6
        halves += env.target_objects().tolist()
        env.close()
    assert halves == whole and len(set(whole)) == 3
    with pytest.raises(TrainerError, match="num_envs 6 does not divide among 4 processes"):
        distributed.local_envs(6, 4)


def _tiny_toml(path: Path, data_dir: Path) -> Path:
    path.write_text(f"""num_envs = 4
objects = "builtin_cylinder,builtin_sphere"
representation = "com"
data_dir = "{data_dir}"
max_steps = 20
nthread = 1
[ppo]
frames_per_env = 8
minibatches = 2
min_minibatch = 1
epochs = 2
hidden = [32, 32, 32]
[run]
total_steps = 64
checkpoint_every = 1
seed = 3
""")
    return path


def _trainer(args: list[str], nproc: int | None) -> subprocess.CompletedProcess[str]:
    """``trainer ARGS`` as a subprocess: under ``torchrun --standalone --nproc_per_node
    NPROC``, or plain (``nproc`` None)."""
    launch = [sys.executable, "-m", "trainer.cli"]
    if nproc is not None:
        launch = [sys.executable, "-m", "torch.distributed.run", "--standalone",
                  f"--nproc_per_node={nproc}", "-m", "trainer.cli"]
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1"}
    env.pop("WORLD_SIZE", None)
    return subprocess.run([*launch, *args], capture_output=True, text=True, env=env,
                          timeout=240, cwd=ROOT)


def _files(path: Path) -> list[str]:
    return sorted(str(p.relative_to(path)) for p in path.rglob("*")
                  if p.is_file() and "tb" not in p.parts)


@pytest.mark.slow
def test_two_rank_run_writes_the_run_and_resumes_under_torchrun(
    builtin_data: Config, tmp_path: Path
) -> None:
    toml = _tiny_toml(tmp_path / "tiny.toml", builtin_data.data_dir)
    two = tmp_path / "two"
    done = _trainer(["run", "--config", str(toml), "--run-dir", str(two), "--no-compile"], 2)
    assert done.returncode == 0, done.stderr[-3000:]
    assert done.stdout.count("run: ") == 1  # rank 0 alone speaks
    one = train(load_train_config(toml), tmp_path / "one", progress=False)
    assert _files(two) == _files(one.path)
    assert json.loads((two / "config.json").read_text())["run"]["world_size"] == 2
    assert json.loads(one.config.read_text())["run"]["world_size"] == 1
    rows = list(csv.DictReader((two / "metrics.csv").read_text().splitlines()))
    assert [int(r["env_steps"]) for r in rows] == [32, 64]  # both ranks' envs counted
    last = torch.load(two / "checkpoints" / "last.pt", weights_only=False)
    assert len(last["ranks"]) == 1  # rank 1's envs and generators beside rank 0's
    assert last["ranks"][0]["env"]["state"].batch_size == last["env"]["state"].batch_size == (2,)
    assert not torch.equal(last["ranks"][0]["torch_rng"], last["torch_rng"])

    # Another number of processes is refused in one line, naming both.
    wrong = _trainer(["run", "--resume", str(two), "--steps", "128"], None)
    assert wrong.returncode == 1
    assert wrong.stderr.strip().count("\n") == 0, wrong.stderr
    assert "2 processes" in wrong.stderr and "has 1" in wrong.stderr

    more = _trainer(["run", "--resume", str(two), "--steps", "128"], 2)
    assert more.returncode == 0, more.stderr[-3000:]
    rows = list(csv.DictReader((two / "metrics.csv").read_text().splitlines()))
    assert [int(r["iteration"]) for r in rows] == [1, 2, 3, 4]
    assert (two / "checkpoints" / "iter_000004.pt").is_file()
