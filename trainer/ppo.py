"""PPO on the batched grasping environment, with TorchRL's collector, GAE and ClipPPOLoss.

Reading order: ``train`` is the whole algorithm, top to bottom: build the env and the parts
(the builders below it), then per iteration collect a rollout of ``frames_per_env`` steps from
every env, update the networks (``PPOUpdate``: GAE with values in reward units, normalized
value targets, ``epochs`` passes of minibatch updates, observation statistics), count the
ended episodes, move the lift curriculum, log, checkpoint.

The run's state lives in ``trainer.training``: the run directory and its metrics file
(``run_dir``), the checkpointed ``TrainState`` (``checkpoint``), the curriculum and the episode
counters. Resuming continues a killed run bit for bit; SIGINT or SIGTERM stops a run at the end
of its iteration, with a checkpoint.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import time
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import torch
from tensordict import TensorDictBase
from torchrl.collectors import Collector
from torchrl.objectives import ClipPPOLoss
from torchrl.objectives.value import GAE
from tqdm import tqdm

from geomgrasp.machine import code_version, cpu_model, niceness, usable_cores
from trainer.config import AGENT_PARTS, PPOConfig, TrainConfig, check_device
from trainer.errors import TrainerError
from trainer.models import Agent
from trainer.objects import resolve_names
from trainer.randomness import RandomStreams, run_streams
from trainer.tasks import GraspTask, make_env
from trainer.tasks.starts import DamagedStarts, GraspStarts
from trainer.training import distributed
from trainer.training.checkpoint import (
    TrainState,
    agent_source,
    copy_agent_parts,
    init_agent_from,
    load_last_checkpoint,
    restore_global_rng,
    write_checkpoint,
)
from trainer.training.curriculum import LiftCurriculum
from trainer.training.grasp_starts import (
    cached_starts_path,
    object_grasps,
    record_grasp_starts,
)
from trainer.training.outcomes import EndedEpisodes, EpisodeStats
from trainer.training.progress import NoLog, ProgressLog, RunClock
from trainer.training.run_dir import RunDir, record_launch
from trainer.training.stop import StopSignals

LOSS_KEYS = ("loss_objective", "loss_critic", "loss_entropy", "entropy", "kl_approx", "clip_fraction")  # noqa: E501


def iteration_frames(cfg: TrainConfig) -> int:
    return cfg.env.num_envs * cfg.ppo.frames_per_env


def total_iterations(cfg: TrainConfig) -> int:
    """PPO iterations a run of ``cfg`` does: ``run.total_steps`` rounded up to whole rollouts."""
    return math.ceil(cfg.run.total_steps / iteration_frames(cfg))


def minibatch_size(cfg: TrainConfig) -> int:
    """Frames per minibatch: the rollout in ``minibatches`` parts, but at least
    ``min_minibatch`` frames (and at most the whole rollout)."""
    frames = iteration_frames(cfg)
    return min(frames, max(frames // cfg.ppo.minibatches, cfg.ppo.min_minibatch, 1))


def train(
    cfg: TrainConfig | None,
    run_dir: Path,
    resume: bool = False,
    progress: bool = True,
    stop_after: int | None = None,
    overwrite: bool = False,
    resume_as: Path | None = None,
) -> RunDir:
    """Train (or, with ``resume``, continue) the one run in ``run_dir``; returns it.

    With ``resume``, ``cfg`` is None (the run's config.json) or that config with a larger
    ``run.total_steps`` or ``run.max_minutes`` (extend the run). Without it, a directory that
    already holds a run is refused unless ``overwrite`` (which deletes that run first).
    SIGINT or SIGTERM ends the run at the end of the current iteration with a checkpoint; then
    the signal is delivered as usual (Ctrl-C: KeyboardInterrupt). ``stop_after``: leave after
    this many iterations of this call, as a killed run would (the resume test).
    ``resume_as``: the folder the stop messages tell the user to ``--resume`` (default
    ``run_dir``). A run with ``[run] warmup_objects`` starts from its trained warmup:
    ``train_run`` composes the two."""
    run = RunDir(Path(run_dir))
    world = distributed.world()
    cfg, checkpoint = open_run(run, cfg, resume, overwrite, world)
    parts = build_parts(cfg, run, checkpoint, progress and world.is_main, world)
    env, agent, update, state = parts.env, parts.agent, parts.update, parts.state
    frames, iterations = iteration_frames(cfg), total_iterations(cfg)
    collector = make_collector(env, agent, frames // world.size)
    if checkpoint is not None:
        restore_global_rng(checkpoint, env.device)  # after the collector's set-up draws from it
    log: ProgressLog | NoLog = NoLog()
    if world.is_main:
        log = ProgressLog(run, iterations * frames, state.iteration, frames, resume, progress)
    for note in parts.notes:  # (the log opens after the run's state is loaded)
        log.write(note)
    merge = _merge_episodes if world.distributed else None
    clock = RunClock(state.wall_time_s, state.iteration * frames)
    stop = StopSignals(again_stops=not world.distributed)
    resume_target: Path | str = Path(resume_as) if resume_as is not None else run.path
    if world.distributed:
        resume_target = f"{resume_target} (under torchrun, {world.size} processes)"
    try:
        with stop:
            for data in collector:
                if state.iteration >= iterations or stop_after == 0:
                    break
                stop_after = None if stop_after is None else stop_after - 1
                state.iteration += 1
                losses = update(data, state.shuffle)
                episodes = state.episodes.record(data, state.curriculum, merge)
                # The row reports the curriculum as this iteration trained; then it moves on.
                row, postfix, object_h_bars = iteration_row(state, env, frames, episodes, losses)
                if state.curriculum.promote():
                    env.set_lift_target(state.curriculum.targets())
                state.wall_time_s, row["fps"] = clock.lap(state.iteration * frames)
                stopping = stop.received is not None
                if world.distributed:  # every rank stops alike, on rank 0's clock
                    stopping, state.wall_time_s = distributed.agree_to_stop(
                        stopping, state.wall_time_s, env.device)
                row.update(wall_time_s=state.wall_time_s, action_std=agent.policy_net.mean_std(
                    data["scale"]), lr=update.optimizer.param_groups[0]["lr"])
                log.log(row, postfix, object_h_bars)
                for message in env.backend.drain_warnings():  # e.g. Warp buffers to enlarge
                    log.write(f"warning: {message}")
                done = state.iteration == iterations
                out_of_time = _out_of_time(cfg, state.wall_time_s)
                if (state.iteration % cfg.run.checkpoint_every == 0 or done or out_of_time
                        or stopping):
                    save_checkpoint(run, state, world)
                steps = f"{row['env_steps']:,} env steps, iteration {state.iteration}"
                if out_of_time and not done:
                    log.write(f"stopped: time budget of {cfg.run.max_minutes:g} minutes used "
                              f"({steps}); extend it with --resume {resume_target} --minutes M")
                elif stopping and not done:
                    name = stop.received.name if stop.received else "a signal to another rank"
                    log.write(f"stopped: {name} ({steps}, checkpoint written); "
                              f"continue it with --resume {resume_target}")
                if done or out_of_time or stopping:
                    break
    finally:
        log.close()
        collector.shutdown()
    stop.reraise()
    return run


def save_checkpoint(run: RunDir, state: TrainState, world: distributed.World) -> None:
    """Write the run's checkpoint: ``state``'s; in a distributed run rank 0 writes it with
    every other rank's own part (``distributed.PER_RANK_KEYS``) gathered, after checking that
    the ranks' agents are still one."""
    state_dict = state.state_dict()
    if not world.distributed:
        write_checkpoint(run, state_dict)
        return
    distributed.check_same(state.agent, f"iteration {state.iteration}")
    parts = distributed.gather_to_main(distributed.rank_part(state_dict))
    if parts is not None:
        write_checkpoint(run, distributed.with_ranks(state_dict, parts))
    distributed.barrier()  # (the checkpoint is whole before any rank goes on or ends)


def _merge_episodes(ended: EndedEpisodes) -> EndedEpisodes:
    """The episodes that ended in every process of the run, in a one-process run's order."""
    return EndedEpisodes.merged(distributed.all_gather(ended))


def train_run(
    cfg: TrainConfig | None, run_dir: Path, resume: bool = False, progress: bool = True,
    overwrite: bool = False,
) -> RunDir:
    """A run as ``trainer run`` trains it: with ``[run] warmup_objects``, two runs composed —
    its warmup (``warmup_config``, a run of its own in ``run_dir/warmup``), then the run itself
    started from the warmup's agent; without, ``train``. Arguments as ``train``'s. A run
    stopped in its warmup resumes there with ``resume``."""
    run = RunDir(Path(run_dir))
    world = distributed.world()
    if resume:
        cfg = run.config_to_resume(cfg, world.size)
    assert cfg is not None or resume
    if cfg is None or not cfg.run.warmup_steps or run.has_checkpoint():
        return train(cfg, run.path, resume=resume, progress=progress, overwrite=overwrite)
    if not resume:
        run.make_room(overwrite)
    # Its config.json first, so that a run stopped while warming up resumes with --resume of
    # this folder (but not before both object sets are known to exist).
    for spec in (cfg.run.warmup_objects, cfg.env.objects):
        resolve_names(spec, cfg.env.data_dir)
    cfg = with_world_size(cfg, world.size)
    if world.is_main:
        run.write_config(cfg)
    if not _warm_up(cfg, run, progress):
        return run
    return train(cfg, run.path, resume=True, progress=progress)


def with_world_size(cfg: TrainConfig, world_size: int) -> TrainConfig:
    """``cfg`` of a fresh run launched as ``world_size`` processes (``run.world_size``)."""
    if cfg.run.world_size == world_size:
        return cfg
    return dataclasses.replace(cfg, run=dataclasses.replace(cfg.run, world_size=world_size))


def warmup_config(cfg: TrainConfig) -> TrainConfig:
    """The config of a run's warmup (``[run] warmup_objects``): the run's, on the warmup's
    objects for ``warmup_steps`` env steps, with no warmup of its own."""
    return dataclasses.replace(
        cfg,
        env=dataclasses.replace(cfg.env, objects=cfg.run.warmup_objects),
        run=dataclasses.replace(
            cfg.run, total_steps=cfg.run.warmup_steps, warmup_objects="", warmup_steps=0,
            init_agent_unseen="keep",  # (it starts fresh)
        ),
    )


def _warm_up(cfg: TrainConfig, run: RunDir, progress: bool) -> bool:
    """Train (or resume) the warmup of ``run`` in ``run.warmup``; True once it is complete and
    time is left for the run itself, else False (stopped: the run resumes it)."""
    warm_cfg = warmup_config(cfg)
    warm = RunDir(run.warmup)
    if warm.has_checkpoint():
        state = load_last_checkpoint(warm, map_location="cpu")
        if not _warmup_over(warm_cfg, state):
            train(warm_cfg, warm.path, resume=True, progress=progress, resume_as=run.path)
    else:  # (a warmup killed before its first checkpoint starts again)
        train(warm_cfg, warm.path, progress=progress, overwrite=True, resume_as=run.path)
    state = load_last_checkpoint(warm, map_location="cpu")
    if state["iteration"] < total_iterations(warm_cfg):
        print(f"stopped while warming up ({warm.path}): continue the run with --resume "
              f"{run.path}", flush=True)
        return False
    if _out_of_time(cfg, state["wall_time_s"]):
        print(f"stopped: the warmup used the time budget of {cfg.run.max_minutes:g} minutes; "
              f"extend it with --resume {run.path} --minutes M", flush=True)
        return False
    return True


def _warmup_over(warm_cfg: TrainConfig, state: dict[str, Any]) -> bool:
    """The warmup whose last checkpoint is ``state`` has done its steps or used its time."""
    done = state["iteration"] >= total_iterations(warm_cfg)
    return done or _out_of_time(warm_cfg, state["wall_time_s"])


# --- builders --------------------------------------------------------------------------------
def open_run(
    run: RunDir, cfg: TrainConfig | None, resume: bool, overwrite: bool,
    world: distributed.World | None = None,
) -> tuple[TrainConfig, dict[str, Any] | None]:
    """The config ``train`` runs and the checkpoint it continues (None: a fresh start): a
    resumed run's (refused if it has nothing left to do, or if ``world``, this launch, has
    another number of processes than the run; a run whose warmup just ended has no
    checkpoint yet), or ``cfg`` in a directory made room for (by rank 0), recording
    ``world``'s size. A distributed run's processes join their process group here."""
    world = world or distributed.World()
    checkpoint = None
    if resume:
        cfg = run.config_to_resume(cfg, world.size)
        if not (cfg.run.warmup_steps and not run.has_checkpoint()):  # (else: after its warmup)
            checkpoint = load_last_checkpoint(run)
            _check_left_to_do(run, cfg, checkpoint)
            checkpoint = distributed.state_of_rank(checkpoint, world.rank, world.size)
    else:
        assert cfg is not None
        cfg = with_world_size(cfg, world.size)
        distributed.local_envs(cfg.env.num_envs, world.size)  # (refused before any file)
        if world.is_main:
            run.make_room(overwrite)
    assert cfg is not None
    if world.distributed:
        distributed.setup(world, distributed.device_of(cfg.env.device, world))
        if not resume:
            distributed.barrier()  # (rank 0 has made room before any rank writes there)
    check_device(
        cfg.env.device, f"device {cfg.env.device!r} of {run.path}",
        "resume it where that device exists" if resume else "train with --device cpu",
    )
    return cfg, checkpoint


@dataclass
class RunParts:
    """What ``train``'s loop works with, built by ``build_parts``."""

    env: GraspTask
    agent: Agent
    update: PPOUpdate
    state: TrainState
    notes: list[str]
    """Lines for the run's log: where the agent started from, the grasp starts."""


def build_parts(
    cfg: TrainConfig, run: RunDir, checkpoint: dict[str, Any] | None, progress: bool,
    world: distributed.World | None = None,
) -> RunParts:
    """The env (with its start strategies), the agent (fresh, from another run's agent, or the
    checkpoint's), the PPO update and the run's state, from ``checkpoint`` or fresh; writes the
    run's config.json. A fresh run's clock starts at its warmup's time plus the minutes spent
    recording its grasp starts: ``--minutes`` counts both. A process of a distributed run
    (``world``) builds its slice of the envs, with its own streams, on its own device, and
    takes rank 0's agent."""
    world = world or distributed.World()
    torch.set_num_threads(cfg.run.torch_threads)
    streams = run_streams(cfg, world.rank)
    streams.seed_global_torch("actions")
    env_cfg = dataclasses.replace(cfg.env, device=distributed.device_of(cfg.env.device, world),
                                  nthread=distributed.threads_of(cfg.env.nthread, world))
    # The env first: a config it refuses (a bin larger than the object set, a missing object)
    # leaves no run directory behind that a corrected rerun would have to --overwrite.
    env = make_env(env_cfg, seed=streams, shard=(world.rank, world.size))
    notes: list[str] = []
    initial_agent, started = None, 0.0
    source = agent_source(cfg, run)
    if checkpoint is None and source:
        # Checked before the grasp starts' minutes of recording; built aside from the global
        # generator, so that the run draws what any run of its config draws.
        with torch.random.fork_rng(devices=[]):
            initial_agent = make_agent(env, cfg.ppo)
        notes.append(init_agent_from(initial_agent, Path(source)))
        if set(cfg.run.init_agent_parts) != set(AGENT_PARTS):
            notes[-1] += f", its {' and '.join(cfg.run.init_agent_parts)} only"
        if cfg.run.warmup_steps:
            started = float(load_last_checkpoint(RunDir(run.warmup), "cpu")["wall_time_s"])
    if cfg.run.grasp_starts > 0:
        starts, seconds = shared_grasp_starts(cfg, run, streams, progress, checkpoint, world)
        started += seconds
        notes.append(f"grasp starts: {int(starts.valid.any(1).sum())} of {cfg.env.num_envs} "
                     f"envs have one; the scripted trials lifted "
                     f"{float(starts.lifted.float().mean()):.2f} of theirs")
        first = world.rank * env.num_envs  # (this process's rows: its envs)
        env.set_grasp_starts(starts.rows(first, first + env.num_envs), cfg.run.grasp_starts,
                             streams.torch("grasp_choice"))
    if cfg.run.fixed_drops:
        env.use_fixed_drops()
    if world.is_main:
        run.write_config(cfg)
    agent = make_agent(env, cfg.ppo)
    if initial_agent is not None:
        copy_agent_parts(initial_agent, agent, cfg.run.init_agent_parts)
        if cfg.run.init_agent_unseen == "silence":
            silenced = agent.silence_unseen_features()
            notes[0] += f"; {silenced} observation features it never saw vary silenced"
    if world.distributed:
        # A fresh run's ranks drew their own initial weights: all take rank 0's (a resumed
        # run's are equal already).
        distributed.broadcast_module(agent)
    update = PPOUpdate.build(agent, cfg.ppo, max(1, minibatch_size(cfg) // world.size),
                             distributed=world.distributed)
    state = make_train_state(cfg, env, agent, update.optimizer, world.rank)
    if checkpoint is not None:
        state.load_state_dict(checkpoint)
        if world.is_main:
            run.truncate_metrics(state.iteration)
    else:
        state.wall_time_s = started
        if cfg.ppo.stagger_episodes:
            env.stagger_next_reset()  # (a resumed run's envs continue where they stood)
    env.set_lift_target(state.curriculum.targets())
    if world.is_main:
        record_launch(run, launch_row(state.iteration + 1, env.device, world.size,
                                           env_cfg.nthread, cfg.run.torch_threads))
    return RunParts(env, agent, update, state, notes)


def launch_row(
    first_iteration: int, device: torch.device, processes: int, sim_threads: int,
    torch_threads: int,
) -> dict[str, Any]:
    """The row of ``launches.csv`` (``trainer.training.run_dir.LAUNCH_COLUMNS``) for a launch
    that trains from ``first_iteration``: this code on this machine."""
    name = torch.cuda.get_device_name(device) if device.type == "cuda" else str(device)
    return {
        "first_iteration": first_iteration,
        "started": datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "code": code_version(), "cpu": cpu_model(), "cores": usable_cores(), "nice": niceness(),
        "device": name, "processes": processes, "sim_threads": sim_threads,
        "torch_threads": torch_threads,
    }


def shared_grasp_starts(
    cfg: TrainConfig, run: RunDir, streams: RandomStreams, progress: bool,
    checkpoint: dict[str, Any] | None, world: distributed.World,
) -> tuple[GraspStarts, float]:
    """The run's grasp starts for all of its envs and the seconds spent getting them
    (``grasp_starts_of``). In a distributed run rank 0 gets them, as a one-process run of the
    config would (recorded on every env of the run, or loaded), while the others wait; then
    every rank reads them from the run's ``grasp_starts.pt``."""
    if not world.distributed:
        return grasp_starts_of(cfg, run, streams, progress, fresh=checkpoint is None)
    seconds = 0.0
    if world.is_main:
        _, seconds = grasp_starts_of(cfg, run, run_streams(cfg), progress,
                                     fresh=checkpoint is None)
    distributed.barrier()  # (within the process group's timeout: distributed.TIMEOUT_ENV)
    # (rank 0's seconds only: the run's clock is rank 0's)
    return _fitting(GraspStarts.load(run.grasp_starts), cfg, run.grasp_starts), seconds


def grasp_starts_of(
    cfg: TrainConfig, run: RunDir, streams: RandomStreams, progress: bool, fresh: bool
) -> tuple[GraspStarts, float]:
    """The run's grasp starts and the seconds spent getting them. A resumed run loads its own
    (``run.grasp_starts``); a fresh one (or a resumed one whose file is missing or damaged)
    the data directory's recording of the same key (``cached_starts_path``: the same config,
    seed and grasps) where there is one, else records them (minutes for ten objects, with a
    progress bar; searching first the grasps of objects that have none, minutes each) and
    keeps them in the run and under that key. A damaged file is said in one line and replaced:
    recording again from the same streams gives the same states."""
    began = time.perf_counter()
    damaged = ""
    if not fresh and run.grasp_starts.is_file():
        try:
            return _fitting(GraspStarts.load(run.grasp_starts), cfg, run.grasp_starts), 0.0
        except DamagedStarts as exc:
            damaged = f"{exc.path} is damaged ({exc.reason}): "
    # (flushed: a search's line comes minutes before the next)
    grasps = object_grasps(cfg.env, cfg.run.grasp_start_family,
                           echo=functools.partial(print, flush=True))
    cached = cached_starts_path(cfg, grasps)
    if cached.is_file():
        try:
            starts = _fitting(GraspStarts.load(cached), cfg, cached)
        except DamagedStarts as exc:
            damaged += f"{exc.path} is damaged ({exc.reason}): "
        else:
            print(f"{damaged}grasp starts from {cached} (recorded by an earlier run of this "
                  f"configuration and seed)", flush=True)
            starts.save(run.grasp_starts)
            return starts, time.perf_counter() - began
    if damaged:
        print(f"{damaged}recording the grasp starts again; the same streams give the same "
              f"states", flush=True)
    print(f"recording the grasp starts ({cfg.run.grasp_start_rounds} scripted trials per env of "
          f"{cfg.env.num_envs}; counted in the time budget)", flush=True)
    with tqdm(desc="grasp starts", unit="action", disable=not progress, dynamic_ncols=True,
              leave=False) as bar:
        def advance(done: int, total: int) -> None:
            bar.total = total
            bar.update(done - bar.n)

        starts = record_grasp_starts(cfg.env, streams, cfg.run.grasp_start_family,
                                     cfg.run.grasp_start_rounds, phase=cfg.run.grasp_start_phase,
                                     on_progress=advance)
    starts.save(run.grasp_starts)
    starts.save(cached)
    return starts, time.perf_counter() - began


def _fitting(starts: GraspStarts, cfg: TrainConfig, path: Path) -> GraspStarts:
    """``starts`` read from ``path``, refused as damaged unless they have one row per env."""
    if starts.valid.shape[0] != cfg.env.num_envs:
        raise DamagedStarts(path, f"starts of {starts.valid.shape[0]} envs, the run has "
                                  f"{cfg.env.num_envs}")
    return starts


def iteration_row(
    state: TrainState, env: GraspTask, frames: int, episodes: dict[str, float],
    losses: dict[str, float],
) -> tuple[dict[str, Any], dict[str, Any], list[tuple[str, float]]]:
    """(the iteration's metrics row without its timing and action scales, the progress bar's
    postfix, each object's lift target): the curriculum as this iteration trained."""
    curriculum = state.curriculum
    h_bar, target_rate = curriculum.mean_h_bar(), curriculum.rate()
    row = {
        "iteration": state.iteration,
        "env_steps": state.iteration * frames,
        "success_rate": state.episodes.success_rate(),
        "object_success_rate": state.episodes.object_success_rate(),
        "h_bar": h_bar,
        "target_success_rate": target_rate,
        **episodes,
        **losses,
    }
    # No rate before the first episode ends: "nan" would read as a broken run.
    success = f"{row['object_success_rate']:.2f}" if state.episodes.outcomes else "-"
    postfix: dict[str, Any] = {"success": success, "it": state.iteration}
    if curriculum.active:
        postfix.update(h_bar=f"{h_bar:.2f}", at_h_bar=f"{target_rate:.2f}")
    object_h_bars = list(zip(env.objects.names, curriculum.h_bars, strict=True))
    return row, postfix, object_h_bars if curriculum.per_object else []


def make_agent(env: GraspTask, ppo: PPOConfig) -> Agent:
    """The policy and value networks (and their normalizers) for ``env``, on its device."""
    return Agent(env.observation_spec, ppo).to(env.device)


def make_collector(env: GraspTask, agent: Agent, frames: int) -> Collector:
    """Endless rollouts of ``frames`` frames ((num_envs, frames_per_env) batches) of the
    stochastic policy. It resets ``env`` and runs the policy once as it is built."""
    return Collector(
        env, agent.actor, frames_per_batch=frames, total_frames=-1,
        auto_register_policy_transforms=False,
    )


def make_train_state(
    cfg: TrainConfig, env: GraspTask, agent: Agent, optimizer: torch.optim.Optimizer,
    rank: int = 0,
) -> TrainState:
    """A fresh run's state (that of process ``rank`` of a distributed run): iteration 0, the
    lift curriculum at its start, no episode ended. Success is counted over the last
    ``run.success_window`` episodes of the whole run (0: one per env of the run)."""
    window = cfg.run.success_window or cfg.env.num_envs
    return TrainState(
        agent=agent,
        optimizer=optimizer,
        # Every tensor of the loop lives on the env's device; the minibatch order is drawn
        # there too.
        shuffle=run_streams(cfg, rank).torch("shuffle", env.device),
        # Success at the task's lift height (the paper's measure) and, for the curriculum, at
        # the current training target.
        episodes=EpisodeStats(env.num_envs, window, cfg.env.reward.h_bar, env.device,
                              env_offset=rank * env.num_envs, run_envs=cfg.env.num_envs),
        curriculum=LiftCurriculum(cfg.env.reward, len(env.objects.names), window),
        env=env,
    )


@dataclass
class PPOUpdate:
    """One PPO update from a rollout: advantages (GAE), value targets, ``ppo.epochs`` passes
    over shuffled minibatches of ``minibatch`` frames of the clipped loss, then the observation
    statistics.

    ``distributed``: this process's rollout is its share of a run's (``trainer.training.
    distributed``), ``minibatch`` its share of each minibatch; the value and observation
    statistics pool every process's, each minibatch's advantages are normalized by the moments
    of every process's minibatch together, the gradients are averaged before clipping and the
    step, the learning rate adapts to the KL averaged over the processes: every process takes
    the update one process would take on all the minibatches together."""

    agent: Agent
    ppo: PPOConfig
    minibatch: int
    optimizer: torch.optim.Optimizer
    advantage: GAE
    loss: ClipPPOLoss
    distributed: bool = False

    @classmethod
    def build(
        cls, agent: Agent, ppo: PPOConfig, minibatch: int, distributed: bool = False
    ) -> PPOUpdate:
        optimizer = torch.optim.Adam(agent.parameters(), lr=ppo.lr)
        # (no value network: ``rollout_values`` writes the values GAE reads)
        advantage = GAE(gamma=ppo.gamma, lmbda=ppo.lmbda, value_network=None)
        loss = ClipPPOLoss(
            agent.actor, agent.critic, clip_epsilon=ppo.clip_epsilon,
            entropy_bonus=True, entropy_coeff=ppo.entropy_coef,
            critic_coeff=ppo.critic_coef, loss_critic_type="l2",
            # (distributed: normalized over every process's minibatch, in ``step``)
            normalize_advantage=not distributed,
        )
        return cls(agent, ppo, minibatch, optimizer, advantage, loss, distributed)

    def __call__(self, data: TensorDictBase, shuffle: torch.Generator) -> dict[str, float]:
        """Update from ``data`` (a (num_envs, T) rollout; the advantage and value keys are
        written into it); the minibatch order is drawn from ``shuffle``. Returns the
        ``LOSS_KEYS``, each its mean over the minibatches (and processes) (NaN: the loss has
        no such term)."""
        agent, ppo = self.agent, self.ppo
        pool = distributed.pool_moments if self.distributed else None
        # Advantages with values in reward units; the critic learns the normalized targets.
        with torch.no_grad():
            rollout_values(agent, data)
            self.advantage(data)
        agent.value_norm.update(data["value_target"], pool)
        data["value_target"] = agent.value_norm(data["value_target"])
        data["state_value"] = agent.value_norm(data["state_value"])
        # The collector's own bookkeeping (trajectory ids) stays on the CPU: not a loss input;
        # nor is a shared encoder's output of the rollout (the loss's actor encodes afresh).
        encoded = Agent.ENCODED
        flat = data.exclude("collector", encoded, ("next", encoded)).reshape(-1)
        # Loss statistics stay on the device (a float() per minibatch would wait for the GPU
        # every time); they are read once per epoch (the learning-rate schedule).
        losses: dict[str, list[torch.Tensor]] = {k: [] for k in LOSS_KEYS}
        for _ in range(ppo.epochs):
            order = torch.randperm(flat.shape[0], generator=shuffle, device=shuffle.device)
            epoch_kl: list[torch.Tensor] = []
            for index in order.split(self.minibatch):
                out = self.step(flat[index])
                for key in LOSS_KEYS:
                    if key in out:
                        losses[key].append(out[key].detach().mean())
                epoch_kl.append(losses["kl_approx"][-1])
            if ppo.lr_schedule == "adaptive":
                kl = torch.stack(epoch_kl).mean()
                if self.distributed:  # (every process adapts its rate alike)
                    kl = distributed.all_reduce_mean(kl)
                _adapt_lr(self.optimizer, float(kl), ppo)
        agent.obs_norm.update(*(data[key] for key in agent.obs_keys), pool=pool)
        means = {k: torch.stack(v).mean() for k, v in losses.items() if v}
        if self.distributed and means:
            averaged = distributed.all_reduce_mean(torch.stack(list(means.values())))
            means = dict(zip(means, averaged, strict=True))
        return {k: float(means[k]) if k in means else float("nan") for k in LOSS_KEYS}

    def step(self, batch: TensorDictBase) -> TensorDictBase:
        """One optimizer step on the minibatch ``batch`` (flat, with advantages and value
        targets); returns the loss's outputs."""
        agent = self.agent
        if self.distributed:
            batch["advantage"] = distributed.standardize(batch["advantage"])
        out = self.loss(batch)
        loss = out["loss_objective"] + out["loss_critic"]
        if "loss_entropy" in out:
            loss = loss + out["loss_entropy"]
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        if self.distributed:
            distributed.average_gradients(agent.parameters())
        torch.nn.utils.clip_grad_norm_(agent.parameters(), self.ppo.max_grad_norm)
        self.optimizer.step()
        return out


def rollout_values(agent: Agent, data: TensorDictBase) -> None:
    """Write ``state_value`` and ``("next", "state_value")`` (reward units, (E, T, 1)) into
    ``data``, a rollout of E envs by T steps, running the value network once per observation.

    Where a step did not end its episode, its next observation is the following step's
    observation (the collector carries it over, equal to the bit), so its next value is that
    step's value; the next observations are run only where an episode ended and at the last
    step. (TorchRL's GAE with a value network runs every next observation again: a third of
    the rollout's network work, most of it for point clouds.)"""
    values = agent.state_values(data)
    following = torch.empty_like(values)
    following[:, :-1] = values[:, 1:]
    ran = data["next", "done"].reshape(values.shape[:2]).clone()
    ran[:, -1] = True
    following[ran] = agent.state_values(data["next"][ran].select(*agent.obs_keys))
    data["state_value"] = values
    data["next", "state_value"] = following


def _adapt_lr(optimizer: torch.optim.Optimizer, kl: float, ppo: PPOConfig) -> None:
    """Keep the policy's step size near ``ppo.kl_target`` (rl_games' adaptive schedule)."""
    low, high = ppo.lr_bounds
    for group in optimizer.param_groups:
        if kl > 2.0 * ppo.kl_target:
            group["lr"] = max(group["lr"] / 1.5, low)
        elif kl < 0.5 * ppo.kl_target:
            group["lr"] = min(group["lr"] * 1.5, high)


def _check_left_to_do(run: RunDir, cfg: TrainConfig, checkpoint: dict[str, Any]) -> None:
    """Refuse to resume a run that has done its steps or used its time budget."""
    done, frames = checkpoint["iteration"], iteration_frames(cfg)
    if done >= total_iterations(cfg):
        raise TrainerError(
            f"{run.path} is complete ({done * frames} steps of {cfg.run.total_steps}): "
            f"pass --steps with more than {done * frames} to extend it"
        )
    if _out_of_time(cfg, checkpoint["wall_time_s"]):
        spent = checkpoint["wall_time_s"] / 60
        raise TrainerError(
            f"{run.path} has used its time budget ({spent:.1f} of {cfg.run.max_minutes:g} "
            f"minutes): pass --minutes with more than {spent:.1f} to extend it"
        )


def _out_of_time(cfg: TrainConfig, wall_time_s: float) -> bool:
    """The run's time budget (``run.max_minutes``; 0: none) is used up."""
    return cfg.run.max_minutes > 0 and wall_time_s >= 60 * cfg.run.max_minutes
