"""Environment steps per second of the tasks (``trainer.tasks.make_env``) next to physics-only
stepping of the same models, lift and bin picking in one run; and what a bin costs to build and
hold in memory.

1. Throughput. For each task, env count and representation: the full env step (JT control in
   torch, batched physics, observations, reward, resets of finished envs), and in the same run
   the backend's ``step_held`` (the same models, substeps and held controls, nothing else).
   Prints both and their ratio (target >= 0.70), then bin / lift env steps/s at each env count
   (issue target: >= 0.50 at 256 envs). The tasks' envs are timed in alternating blocks.
2. Build cost and memory of a bin env (default: 256 envs, ``[bin] layouts`` random bins of 10
   objects from ``--memory-objects``): seconds to build the env (first build, which may settle
   and cache the layouts' initial states, then a second, cached build) and the backend alone
   (``trainer.sim.make_backend``: model compilation and state allocation); the MjModel and MjData
   buffers (``model.nbuffer``, ``MjData(model).nbuffer`` and its reserved ``narena``) summed over
   the layouts; the backend's state (``state_dict``: what a checkpoint holds) and the
   initial-state banks; and how much the process's resident memory grew in the first build.

    python bench/env_throughput.py [--tasks lift,bin] [--envs 256] [--reprs default|com,sdf,...]
                                   [--objects builtin] [--bin-objects 5] [--no-compile]
                                   [--memory-objects ycb] [--memory-bin-objects 10] [--no-memory]
                                   [--sleep] [--noslip 0,5] [--set KEY=VALUE ...]

``--sleep`` sets ``[physics] sleep`` (resting objects sleep; the CPU backend then steps through
persistent ``mujoco.batch.Batch``es): compare a run with it to one without. ``--noslip`` sets
``[physics] noslip_iterations``; a comma list builds every task at each value and times them all
in the same alternating rounds, so the cost of the no-slip solver is a ratio within one run.
``--set KEY=VALUE`` (``section.field``, repeatable; e.g. ``robot.hand_drive=all-joints``) adds
one more configuration, timed in the same rounds, with its ratio to the first.

``--reprs default`` (the default) uses each task's own representation (``trainer.config.TASKS``:
sq for lift, bbox for bin).

3. The MuJoCo Warp backend (``--backend warp``; ``--num-envs`` is ``--envs``, ``--repr`` is
   ``--reprs``): the lift task by default, at ``--num-envs`` (default 1024,4096,16384 with
   ``--device cuda``, 8,32 on Warp's CPU device) for ``--repr com,sdf``, with the YCB objects
   built in the data dir (all 78 when built; ``--objects auto``), else the built-in set. For each:
   the env's build time, its first physics period (Warp compiles its kernels or loads them from
   ``~/.cache/warp``), its first env step (torch.compile; on CUDA the next control period is
   captured as a graph) and, after warm-up, the same alternating env /
   ``step_held`` blocks as above (the device synchronized around each), their ratio, and the env
   steps/s as a fraction of the paper's 53,000 (COM with PPO, RTX A6000, Isaac Gym). No memory
   section (it measures the CPU backend's models).

    python bench/env_throughput.py --backend warp --device cuda [--num-envs 1024,4096,16384]
                                   [--repr com,sdf] [--tasks lift] [--objects auto]

4. In contact (``--policy RUN``, either backend): the run's own env config (its task, objects,
   representation, physics; ``--num-envs`` the first of ``--envs``) driven by the run's trained
   policy (deterministic actions), first ``--advance`` env steps untimed so that the hands reach
   the objects, then the alternating blocks, policy + env step against physics only. Random
   actions from the reset states (1-3) hardly touch an object, so they miss what contacts cost
   the physics (a learning run's rate falls 3-7x as its hands start grasping). Each
   ``--variant "KEY=VALUE ..."`` (repeatable) is one more configuration timed in the same
   rounds, with its ratio to the run's own; the mean contacts and constraint rows per env at the
   end are printed beside each, e.g. on a GPU:

    python bench/env_throughput.py --backend warp --device cuda --policy RUN --envs 16384 \
        --variant robot.hand_geometry=capsules --variant physics.noslip_iterations=0 \
        --variant robot.hand_drive=equalities
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import statistics
import time
from pathlib import Path

import torch
from torchrl.envs.utils import ExplorationType, set_exploration_type

from trainer.config import (
    EnvConfig,
    check_backend,
    check_device,
    dotted_overrides,
    load_env_config,
    override,
)
from trainer.config_keys import parse_sets
from trainer.errors import TrainerError
from trainer.objects import resolve_names
from trainer.sim import make_backend
from trainer.tasks import GraspTask, make_env
from trainer.training.checkpoint import load_agent

PAPER_STEPS_PER_S = 53_000
"""The paper's throughput: COM representation, training with PPO, one RTX A6000 (Isaac Gym)."""
WARP_ENVS = {"cuda": "1024,4096,16384", "cpu": "8,32"}
"""Default ``--num-envs`` of the warp backend by device type (Warp's CPU device: ~10 ms per
physics step for up to ~30 worlds, so only a few worlds)."""


def sync(device: str | torch.device) -> None:
    """Wait for the device's queued work (CUDA runs asynchronously), so a timing covers it."""
    device = torch.device(device)
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def pick_objects(spec: str, data_dir: str | Path | None) -> str:
    """``auto``: ``ycb`` when YCB objects are imported and built in the data dir (the paper's 78
    when all are), else ``builtin``; any other set or list as given."""
    if spec != "auto":
        return spec
    data = Path(data_dir) if data_dir else load_env_config().data_dir
    try:
        names = resolve_names("ycb", data)
    except TrainerError:
        return "builtin"
    built = all((data / "processed" / f"{name}.h5").is_file() for name in names)
    return "ycb" if names and built else "builtin"


class Stepper:
    """Times one env: blocks of ``steps`` env steps (each one action of every env, then the
    resets of the finished envs, as a collector does) and of ``steps`` physics-only steps."""

    def __init__(self, env: GraspTask, steps: int) -> None:
        self.env = env
        gen = torch.Generator().manual_seed(0)
        self.actions = [
            (torch.rand(env.num_envs, 11, generator=gen) * 2 - 1).to(env.device)
            for _ in range(steps)
        ]
        self.td = env.reset()
        sync(env.device)
        # Warm-up (and compilation, with --compile; Warp's kernels in the first step, its CUDA
        # graph in the second): the first step is timed on its own.
        for i, action in enumerate(self.actions[:3]):
            start = time.perf_counter()
            self.td["action"] = action
            _, self.td = env.step_and_maybe_reset(self.td)
            if i == 0:
                sync(env.device)
                self.first_step_s = time.perf_counter() - start
        sync(env.device)
        self.env_rates: list[float] = []
        self.raw_rates: list[float] = []

    def _env_steps(self) -> int:
        """One timed block's env steps; returns how many."""
        for action in self.actions:
            self.td["action"] = action
            _, self.td = self.env.step_and_maybe_reset(self.td)
        return len(self.actions)

    def block(self) -> None:
        env = self.env
        sync(env.device)
        start = time.perf_counter()
        steps = self._env_steps()
        sync(env.device)
        self.env_rates.append(env.num_envs * steps / (time.perf_counter() - start))
        start = time.perf_counter()
        for _ in range(steps):
            env.backend.step_held()
        sync(env.device)
        self.raw_rates.append(env.num_envs * steps / (time.perf_counter() - start))


class PolicyStepper(Stepper):
    """``Stepper`` with the actions of a trained policy (deterministic), after ``advance``
    untimed env steps: the timed blocks see the contacts of grasping, not of the reset
    states."""

    def __init__(self, env: GraspTask, actor: torch.nn.Module, steps: int, advance: int) -> None:
        self.env, self.actor, self.steps = env, actor, steps
        self.td = env.reset()
        sync(env.device)
        start = time.perf_counter()
        self._act(1)  # compilation (torch.compile, Warp's kernels, the CUDA graph) timed alone
        sync(env.device)
        self.first_step_s = time.perf_counter() - start
        self._act(max(advance - 1, 0))
        sync(env.device)
        self.env_rates, self.raw_rates = [], []

    def _act(self, steps: int) -> None:
        with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
            for _ in range(steps):
                self.td = self.actor(self.td)
                _, self.td = self.env.step_and_maybe_reset(self.td)

    def _env_steps(self) -> int:
        self._act(self.steps)
        return self.steps


def policy_throughput(args: argparse.Namespace) -> None:
    """Section 4: the run's env config and policy, the run's own physics and each variant's.

    Each configuration is timed once as soon as it is built (its line printed then), then in
    ``--rounds`` - 1 alternating rounds; the table is printed at the end, or with what was
    measured when interrupted (SIGINT: a device call's deadline), so a slow build of a late
    configuration loses none of the earlier ones' figures."""
    try:
        cfg, agent = load_agent(Path(args.policy), args.device)
    except (TrainerError, FileNotFoundError) as exc:
        raise SystemExit(f"env_throughput: --policy {args.policy}: {exc}") from None
    n = int(args.envs.split(",")[0])
    base = {"num_envs": n, "backend": args.backend, "device": args.device}
    if args.data_dir:
        base["data_dir"] = args.data_dir
    configs = variants(args)
    print(f"{args.policy}: {cfg.env.task}, {len(resolve_names(cfg.env.objects, cfg.env.data_dir))}"
          f" objects, repr {cfg.env.representation}, {n} envs, {args.backend} on {args.device}; "
          f"{args.advance} policy steps, then {args.rounds} rounds of {args.steps}", flush=True)
    steppers: dict[str, PolicyStepper] = {}
    interrupted = False
    try:
        for label, extra in configs:
            env_cfg = override(cfg.env, {**base, **extra}, {})
            stepper = PolicyStepper(make_env(env_cfg), agent.actor, args.steps, args.advance)
            stepper.block()
            steppers[label] = stepper
            print(f"  built and timed once: {stepper.env_rates[0]:.0f} policy+env steps/s, "
                  f"{stepper.raw_rates[0]:.0f} phys, 1st step {stepper.first_step_s:.1f} s: "
                  f"{label}", flush=True)
        for _ in range(args.rounds - 1):
            for stepper in steppers.values():
                stepper.block()
    except KeyboardInterrupt:
        interrupted = True
    if not steppers:
        raise SystemExit("env_throughput: interrupted before any configuration was timed")
    rounds = min(len(s.env_rates) for s in steppers.values())
    print(f"{'policy+env steps/s':>18} {'phys steps/s':>13} {'ratio':>6} {'1st step s':>10} "
          f"{'contacts':>9} {'rows':>7} {'/ first':>8}  config")
    first = next(iter(steppers))
    for label, stepper in steppers.items():
        env_rate = statistics.median(stepper.env_rates)
        raw_rate = statistics.median(stepper.raw_rates)
        load = stepper.env.backend.contact_load()
        rel = paired(steppers, first, label)  # the first against itself: 1.0
        print(f"{env_rate:>18.0f} {raw_rate:>13.0f} {env_rate / raw_rate:>6.2f} "
              f"{stepper.first_step_s:>10.2f} {load.get('contacts', float('nan')):>9.1f} "
              f"{load.get('constraint rows', float('nan')):>7.1f} {rel:>8.2f}  {label}")
        for message in stepper.env.backend.drain_warnings():
            print(f"  warning: {message}")
        stepper.env.close()
    print("policy+env: the trained policy's deterministic action, then the env step with resets; "
          "phys: step_held; contacts, rows: mean per env at the end (active contacts, constraint "
          "rows); / first: the per-round median of env steps/s over the first configuration's")
    if interrupted:
        print(f"interrupted: {len(steppers)} of {len(configs)} configurations timed, {rounds} "
              "round(s) each in the table")


def task_config(args: argparse.Namespace, task: str, envs: int, rep: str, objects: str,
                bin_objects: int, extra: dict | None = None) -> EnvConfig:
    """The config of one timed env; ``extra``: a variant's overrides (``variants``), merged
    section by section over this benchmark's own."""
    extra = extra or {}
    overrides: dict = {"task": task, "num_envs": envs, "objects": objects,
                       "compile": args.compile,
                       "robot": {"kind": args.robot, **extra.get("robot", {})},
                       "physics": {"sleep": args.sleep, **extra.get("physics", {})}}
    overrides.update({k: v for k, v in extra.items() if k not in ("robot", "physics")})
    if rep != "default":
        overrides["representation"] = rep
    if task == "bin":
        overrides["bin"] = {"num_objects": bin_objects}
    if args.data_dir:
        overrides["data_dir"] = args.data_dir
    overrides.update(backend=args.backend, device=args.device)  # defaults: cpu, cpu
    return load_env_config(**overrides)


def paired(steppers: dict, a: object, b: object) -> float:
    """b's env steps/s over a's: the median of the per-round ratios (the blocks of a round ran
    back to back), over the rounds both completed (an interrupted bench: fewer for some)."""
    rounds = min(len(steppers[a].env_rates), len(steppers[b].env_rates))
    return statistics.median(
        y / x for x, y in zip(steppers[a].env_rates[:rounds], steppers[b].env_rates[:rounds],
                              strict=True)
    )


def variants(args: argparse.Namespace) -> list[tuple[str, dict]]:
    """(label, overrides) of each configuration timed: the default (with ``--policy``: the
    run's own) or each ``--noslip`` value, then ``--set``'s configuration if given, then each
    ``--variant``'s."""
    if args.noslip is None:
        out = [("default", {})]
    else:
        out = [(f"noslip {v}", {"physics": {"noslip_iterations": int(v)}})
               for v in args.noslip.split(",")]
    if args.sets:
        out.append((" ".join(args.sets), dotted_overrides(parse_sets(args.sets))))
    for text in args.variants:
        out.append((text, dotted_overrides(parse_sets(text.split(), "--variant"))))
    return out


def throughput(args: argparse.Namespace) -> None:
    """All tasks' envs of one env count and representation are built together and timed in
    alternating blocks (``--rounds`` of each), each rate the median over its blocks, so that a
    slow moment of the machine hits every task and the physics-only baseline alike."""
    configs = variants(args)
    labels = [label for label, _ in configs]
    extras = dict(configs)
    print(f"{'task':>5} {'envs':>6} {'repr':>6} {'noslip':>6} {'env steps/s':>12} "
          f"{'phys steps/s':>13} {'ratio':>6}  config")
    for n in (int(v) for v in args.envs.split(",")):
        for rep in args.reprs.split(","):
            steppers = {}
            for label in labels:
                for task in args.tasks.split(","):
                    cfg = task_config(args, task, n, rep, args.objects, args.bin_objects,
                                      extras[label])
                    steppers[task, label] = Stepper(make_env(cfg), args.steps)
            for _ in range(args.rounds):
                for stepper in steppers.values():
                    stepper.block()
            rates = {}
            for (task, label), stepper in steppers.items():
                env_rate = statistics.median(stepper.env_rates)
                raw_rate = statistics.median(stepper.raw_rates)
                rates[task, label] = env_rate
                iterations = stepper.env.cfg.physics.noslip_iterations
                print(f"{task:>5} {n:>6} {stepper.env.cfg.representation:>6} {iterations:>6} "
                      f"{env_rate:>12.0f} {raw_rate:>13.0f} {env_rate / raw_rate:>6.2f}  {label}")
                stepper.env.close()

            for label in labels:
                if ("bin", label) in steppers and ("lift", label) in steppers:
                    at = "" if len(labels) == 1 else f", {label}"
                    ratio = rates["bin", label] / rates["lift", label]
                    per_round = paired(steppers, ("lift", label), ("bin", label))
                    print(f"bin ({args.bin_objects} objects) / lift env steps/s, {n} envs, repr "
                          f"{rep}{at}: {ratio:.2f} (per-round median {per_round:.2f}; "
                          "target >= 0.50)")
            for task in args.tasks.split(","):
                for label in labels[1:]:
                    print(f"{task}, {n} envs, repr {rep}: {label} / {labels[0]} "
                          f"env steps/s: {rates[task, label] / rates[task, labels[0]]:.2f} "
                          f"(per-round median "
                          f"{paired(steppers, (task, labels[0]), (task, label)):.2f})")


def warp_throughput(args: argparse.Namespace) -> None:
    """``throughput`` for the warp backend: one env at a time (they share the device), with its
    build and first-step seconds, its memory on the device and the ratio to the paper."""
    objects = pick_objects(args.objects, args.data_dir)
    names = resolve_names(objects, Path(args.data_dir) if args.data_dir else
                          load_env_config().data_dir)
    print(f"MuJoCo Warp on {args.device}, objects {objects} ({len(names)}), "
          f"{args.rounds} rounds of {args.steps} env steps after 3 warm-up steps")
    print(f"{'task':>5} {'envs':>6} {'repr':>5} {'build s':>8} {'1st phys s':>10} "
          f"{'1st step s':>10} "
          f"{'env steps/s':>12} {'phys steps/s':>13} {'ratio':>6} {'/ paper':>8} {'MiB':>7}")
    for n in (int(v) for v in args.envs.split(",")):
        for rep in args.reprs.split(","):
            for task in args.tasks.split(","):
                cfg = task_config(args, task, n, rep, objects, args.bin_objects)
                sync(args.device)
                start = time.perf_counter()
                env = make_env(cfg)
                sync(args.device)
                build_s = time.perf_counter() - start
                start = time.perf_counter()
                env.backend.step_held()  # Warp compiles its kernels (or loads them from cache)
                sync(args.device)
                kernels_s = time.perf_counter() - start
                stepper = Stepper(env, args.steps)  # resets: the period above is forgotten
                for _ in range(args.rounds):
                    stepper.block()
                env_rate = statistics.median(stepper.env_rates)
                raw_rate = statistics.median(stepper.raw_rates)
                mib = sum(env.backend.memory().values()) / 2.0**20
                print(f"{task:>5} {n:>6} {env.cfg.representation:>5} {build_s:>8.1f} "
                      f"{kernels_s:>10.2f} {stepper.first_step_s:>10.2f} {env_rate:>12.0f} "
                      f"{raw_rate:>13.0f} {env_rate / raw_rate:>6.2f} "
                      f"{env_rate / PAPER_STEPS_PER_S:>8.3f} {mib:>7.1f}")
                for message in env.backend.drain_warnings():
                    print(f"  warning: {message}")
                env.close()
                del env, stepper
    print("build: make_env; 1st phys: the first step_held (Warp compiles its kernels, or loads "
          "them from ~/.cache/warp); 1st step: the first env step (torch.compile with "
          "--compile; on CUDA the graph capture); MiB: the backend's Warp model and data")
    print(f"ratio: env steps/s over physics-only (step_held) steps/s, same run; / paper: env "
          f"steps/s over the paper's {PAPER_STEPS_PER_S:,} (COM, with PPO, RTX A6000). Issue "
          "target on one H100: env-only >= 300,000 env steps/s at 16,384 envs.")


def rss_bytes() -> int:
    """Resident memory of this process (Linux)."""
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")


def _nbytes(value: object) -> int:
    if isinstance(value, dict):
        return sum(_nbytes(v) for v in value.values())
    if isinstance(value, torch.Tensor):
        return value.numel() * value.element_size()
    return int(getattr(value, "nbytes", 0))


def build_cost(args: argparse.Namespace) -> None:
    n, N = args.memory_envs, args.memory_bin_objects
    cfg = task_config(args, "bin", n, "default", args.memory_objects, N)
    cfg = dataclasses.replace(cfg, compile=False)
    print(f"\nbin env of {n} envs, {cfg.bin.layouts} layouts of {N} objects "
          f"({args.memory_objects}), CPU backend:")
    rss = rss_bytes()
    start = time.perf_counter()
    env = make_env(cfg)
    first = time.perf_counter() - start
    grown = rss_bytes() - rss
    env.close()
    start = time.perf_counter()
    env = make_env(cfg)
    again = time.perf_counter() - start
    L = len(env.layouts)
    xmls = [[env.objects.xml_paths[k] for k in row] for row in env.layouts.tolist()]
    start = time.perf_counter()
    backend = make_backend(cfg, env.scene, xmls, env.env_layout.cpu().numpy(), "cpu")
    backend_s = time.perf_counter() - start
    backend.close()
    held = env.backend.memory()  # the stepping models: no visual meshes or textures
    render = env.backend.model_for_env(0)  # what a video of env 0 loads on demand
    banks = _nbytes(env.banks)
    m0 = env.backend.model
    mib = 2.0**20
    print(f"  build the env: first {first:.1f} s (settles and caches missing initial states), "
          f"cached {again:.1f} s")
    print(f"  backend alone (compile {L} models, allocate): {backend_s:.2f} s")
    print(f"  per stepping model: nq {m0.nq}, nv {m0.nv}, ngeom {m0.ngeom}, nbuffer "
          f"{m0.nbuffer / mib:.2f} MiB (with visual meshes and textures, for videos only: "
          f"{render.nbuffer / mib:.2f} MiB)")
    print(f"  stepping models, {L} layouts: {held['models'] / mib:.1f} MiB")
    print(f"  MjData, one per layout and pool thread at most: {held['data'] / mib:.1f} MiB")
    print(f"  state, output and control arrays for {n} envs: {held['state'] / mib:.2f} MiB")
    print(f"  initial-state banks: {banks / mib:.3f} MiB")
    total = held["models"] + held["data"] + held["state"] + banks
    print(f"  total of the above: {total / mib:.1f} MiB; process RSS grew {grown / mib:.0f} MiB "
          "in the first build")
    env.close()


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--backend", default="cpu", choices=("cpu", "warp"))
    parser.add_argument("--device", default="cpu", help="torch device: cpu, or cuda for a GPU")
    parser.add_argument("--tasks", default=None, help="default: lift,bin (cpu), lift (warp)")
    parser.add_argument("--envs", "--num-envs", dest="envs", default=None,
                        help="comma list; default: 256 (cpu), " + ", ".join(
                            f"{v} (warp on {k})" for k, v in WARP_ENVS.items()))
    parser.add_argument("--reprs", "--repr", dest="reprs", default=None,
                        help="comma list; 'default': each task's own representation; default: "
                        "default (cpu), com,sdf (warp)")
    parser.add_argument("--objects", default=None,
                        help="default: builtin (cpu), auto (warp: ycb if built, else builtin)")
    parser.add_argument("--bin-objects", type=int, default=5, help="objects per bin (throughput)")
    parser.add_argument("--robot", default="ur5e")
    parser.add_argument("--data-dir", default=None, help="default: the config's data_dir")
    parser.add_argument("--sleep", action=argparse.BooleanOptionalAction, default=False,
                        help="[physics] sleep: resting objects sleep (cpu backend)")
    parser.add_argument("--noslip", default=None,
                        help="[physics] noslip_iterations, or a comma list to compare (cpu)")
    parser.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE",
                        help="one more configuration to time beside the others (cpu; repeatable)")
    parser.add_argument("--variant", dest="variants", action="append", default=[],
                        metavar="'KEY=VALUE ...'",
                        help="one more configuration per use (several KEY=VALUE in one string)")
    parser.add_argument("--policy", default=None, metavar="RUN",
                        help="time the run's env config driven by its trained policy (section 4)")
    parser.add_argument("--advance", type=int, default=150,
                        help="--policy: untimed policy steps before the timed blocks")
    parser.add_argument("--steps", type=int, default=20, help="env steps per timed block")
    parser.add_argument("--rounds", type=int, default=5, help="alternating env/physics blocks")
    parser.add_argument(
        "--compile", action=argparse.BooleanOptionalAction, default=True,
        help="torch.compile the task computations (EnvConfig.compile)",
    )
    parser.add_argument("--memory", action=argparse.BooleanOptionalAction, default=True,
                        help="also measure a bin env's build time and memory")
    parser.add_argument("--memory-envs", type=int, default=256)
    parser.add_argument("--memory-objects", default="ycb")
    parser.add_argument("--memory-bin-objects", type=int, default=10)
    args = parser.parse_args(argv)
    try:
        variants(args)  # every --set and --variant checked before anything is built
    except TrainerError as exc:
        raise SystemExit(f"env_throughput: {exc}") from None
    torch.set_num_threads(1)
    if args.policy is not None:
        try:
            check_device(args.device, f"--device {args.device}", "use --device cpu")
            check_backend(args.backend)
        except TrainerError as exc:
            parser.error(str(exc))
        args.envs = args.envs or ("256" if args.backend == "cpu" else
                                  WARP_ENVS[torch.device(args.device).type].split(",")[-1])
        try:
            policy_throughput(args)
        except TrainerError as exc:
            raise SystemExit(f"env_throughput: {exc}") from None
        return
    if args.backend == "cpu":
        args.tasks = args.tasks or "lift,bin"
        args.envs = args.envs or "256"
        args.reprs = args.reprs or "default"
        args.objects = args.objects or "builtin"
        throughput(args)
        if args.memory:
            build_cost(args)
        return
    try:
        check_device(args.device, f"--device {args.device}", "use --device cpu")
        check_backend(args.backend)
    except TrainerError as exc:
        parser.error(str(exc))
    args.tasks = args.tasks or "lift"
    args.envs = args.envs or WARP_ENVS[torch.device(args.device).type]
    args.reprs = args.reprs or "com,sdf"
    args.objects = args.objects or "auto"
    warp_throughput(args)


if __name__ == "__main__":
    main()
