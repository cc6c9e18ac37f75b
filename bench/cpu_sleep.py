"""Would MuJoCo's sleeping islands make bin picking cheap enough on the CPU? A probe for issue 15
(bin >= 0.50 of lift env steps/s at 256 envs), not a backend.

The CPU backend (``trainer/sim/cpu.py``) steps every env from its saved state with
``mujoco.rollout``, so resting objects are woken at every control period and never sleep.
MuJoCo 4.0's ``mujoco.batch.Batch(persistent=True)`` keeps one MjData per simulation, which
sleeping needs. This bench builds the lift and bin envs as ``bench/env_throughput.py`` does
(256 envs, built-in objects, each task's default), takes each env's state after a few random
actions, and times physics-only stepping of the same models and states, controls held:

- ``rollout``: the backend's ``step_held`` (the baseline, same run);
- ``batch``: one persistent ``Batch`` per layout (``Batch`` needs one MjData layout per batch),
  the layouts' batches on a pool of ``--threads`` threads, sleep off, then sleep on
  (``mjENBL_SLEEP``, MuJoCo's default ``sleep_tolerance``).

With the controls held the hand stops moving, so nothing wakes the objects it does not already
touch: the sleep figures are an upper bound of what training would see.

    python bench/cpu_sleep.py [--envs 256] [--threads 2] [--blocks 6]
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

import mujoco
import numpy as np
import torch
from mujoco.batch import Batch

from trainer.config import load_env_config
from trainer.tasks import GraspTask, make_env

FULL = int(mujoco.mjtState.mjSTATE_FULLPHYSICS)
INTEGRATION = int(mujoco.mjtState.mjSTATE_INTEGRATION)
CONTROL = int(
    mujoco.mjtState.mjSTATE_CTRL
    | mujoco.mjtState.mjSTATE_MOCAP_POS
    | mujoco.mjtState.mjSTATE_MOCAP_QUAT
)
SLEEP = int(mujoco.mjtEnableBit.mjENBL_SLEEP)


def build(task: str, envs: int) -> GraspTask:
    """The task's env after 5 random actions (the hand off its start pose)."""
    env = make_env(load_env_config(task=task, num_envs=envs, objects="builtin"))
    td = env.reset()
    gen = torch.Generator().manual_seed(0)
    for _ in range(5):
        td["action"] = torch.rand(envs, 11, generator=gen) * 2 - 1
        _, td = env.step_and_maybe_reset(td)
    return env


def batches(env: GraspTask, sleep: bool) -> list[Batch]:
    """One persistent Batch per layout, holding that layout's envs' states and controls."""
    backend = env.backend
    state, control = backend.state_dict()["state"], backend._control[:, 0]
    out = []
    for k, model in enumerate(backend.models):
        model = model.__copy__()
        model.opt.enableflags = (model.opt.enableflags | SLEEP) if sleep else (
            model.opt.enableflags & ~SLEEP
        )
        ids = np.flatnonzero(backend.env_layout == k)
        batch = Batch(model, nsim=len(ids), nthread=1, persistent=True)
        data = mujoco.MjData(model)
        for row, env_id in enumerate(ids):
            mujoco.mj_setState(model, data, state[env_id], FULL)
            mujoco.mj_setState(model, data, control[env_id], CONTROL)
            mujoco.mj_getState(model, data, batch.state[row], INTEGRATION)
        out.append(batch)
    return out


def rate(step: Callable[[], None], envs: int, blocks: int, steps: int = 10) -> float:
    """Median env steps/s over ``blocks`` blocks of ``steps`` control periods (after one)."""
    step()
    rates = []
    for _ in range(blocks):
        start = time.perf_counter()
        for _ in range(steps):
            step()
        rates.append(envs * steps / (time.perf_counter() - start))
    return statistics.median(rates)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--envs", type=int, default=256)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--blocks", type=int, default=6)
    args = parser.parse_args()
    torch.set_num_threads(1)
    pool = ThreadPoolExecutor(args.threads)
    rates: dict[tuple[str, str], float] = {}
    for task in ("lift", "bin"):
        env = build(task, args.envs)
        substeps = env.backend.substeps
        rates[task, "rollout"] = rate(env.backend.step_held, args.envs, args.blocks)
        for sleep in (False, True):
            layouts = batches(env, sleep)

            def step(layouts: list[Batch] = layouts, nstep: int = substeps) -> None:
                list(pool.map(lambda b: b.step(nstep=nstep), layouts))

            rates[task, f"batch, sleep {'on' if sleep else 'off'}"] = rate(
                step, args.envs, args.blocks
            )
        env.close()
    kinds = ("rollout", "batch, sleep off", "batch, sleep on")
    print(f"physics-only steps/s, {args.envs} envs, {args.threads} threads, controls held")
    print(f"{'':18s}{'lift':>10s}{'bin':>10s}{'bin/lift':>10s}{'bin vs rollout':>16s}")
    for kind in kinds:
        lift, bin_ = rates["lift", kind], rates["bin", kind]
        print(f"{kind:18s}{lift:10,.0f}{bin_:10,.0f}{bin_ / lift:10.2f}"
              f"{bin_ / rates['bin', 'rollout']:16.2f}")


if __name__ == "__main__":
    main()
