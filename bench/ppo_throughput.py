"""Training frames per second of ``trainer run`` next to env-only frames per second, same run.

env-only: the collector stepping the environments with the (untrained) policy and nothing else;
training: the whole PPO iteration (collection, GAE, the minibatch epochs, normalizer updates,
logging). Prints both and the ratio (target >= 0.50: learning must not dominate the cost).

    python bench/ppo_throughput.py [--task lift|bin] [--envs 64,256] [--repr com]
                                   [--bin-objects 5] [--iterations 5] [--no-compile]

``--repr default`` uses the task's own representation (sq for lift, bbox for bin).
"""

from __future__ import annotations

import argparse
import csv
import tempfile
import time
from pathlib import Path

import torch
from torchrl.collectors import Collector

from trainer.config import load_train_config
from trainer.models import Agent
from trainer.ppo import iteration_frames, train
from trainer.tasks import make_env


def env_only_rate(cfg, iterations: int) -> float:  # noqa: ANN001
    env = make_env(cfg.env, seed=cfg.run.seed)
    agent = Agent(env.observation_spec, cfg.ppo)
    frames = iteration_frames(cfg)
    collector = Collector(env, agent.actor, frames_per_batch=frames, total_frames=-1,
                          auto_register_policy_transforms=False)
    batches = iter(collector)
    next(batches)  # warm-up
    start = time.perf_counter()
    for _ in range(iterations):
        next(batches)
    rate = iterations * frames / (time.perf_counter() - start)
    collector.shutdown()
    env.close()
    return rate


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="lift", choices=("lift", "bin"))
    parser.add_argument("--envs", default="64,256")
    parser.add_argument("--repr", default="com", help="'default': the task's own")
    parser.add_argument("--objects", default="builtin")
    parser.add_argument("--bin-objects", type=int, default=5, help="objects per bin (bin task)")
    parser.add_argument("--iterations", type=int, default=5)
    parser.add_argument(
        "--compile", action=argparse.BooleanOptionalAction, default=True,
        help="torch.compile the env's task computations (trainer run --compile)",
    )
    args = parser.parse_args()
    torch.set_num_threads(1)
    print(f"{'task':>5} {'envs':>6} {'repr':>6} {'train frames/s':>15} "
          f"{'env-only frames/s':>18} {'ratio':>6}")
    for n in (int(v) for v in args.envs.split(",")):
        env = {"task": args.task, "num_envs": n, "objects": args.objects, "compile": args.compile}
        if args.repr != "default":
            env["representation"] = args.repr
        if args.task == "bin":
            env["bin"] = {"num_objects": args.bin_objects}
        frames = iteration_frames(load_train_config(env=env))
        cfg = load_train_config(
            env=env,
            run={"total_steps": frames * (args.iterations + 1), "checkpoint_every": 10**9},
        )
        env_rate = env_only_rate(cfg, args.iterations)
        with tempfile.TemporaryDirectory() as tmp:
            run = train(cfg, Path(tmp) / "run", progress=False)
            rows = list(csv.DictReader(run.metrics.read_text().splitlines()))
        # Skip the first iteration (set-up, first collector reset), as for env-only.
        seconds = float(rows[-1]["wall_time_s"]) - float(rows[0]["wall_time_s"])
        train_rate = (len(rows) - 1) * iteration_frames(cfg) / seconds
        print(f"{args.task:>5} {n:>6} {cfg.env.representation:>6} {train_rate:>15.0f} "
              f"{env_rate:>18.0f} {train_rate / env_rate:>6.2f}")


if __name__ == "__main__":
    main()
