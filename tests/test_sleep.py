"""``[physics] sleep`` on the CPU backend: resting objects fall asleep, behave as awake ones did
(to a stated tolerance), wake when the hand touches them, and the option is refused where it
does not exist."""

from __future__ import annotations

import dataclasses

import mujoco
import numpy as np
import pytest
import torch

from geomprep.config import Config
from trainer.config import load_env_config
from trainer.errors import TrainerError
from trainer.grasps import run_scripted_grasp
from trainer.tasks import make_env
from trainer.tasks.base import GraspTask

HOLD_STEPS = 20
SAME_REST_M = 0.002
"""Objects at rest with and without sleep: within 2 mm after the same held steps (a sleeping
island stops where it fell asleep; an awake one creeps by micrometres, and the solver's warm
start differs between the two steppers)."""


def bin_env(data: Config, sleep: bool) -> GraspTask:
    cfg = load_env_config(
        task="bin", num_envs=8, objects="builtin", data_dir=data.data_dir,
        bin={"num_objects": 5, "layouts": 2, "bank_size": 4}, physics={"sleep": sleep},
    )
    return make_env(cfg, seed=5)


def hold(env: GraspTask, steps: int) -> None:
    td = env.reset()
    for _ in range(steps):
        td["action"] = torch.zeros(env.num_envs, 11)
        _, td = env.step_and_maybe_reset(td)


def test_resting_clutter_sleeps_and_stays_where_awake_clutter_rests(builtin_data: Config) -> None:
    awake, sleeping = bin_env(builtin_data, False), bin_env(builtin_data, True)
    hold(awake, HOLD_STEPS)
    hold(sleeping, HOLD_STEPS)
    a = awake.slot_poses(awake.backend.qpos)[..., :3]
    b = sleeping.slot_poses(sleeping.backend.qpos)[..., :3]
    assert float((a - b).abs().max()) < SAME_REST_M
    # The islands really sleep: most of the objects (one still rocking, or leaning on another
    # that is, keeps its island awake), never the robot (actuated: MuJoCo's policy "never").
    asleep = []
    for ids, batch in sleeping.backend._batches:
        data = mujoco.MjData(batch.model)
        for row in range(len(ids)):
            batch.get_data(row, data)
            asleep.append(np.asarray(data.tree_asleep) >= 0)
    asleep = np.stack(asleep)
    assert not asleep[:, 0].any()
    assert asleep[:, 1:].mean() >= 0.6, asleep
    awake.close()
    sleeping.close()


def test_sleeping_objects_wake_when_grasped(builtin_data: Config) -> None:
    """The scripted grasp's bar (8 of 10 lifted by 0.2 m) with sleep on: the hand's touch wakes
    the object it grasps."""
    cfg = load_env_config(
        num_envs=20, objects="builtin_cylinder,builtin_sphere", data_dir=builtin_data.data_dir,
        representation="com", physics={"sleep": True},
    )
    env = make_env(cfg, seed=11)
    lifted = run_scripted_grasp(env).numpy()
    ids = env.target_objects().numpy()
    env.close()
    counts = [int(lifted[ids == k].sum()) for k in range(2)]
    assert all(n >= 8 for n in counts), counts


def test_sleep_is_a_cpu_backend_option(builtin_data: Config) -> None:
    cfg = load_env_config(objects="builtin_box", data_dir=builtin_data.data_dir, num_envs=2)
    cfg = dataclasses.replace(
        cfg, backend="warp", physics=dataclasses.replace(cfg.physics, sleep=True)
    )
    with pytest.raises(TrainerError, match=r"sleep = true is an option of the cpu backend"):
        make_env(cfg)
