"""The MuJoCo C backend (``trainer/sim/cpu.py``) where MuJoCo refuses to step a state: a pile
whose constraint rows outgrow the model's arena stops MuJoCo with ``mj_stackAlloc: out of
memory`` (a bin training run died of it, 2026-11-30). The env is left unstepped (stalled, so the
task resets it), the others step as usual, and the backend says how many and which knob."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
import torch

from trainer.sim.cpu import FULL, MujocoCPUBackend

BOXES = 6


def pile_model(memory: str) -> mujoco.MjModel:
    """Six free boxes over a plane, no-slip on (its dense matrices are what overflow)."""
    bodies = "".join(
        f'<body pos="{0.5 * i} 0 0.3"><freejoint/><geom type="box" size="0.05 0.05 0.05"/></body>'
        for i in range(BOXES))
    return mujoco.MjModel.from_xml_string(
        f'<mujoco><option cone="elliptic" noslip_iterations="5"/><size memory="{memory}"/>'
        f'<worldbody><geom type="plane" size="2 2 .1"/>{bodies}</worldbody></mujoco>')


def backend(memory: str, sleep: bool) -> MujocoCPUBackend:
    """Four envs of the boxes apart in the air; envs 1 and 2 get the boxes stacked on the
    plane (the pile's contacts need more than 60 KB of arena)."""
    model = pile_model(memory)
    sim = MujocoCPUBackend([model], np.zeros(4, dtype=np.int64), substeps=5, nthread=2,
                           sleep=sleep)
    qpos = sim.qpos.double().clone()
    for i in range(BOXES):
        qpos[1:3, 7 * i: 7 * i + 3] = torch.tensor([0.0, 0.0, 0.05 + 0.1 * i],
                                                   dtype=torch.float64)
    sim.set_state(torch.arange(4), qpos, torch.zeros(4, model.nv), torch.zeros(4, 0))
    return sim


@pytest.mark.parametrize("sleep", [False, True], ids=["rollout", "sleep-batches"])
def test_a_state_mujoco_cannot_step_is_left_stalled_and_counted(sleep: bool) -> None:
    sim = backend("60K", sleep)
    before = sim.qpos.clone()
    sim.step(torch.zeros(4, 0))
    time = torch.from_numpy(sim.state_dict()["state"][:, 0])
    assert time[[0, 3]].gt(0).all() and time[[1, 2]].eq(0).all()
    assert sim.unstable().tolist() == [False, True, True, False]  # the task resets 1 and 2
    assert torch.equal(sim.qpos[1:3], before[1:3])
    assert not torch.equal(sim.qpos[[0, 3]], before[[0, 3]])  # the free boxes fell
    [line] = sim.drain_warnings()
    assert line.startswith("MuJoCo could not step 2 env step(s) (mj_stackAlloc: out of memory")
    assert "raise [physics] memory_mb" in line
    assert sim.drain_warnings() == []  # counted once
    # Reset to states it can step, the same envs go on (a fresh MjData where one failed).
    sim.set_state(torch.arange(4), before[[0, 0, 0, 0]].double(), torch.zeros(4, sim.nv),
                  torch.zeros(4, 0))
    sim.step(torch.zeros(4, 0))
    assert not sim.unstable().any() and sim.drain_warnings() == []
    sim.close()


def test_the_arena_that_holds_the_pile_steps_it_as_one_run_of_every_env() -> None:
    # With room for the pile, every env steps; the envs refused above step as they would alone.
    sim = backend("4M", sleep=False)
    start = sim.state_dict()["state"][1]
    sim.step(torch.zeros(4, 0))
    assert not sim.unstable().any() and sim.drain_warnings() == []
    alone = pile_model("4M")
    data = mujoco.MjData(alone)
    mujoco.mj_setState(alone, data, start, FULL)
    for _ in range(5):
        mujoco.mj_step(alone, data)
    np.testing.assert_array_equal(sim.state_dict()["state"][1, 1: 1 + alone.nq], data.qpos)
    sim.close()
