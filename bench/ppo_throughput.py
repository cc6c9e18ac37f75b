"""Training frames per second of ``trainer run`` next to env-only frames per second, same run.

env-only: the collector stepping the environments with the (untrained) policy and nothing else;
training: the whole PPO iteration (collection, GAE, the minibatch epochs, normalizer updates,
logging). Prints both and the ratio (target >= 0.50: learning must not dominate the cost).

    python bench/ppo_throughput.py [--task lift|bin] [--envs 64,256] [--repr com]
                                   [--bin-objects 5] [--iterations 5] [--no-compile]
                                   [--set KEY=VALUE ...]

``--repr default`` uses the task's own representation (sq for lift, bbox for bin).

With ``--backend warp`` (MuJoCo Warp; ``--device cuda`` for a GPU, else Warp's CPU device),
``--num-envs`` (= ``--envs``) defaults to 1024,4096,16384 on CUDA and 8,32 on the CPU device,
``--repr`` to com,sdf (a comma list) and ``--objects`` to auto (the YCB objects built in the
data dir, all 78 when built, else the built-in set). Each row adds the env's build time, the
first collected batch (Warp's kernels, torch.compile, the CUDA graph), the physics-only rate
(``step_held``, same env, same run) and training frames/s over the paper's 53,000 env steps/s
(COM, PPO, RTX A6000, Isaac Gym). The device is synchronized around every timing.

    python bench/ppo_throughput.py --backend warp --device cuda [--num-envs 1024,4096,16384]
                                   [--repr com,sdf] [--iterations 5]

With ``--processes P`` it compares instead one run in one process with P simulation threads
(``nthread = P``) against the same run spread over P processes of one thread each
(``torchrun --standalone --nproc_per_node P trainer run``, started as a subprocess; its frames
/s read from the run's metrics.csv), both training env steps/s and their ratio (P processes
over one); each skips its first iteration. Give each process a core of its own (P <= cores).

    python bench/ppo_throughput.py --processes 2 [--envs 256] [--repr com] [--iterations 5]
"""

from __future__ import annotations

import argparse
import csv
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import torch
from env_throughput import PAPER_STEPS_PER_S, WARP_ENVS, pick_objects, sync

from trainer.config import check_backend, check_device, load_train_config
from trainer.config_keys import parse_sets
from trainer.errors import TrainerError
from trainer.ppo import iteration_frames, make_agent, make_collector, train
from trainer.randomness import run_streams
from trainer.tasks import make_env


def env_only(cfg, iterations: int, physics: bool) -> dict[str, float]:  # noqa: ANN001
    """``rate``: frames/s of the collector over ``iterations`` batches after a warm-up batch;
    ``build_s``: building the env; ``first_s``: the warm-up batch; with ``physics``, also
    ``physics``: the backend's ``step_held`` steps/s over one batch's worth of control periods,
    after the batches."""
    device = cfg.env.device
    sync(device)
    start = time.perf_counter()
    env = make_env(cfg.env, seed=run_streams(cfg))
    sync(device)
    build_s = time.perf_counter() - start
    agent = make_agent(env, cfg.ppo)
    frames = iteration_frames(cfg)
    collector = make_collector(env, agent, frames)
    batches = iter(collector)
    start = time.perf_counter()
    next(batches)  # warm-up
    sync(device)
    first_s = time.perf_counter() - start
    start = time.perf_counter()
    for _ in range(iterations):
        next(batches)
    sync(device)
    out = {"rate": iterations * frames / (time.perf_counter() - start), "build_s": build_s,
           "first_s": first_s}
    if physics:
        start = time.perf_counter()
        for _ in range(cfg.ppo.frames_per_env):
            env.backend.step_held()
        sync(device)
        out["physics"] = frames / (time.perf_counter() - start)
    collector.shutdown()
    env.close()
    return out


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--backend", default="cpu", choices=("cpu", "warp"))
    parser.add_argument("--device", default="cpu", help="torch device: cpu, or cuda for a GPU")
    parser.add_argument("--task", default="lift", choices=("lift", "bin"))
    parser.add_argument("--envs", "--num-envs", dest="envs", default=None,
                        help="comma list; default: 64,256 (cpu), " + ", ".join(
                            f"{v} (warp on {k})" for k, v in WARP_ENVS.items()))
    parser.add_argument("--repr", default=None,
                        help="comma list; 'default': the task's own; default: com (cpu), "
                        "com,sdf (warp)")
    parser.add_argument("--objects", default=None,
                        help="default: builtin (cpu), auto (warp: ycb if built, else builtin)")
    parser.add_argument("--bin-objects", type=int, default=5, help="objects per bin (bin task)")
    parser.add_argument("--data-dir", default=None, help="default: the config's data_dir")
    parser.add_argument("--iterations", type=int, default=5)
    parser.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE",
                        help="a configuration key for every row, e.g. ppo.shared_encoder=true")
    parser.add_argument(
        "--compile", action=argparse.BooleanOptionalAction, default=True,
        help="torch.compile the env's task computations (trainer run --compile)",
    )
    parser.add_argument("--processes", type=int, default=0, metavar="P",
                        help="compare one process of P simulation threads with P processes of "
                        "one thread (torchrun) on the same run instead")
    args = parser.parse_args(argv)
    try:
        if args.processes:
            process_rows(args)
            return
        run_rows(args, parser)
    except TrainerError as exc:
        parser.exit(2, f"error: {exc}\n")


def run_rows(args: argparse.Namespace, parser: argparse.ArgumentParser) -> None:
    """Measure and print one row per env count and representation."""
    sets = parse_sets(args.sets, training=True)
    torch.set_num_threads(1)
    warp = args.backend == "warp"
    if warp:
        try:
            check_device(args.device, f"--device {args.device}", "use --device cpu")
            check_backend(args.backend)
        except TrainerError as exc:
            parser.error(str(exc))
        args.envs = args.envs or WARP_ENVS[torch.device(args.device).type]
        args.repr = args.repr or "com,sdf"
        args.objects = pick_objects(args.objects or "auto", args.data_dir)
        print(f"MuJoCo Warp on {args.device}, objects {args.objects}, {args.iterations} timed "
              "iterations after one")
        print(f"{'task':>5} {'envs':>6} {'repr':>5} {'build s':>8} {'1st batch s':>11} "
              f"{'train frames/s':>15} {'env-only frames/s':>18} {'ratio':>6} "
              f"{'phys steps/s':>13} {'train / paper':>14}")
    else:
        args.envs = args.envs or "64,256"
        args.repr = args.repr or "com"
        args.objects = args.objects or "builtin"
        print(f"{'task':>5} {'envs':>6} {'repr':>6} {'train frames/s':>15} "
              f"{'env-only frames/s':>18} {'ratio':>6}")
    for n in (int(v) for v in args.envs.split(",")):
        for rep in args.repr.split(","):
            env = env_overrides(args, n, rep, args.objects)
            frames = iteration_frames(load_train_config(env=env, sets=sets))
            cfg = load_train_config(
                env=env, sets=sets,
                run={"total_steps": frames * (args.iterations + 1), "checkpoint_every": 10**9},
            )
            measured = env_only(cfg, args.iterations, physics=warp)
            env_rate = measured["rate"]
            with tempfile.TemporaryDirectory() as tmp:
                run = train(cfg, Path(tmp) / "run", progress=False)
                trained = train_rate(run.metrics, iteration_frames(cfg))
            if warp:
                print(f"{args.task:>5} {n:>6} {cfg.env.representation:>5} "
                      f"{measured['build_s']:>8.1f} {measured['first_s']:>11.1f} "
                      f"{trained:>15.0f} {env_rate:>18.0f} {trained / env_rate:>6.2f} "
                      f"{measured['physics']:>13.0f} {trained / PAPER_STEPS_PER_S:>14.3f}")
            else:
                print(f"{args.task:>5} {n:>6} {cfg.env.representation:>6} {trained:>15.0f} "
                      f"{env_rate:>18.0f} {trained / env_rate:>6.2f}")
    if warp:
        print("ratio: train / env-only frames/s, same run (target >= 0.50); phys: step_held "
              "alone, same env; build and 1st batch (Warp's kernels, torch.compile, the CUDA "
              f"graph) are not in the rates; paper: {PAPER_STEPS_PER_S:,} env steps/s (COM, "
              "PPO, RTX A6000). Issue target on one H100: >= 150,000 with PPO at 16,384 envs.")


def env_overrides(args: argparse.Namespace, num_envs: int, rep: str, objects: str) -> dict:
    """The env config of one row: the task, ``num_envs`` envs, ``objects``, the representation
    ``rep`` ("default": the task's own) and the command line's backend and data options."""
    env = {"task": args.task, "num_envs": num_envs, "objects": objects,
           "compile": args.compile, "backend": args.backend, "device": args.device}
    if args.data_dir:
        env["data_dir"] = Path(args.data_dir)
    if rep != "default":
        env["representation"] = rep
    if args.task == "bin":
        env["bin"] = {"num_objects": args.bin_objects}
    return env


def train_rate(metrics: Path, frames: int) -> float:
    """Training env steps/s of the run whose ``metrics.csv`` is ``metrics`` (``frames`` env
    steps per iteration), its first iteration (set-up, first collector reset) left out."""
    rows = list(csv.DictReader(metrics.read_text().splitlines()))
    if len(rows) < 2:
        raise TrainerError(f"{metrics}: {len(rows)} iteration(s), 2 at least are needed")
    seconds = float(rows[-1]["wall_time_s"]) - float(rows[0]["wall_time_s"])
    return (len(rows) - 1) * frames / seconds


def process_rows(args: argparse.Namespace) -> None:
    """``--processes P``: per env count and representation, one process of P simulation
    threads against P processes of one (torchrun), same run settings."""
    procs = args.processes
    if procs < 1:
        raise TrainerError(f"--processes {procs}: must be at least 1")
    sets = parse_sets(args.sets, training=True)
    envs, reps = args.envs or "256", args.repr or "com"
    objects = args.objects or "builtin"
    print(f"{'task':>5} {'envs':>6} {'repr':>6} {f'1 proc x {procs} thr':>15} "
          f"{f'{procs} proc x 1 thr':>15} {'ratio':>6}")
    for n in (int(v) for v in envs.split(",")):
        for rep in reps.split(","):
            env = env_overrides(args, n, rep, objects)
            frames = iteration_frames(load_train_config(env=env, sets=sets))
            steps = frames * (args.iterations + 1)
            run = {"total_steps": steps, "checkpoint_every": 10**9}
            one_cfg = load_train_config(env={**env, "nthread": procs}, sets=sets, run=run)
            with tempfile.TemporaryDirectory() as tmp:
                one = train_rate(train(one_cfg, Path(tmp) / "one", progress=False).metrics,
                                 frames)
                many = train_rate(torchrun_run(args, env, procs, steps, Path(tmp) / "many"),
                                  frames)
            print(f"{args.task:>5} {n:>6} {one_cfg.env.representation:>6} {one:>15.0f} "
                  f"{many:>15.0f} {many / one:>6.2f}")
    print(f"ratio: training env steps/s of {procs} processes of one simulation thread over one "
          f"process of {procs} threads, the same run")


def torchrun_run(
    args: argparse.Namespace, env: dict, procs: int, steps: int, run_dir: Path
) -> Path:
    """Train the run of ``env`` (this bench's options) for ``steps`` env steps as ``procs``
    processes of one simulation thread (``torchrun --standalone``, a subprocess) in
    ``run_dir``; its metrics.csv."""
    command = [
        sys.executable, "-m", "torch.distributed.run", "--standalone",
        f"--nproc_per_node={procs}", "-m", "trainer.cli", "run", "--run-dir", str(run_dir),
        "--task", env["task"], "--num-envs", str(env["num_envs"]), "--objects", env["objects"],
        "--backend", args.backend, "--device", args.device, "--steps", str(steps),
        "--compile" if args.compile else "--no-compile",
        "--set", "nthread=1", "--set", f"run.checkpoint_every={10**9}",
    ]
    if "representation" in env:
        command += ["--repr", env["representation"]]
    if args.data_dir:
        command += ["--data-dir", str(args.data_dir)]
    if args.task == "bin":
        command += ["--bin-objects", str(args.bin_objects)]
    for value in args.sets:
        command += ["--set", value]
    root = str(Path(__file__).resolve().parents[1])
    path = os.pathsep.join(p for p in (root, os.environ.get("PYTHONPATH", "")) if p)
    done = subprocess.run(command, capture_output=True, text=True,
                          env={**os.environ, "PYTHONPATH": path, "OMP_NUM_THREADS": "1"})
    if done.returncode != 0:
        last = (done.stderr.strip().splitlines() or ["(no output)"])[-1]
        raise TrainerError(f"torchrun with {procs} processes failed: {last}")
    return run_dir / "metrics.csv"


if __name__ == "__main__":
    main()
