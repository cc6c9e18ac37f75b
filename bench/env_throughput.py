"""Environment steps per second of ``GraspEnv`` next to raw MuJoCo stepping of the same models.

For each env count and representation: the full env step (JT control in torch, batched physics,
observations, reward), and in the same run the backend stepping the same models with the same
substeps and held controls and nothing else. Prints both and the ratio (target >= 0.70).

    python bench/env_throughput.py [--envs 64,256,1024] [--reprs com,sdf,...] [--objects builtin]
                                   [--no-compile]
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import time

import torch

from trainer.config import REPRESENTATIONS, load_env_config
from trainer.env import GraspEnv


def measure(env: GraspEnv, steps: int, rounds: int) -> tuple[float, float]:
    """(env steps/s, raw steps/s), each env step = one action of every env.

    Env and raw stepping alternate in ``rounds`` blocks of ``steps`` each, and each rate is the
    median over its blocks, so that a slow moment of the machine hits both alike."""
    td = env.reset()
    gen = torch.Generator().manual_seed(0)
    actions = [torch.rand(env.num_envs, 11, generator=gen) * 2 - 1 for _ in range(steps)]
    for action in actions[:3]:  # warm-up (and compilation, with --compile)
        td["action"] = action
        _, td = env.step_and_maybe_reset(td)
    env_rates, raw_rates = [], []
    for _ in range(rounds):
        start = time.perf_counter()
        for action in actions:
            # What a collector does: step, then reset the envs that are done.
            td["action"] = action
            _, td = env.step_and_maybe_reset(td)
        env_rates.append(env.num_envs * steps / (time.perf_counter() - start))
        start = time.perf_counter()
        for _ in range(steps):
            env.backend.raw_step()
        raw_rates.append(env.num_envs * steps / (time.perf_counter() - start))
    return statistics.median(env_rates), statistics.median(raw_rates)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--envs", default="64,256,1024")
    parser.add_argument("--reprs", default=",".join(REPRESENTATIONS))
    parser.add_argument("--objects", default="builtin")
    parser.add_argument("--robot", default="ur5e")
    parser.add_argument("--steps", type=int, default=20, help="env steps per timed block")
    parser.add_argument("--rounds", type=int, default=5, help="alternating env/raw blocks")
    parser.add_argument(
        "--compile", action=argparse.BooleanOptionalAction, default=True,
        help="torch.compile the task computations (EnvConfig.compile)",
    )
    args = parser.parse_args()
    torch.set_num_threads(1)
    print(f"{'envs':>6} {'repr':>6} {'env steps/s':>12} {'raw steps/s':>12} {'ratio':>6}")
    for n in (int(v) for v in args.envs.split(",")):
        for rep in args.reprs.split(","):
            cfg = load_env_config(num_envs=n, representation=rep, objects=args.objects)
            cfg = dataclasses.replace(
                cfg, robot=dataclasses.replace(cfg.robot, kind=args.robot), compile=args.compile
            )
            env = GraspEnv(cfg)
            env_rate, raw_rate = measure(env, args.steps, args.rounds)
            env.close()
            ratio = env_rate / raw_rate
            print(f"{n:>6} {rep:>6} {env_rate:>12.0f} {raw_rate:>12.0f} {ratio:>6.2f}")


if __name__ == "__main__":
    main()
