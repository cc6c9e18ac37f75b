"""One seeded source of randomness per run (trainer.randomness): independent named streams, the
seeding of runs that predate them kept, and the env and PPO drawing from their own streams."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
import torch

from geomprep.config import Config
from trainer.config import config_dict, load_train_config, read_train_config
from trainer.ppo import make_agent, make_train_state
from trainer.randomness import STREAMS, RandomStreams, run_streams
from trainer.tasks import make_env


def test_streams_are_independent_reproducible_and_named() -> None:
    streams = RandomStreams(7)
    seeds = [streams.seed_of(name) for name in STREAMS]
    assert len(set(seeds)) == len(STREAMS)  # no two consumers share a sequence
    assert all(0 <= s < 2**63 for s in seeds)
    assert seeds == [RandomStreams(7).seed_of(name) for name in STREAMS]  # reproducible
    assert seeds != [RandomStreams(8).seed_of(name) for name in STREAMS]
    a = streams.torch("resets").get_state()
    assert torch.equal(a, RandomStreams(7).torch("resets").get_state())
    assert not torch.equal(a, streams.torch("shuffle").get_state())
    draws = streams.numpy("layouts").integers(1 << 30, size=4)
    assert (draws == RandomStreams(7).numpy("layouts").integers(1 << 30, size=4)).all()
    with pytest.raises(ValueError, match="unknown random stream 'layout'"):
        streams.seed_of("layout")


def test_legacy_streams_are_the_seed_itself() -> None:
    """Runs before the streams seeded every generator with the run's seed."""
    legacy = RandomStreams(5, legacy=True)
    assert {legacy.seed_of(name) for name in STREAMS} == {5}
    assert torch.equal(legacy.torch("shuffle").get_state(),
                       torch.Generator().manual_seed(5).get_state())
    assert (legacy.numpy("layouts").integers(100, size=8)
            == np.random.default_rng(5).integers(100, size=8)).all()


def test_a_config_json_without_random_streams_is_a_legacy_run(tmp_path: Path) -> None:
    cfg = load_train_config(run={"seed": 4})
    assert cfg.run.random_streams and not run_streams(cfg).legacy  # new runs derive streams
    path = tmp_path / "config.json"
    values = config_dict(cfg)
    path.write_text(json.dumps(values))
    assert read_train_config(path) == cfg
    del values["run"]["random_streams"]  # a run directory written before the streams
    path.write_text(json.dumps(values))
    old = read_train_config(path)
    assert old.run.random_streams is False and run_streams(old).legacy


def test_env_and_ppo_draw_from_their_own_streams(builtin_data: Config) -> None:
    """The env's resets and PPO's minibatch shuffle were two generators seeded with the same
    number (the same draws); now each has its own stream of the run's seed, and a legacy run's
    env still seeds as before."""
    cfg = load_train_config(
        env={"num_envs": 4, "objects": "builtin_cylinder,builtin_sphere",
             "data_dir": builtin_data.data_dir, "representation": "com", "max_steps": 10},
        ppo={"hidden": (8, 8, 8)}, run={"seed": 3},
    )
    env = make_env(cfg.env, seed=run_streams(cfg))
    state = make_train_state(cfg, env, make_agent(env, cfg.ppo), torch.optim.Adam([torch.ones(1)]))
    assert not torch.equal(env._rng.get_state(), state.shuffle.get_state())
    assert torch.equal(env._rng.get_state(), RandomStreams(3).torch("resets").get_state())
    env.set_seed(11)  # evaluation's episode seeding follows the env's streams
    assert torch.equal(env._rng.get_state(), RandomStreams(11).torch("resets").get_state())
    env.close()
    legacy_cfg = dataclasses.replace(cfg, run=dataclasses.replace(cfg.run, random_streams=False))
    legacy = make_env(legacy_cfg.env, seed=run_streams(legacy_cfg))
    assert torch.equal(legacy._rng.get_state(), torch.Generator().manual_seed(3).get_state())
    legacy.set_seed(11)
    assert torch.equal(legacy._rng.get_state(), torch.Generator().manual_seed(11).get_state())
    legacy.close()
