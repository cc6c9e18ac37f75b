"""The evaluation session: a trained run's policy, the environments it is evaluated in, and the
one loop that plays their episodes with hooks. ``trainer eval`` (``trainer.evaluation``),
``trainer play`` and the probe scripts of scripts/ are built on it.

    session = EvalSession.load("runs/NAME")           # config.json and the last checkpoint
    names = session.names()                           # the run's object set
    episodes = session.lift_episodes(names, 10)       # trainer eval's lift episodes, its seed
    env = session.env(32, seed=7)                     # 32 envs of the run's env config
    episodes = session.run(env, on_step=..., on_episode=...)

Shapes: E is the number of envs of one env (``env.num_envs``), N the episodes of a whole call
(E for ``run``; every batch's envs, in batch order, for ``lift_episodes``). Everything a hook
is handed as a mask is a (E,) bool tensor on the CPU; ``Episodes``' fields are (N,) on the CPU.

Hooks (all optional, called in this order within a step):

* ``on_reset(env, td)``: right after the reset (and the forced targets of ``target_slots``);
  ``td`` is the reset's (E,) tensordict (the first observation: ``observation`` (E, D), ...).
* ``on_step(env, step, td)``: after action ``step`` (0-based), the env in the state it left.
  ``td`` (E,): at its root the observation the policy saw and the policy's outputs
  (``action`` (E, 11), ``loc`` and ``scale`` (E, 11): the Gaussian's mean and std), under
  ``next`` the step's result (``reward`` (E, 1), ``done`` (E, 1), ``success`` (E, 1),
  ``lift_height`` (E, 1), each reward term's ``reward_<name>`` (E, 1), the next observation).
* ``on_episode(env, ended, success)``: after a step at which some episodes ended; ``ended``
  marks them, ``success`` those of them that succeeded (a subset of ``ended``). An env's
  episode ends once per ``run``: later steps of a finished env are not episodes.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import warnings
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import NamedTuple

import torch
from tensordict import TensorDictBase
from torchrl.envs.utils import ExplorationType, set_exploration_type, step_mdp

from trainer.config import EnvConfig, RewardConfig, TrainConfig
from trainer.errors import TrainerError
from trainer.models import Agent
from trainer.objects import resolve_names, task_names
from trainer.randomness import RandomStreams, run_streams
from trainer.tasks import GraspTask, make_env
from trainer.training.checkpoint import load_agent
from trainer.training.run_dir import RunDir

MAX_ENVS = 1024
"""Envs of one batch of lift evaluation episodes at most (``trainer eval``; ``lift_batches``)."""
EVAL_SEED = 12345
"""The seed of ``trainer eval``'s episodes (its ``--seed`` default)."""
NEW_BINS_SEED_OFFSET = 1_000_003
"""Bins a bin run never trained on (``trainer eval --new-bins``) are the layouts of the run's
seed plus this: a run trains on the ``[bin] layouts`` of its own seed only."""

ResetHook = Callable[[GraspTask, TensorDictBase], None]
"""``on_reset(env, td)``: see the module's docstring."""
StepHook = Callable[[GraspTask, int, TensorDictBase], None]
"""``on_step(env, step, td)``: see the module's docstring."""
EpisodeHook = Callable[[GraspTask, torch.Tensor, torch.Tensor], None]
"""``on_episode(env, ended, success)``: see the module's docstring."""


class Episodes(NamedTuple):
    """One episode per env, (N,) each, on the CPU (unpacks as ``success, length, target``)."""

    success: torch.Tensor
    """(N,) bool: the episode ended in a success."""
    length: torch.Tensor
    """(N,) long: its actions (up to its end, or up to the last step run)."""
    target: torch.Tensor
    """(N,) long: its target object, taken right after the reset: an index into the env's
    ``objects.names`` (``run``) or into the ``names`` asked for (``lift_episodes``)."""

    @staticmethod
    def cat(parts: Sequence[Episodes]) -> Episodes:
        """The episodes of ``parts`` one after another."""
        return Episodes(*(torch.cat(field) for field in zip(*parts, strict=True)))


def force_targets(env: GraspTask, slots: torch.Tensor) -> TensorDictBase:
    """Right after a reset: make slot ``slots[i]`` the target of env i's episode (rows with
    ``slots[i] < 0`` keep theirs), ``slots`` (E,) long; returns the reset observation of the
    new targets (``GraspTask.set_targets``)."""
    return env.set_targets(slots)


def run_episodes(
    env: GraspTask,
    actor: Callable[[TensorDictBase], TensorDictBase],
    deterministic: bool = True,
    *,
    target_slots: torch.Tensor | None = None,
    watch: Sequence[int] | None = None,
    hold_finished: bool = False,
    on_reset: ResetHook | None = None,
    on_step: StepHook | None = None,
    on_episode: EpisodeHook | None = None,
) -> Episodes:
    """One episode in every env from a fresh reset, the actions from ``actor`` (the policy's
    mean, or with ``deterministic=False`` sampled from its Gaussian; any callable that writes
    ``action`` (E, 11) into the tensordict it is given will do).

    Envs that finish early keep stepping (nothing is reset) but their outcome is frozen; the
    rollout ends when every env (or every env of ``watch``) has finished, or after
    ``env.cfg.max_steps`` actions. ``target_slots`` (E,): the target slot of each env's
    episode (``force_targets``; -1: the env's own draw). ``hold_finished``: a finished env
    holds its last commands (``GraspTask.hold_action``) instead of following the policy past
    its episode's end (videos: a lift stays lifted). The hooks: see the module's docstring."""
    E = env.num_envs
    success = torch.zeros(E, dtype=torch.bool)
    length = torch.zeros(E, dtype=torch.long)
    finished = torch.zeros(E, dtype=torch.bool)
    watched = torch.as_tensor(list(range(E)) if watch is None else list(watch), dtype=torch.long)
    mode = ExplorationType.DETERMINISTIC if deterministic else ExplorationType.RANDOM
    td: TensorDictBase = env.reset()
    if target_slots is not None:
        td = force_targets(env, target_slots)
    targets = env.target_objects().cpu()
    if on_reset is not None:
        on_reset(env, td)
    with torch.no_grad(), set_exploration_type(mode):
        for step in range(env.cfg.max_steps):
            td = actor(td)
            if hold_finished and finished.any():
                held = finished.to(td.device)
                td["action"][held] = env.hold_action()[held]
            td = env.step(td)
            if on_step is not None:
                on_step(env, step, td)
            done = td["next", "done"][:, 0].cpu() & ~finished
            succeeded = done & td["next", "success"][:, 0].cpu()
            success |= succeeded
            if on_episode is not None and bool(done.any()):
                on_episode(env, done, succeeded)
            length[~finished] += 1
            finished |= done
            if finished[watched].all():
                break
            td = step_mdp(td)
    return Episodes(success, length, targets)


def success_reward(
    reward: RewardConfig, h_bar: float | None = None, hold_tips: int | None = None,
    lift_clearance: float | None = None,
) -> RewardConfig:
    """``reward`` with the success asked for: e.g. ``hold_tips = 2`` counts held lifts only,
    ``h_bar = 0.05`` lifts by 5 cm (the reward and the episode's end follow it, as in training
    at that curriculum target: the curriculum's start and ``hold_from`` may not exceed it),
    ``lift_clearance = 0.01`` lifts whose lowest point rose 1 cm (not tips). None: unchanged."""
    if hold_tips is not None:
        reward = dataclasses.replace(reward, hold_tips=hold_tips)
    if lift_clearance is not None:
        reward = dataclasses.replace(reward, lift_clearance=lift_clearance)
    if h_bar is not None:
        reward = dataclasses.replace(
            reward, h_bar=h_bar, h_bar_start=h_bar, hold_from=min(reward.hold_from, h_bar)
        )
    return reward


class EvalSession:
    """A trained run ready to be evaluated: its config (``cfg``, the success changed where
    ``load`` was asked to) and its checkpoint's agent (``agent``; None for a session that
    drives the envs with its own actions)."""

    def __init__(self, cfg: TrainConfig, agent: Agent | None = None,
                 iteration: int | None = None) -> None:
        self.cfg = cfg
        self.agent = agent
        self.iteration = iteration
        """The checkpoint's training iteration (None: the run's last)."""

    @classmethod
    def load(
        cls, run_dir: str | Path, device: str | None = None, iteration: int | None = None, *,
        h_bar: float | None = None, hold_tips: int | None = None,
        lift_clearance: float | None = None, policy: bool = True,
    ) -> EvalSession:
        """The run in ``run_dir``: its config and the agent of its last checkpoint (or that of
        ``iteration``; 0: the agent it started from), on ``device`` (default: the run's).
        ``h_bar``, ``hold_tips``, ``lift_clearance``: the success to count instead of the
        run's (``success_reward``).
        ``policy=False``: the config only (no checkpoint is read)."""
        if policy:
            cfg, agent = load_agent(Path(run_dir), device, iteration)
        else:
            cfg, agent = RunDir(Path(run_dir)).load_config(), None
            if device is not None:
                cfg = dataclasses.replace(cfg, env=dataclasses.replace(cfg.env, device=device))
        reward = success_reward(cfg.env.reward, h_bar, hold_tips, lift_clearance)
        cfg = dataclasses.replace(cfg, env=dataclasses.replace(cfg.env, reward=reward))
        return cls(cfg, agent, iteration)

    @property
    def actor(self) -> Callable[[TensorDictBase], TensorDictBase]:
        """The policy (``Agent.actor``): observation in, ``action`` (and ``loc``, ``scale``)
        out."""
        if self.agent is None:
            raise TrainerError("this evaluation session has no policy: load it with policy=True "
                               "or pass an actor")
        return self.agent.actor

    def names(self, objects: str | None = None) -> list[str]:
        """The object names of ``objects`` (names or a set, as ``--objects`` takes them), or
        the run's own (its object set less its held-out objects)."""
        if objects:
            return resolve_names(objects, self.cfg.env.data_dir)
        return task_names(self.cfg.env)

    def streams(self, seed: int) -> RandomStreams:
        """The random streams of ``seed`` as the run derives them (``[run] random_streams``)."""
        return RandomStreams(seed, legacy=not self.cfg.run.random_streams)

    def env_config(self, num_envs: int, objects: Sequence[str] | None = None,
                   **changes: object) -> EnvConfig:
        """The run's env config with ``num_envs`` envs, on ``objects`` when given, and
        ``changes`` (``EnvConfig`` fields, e.g. ``compile=False``); on ``objects`` nothing is
        held out (they may be the run's held-out objects)."""
        if objects is not None:
            changes["objects"] = ",".join(objects)
            changes.setdefault("held_out", "")
        return dataclasses.replace(self.cfg.env, num_envs=num_envs, **changes)

    def env(self, num_envs: int, seed: int | RandomStreams,
            objects: Sequence[str] | None = None, quiet: bool = False,
            **changes: object) -> GraspTask:
        """A new env of ``env_config(num_envs, objects, **changes)``, its randomness from
        ``seed`` (``make_env``: an int seeds derived streams; ``streams(seed)`` as the run
        derives them). ``quiet``: the warnings of its build (e.g. homes that touch objects)
        silenced."""
        cfg = self.env_config(num_envs, objects, **changes)
        if not quiet:
            return make_env(cfg, seed=seed)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return make_env(cfg, seed=seed)

    def bin_env(self, num_envs: int, objects: Sequence[str] | None = None,
                bin_objects: int | None = None, new_bins: bool = False) -> GraspTask:
        """The bin env of a bin run with ``num_envs`` envs: the bins the run trained on (its
        seed draws the same layouts, whose settled states are cached), from ``objects``
        instead of the run's object set when given, with ``bin_objects`` objects per bin
        instead of the run's (new bins of that size, drawn by the run's seed; the paper
        evaluates its five-object policy on ten-object bins). ``new_bins``: bins the run
        never trained on, drawn by the run's seed plus ``NEW_BINS_SEED_OFFSET`` (their settled
        states are settled once and cached like the run's). Seed its episodes with
        ``env.set_seed``."""
        changes = {}
        if bin_objects is not None:
            changes["bin"] = dataclasses.replace(self.cfg.env.bin, num_objects=bin_objects)
        streams = (self.streams(self.cfg.run.seed + NEW_BINS_SEED_OFFSET) if new_bins
                   else run_streams(self.cfg))
        return make_env(self.env_config(num_envs, objects, **changes), seed=streams)

    @staticmethod
    def lift_batches(names: Sequence[str], episodes_per_object: int,
                     max_envs: int = MAX_ENVS) -> list[tuple[int, list[str]]]:
        """``trainer eval``'s batches of a lift evaluation: (index of the batch's first object
        in ``names``, its objects), as many whole objects per batch as fit in ``max_envs``
        envs of ``episodes_per_object`` episodes each (at least one)."""
        per_batch = max(1, max_envs // episodes_per_object)
        return [(start, list(names[start : start + per_batch]))
                for start in range(0, len(names), per_batch)]

    def lift_episodes(
        self, names: Sequence[str], episodes_per_object: int, seed: int = EVAL_SEED, *,
        deterministic: bool = True, max_envs: int = MAX_ENVS,
        actor: Callable[[TensorDictBase], TensorDictBase] | None = None,
        on_reset: ResetHook | None = None, on_step: StepHook | None = None,
        on_episode: EpisodeHook | None = None,
    ) -> Episodes:
        """``trainer eval``'s lift episodes: exactly ``episodes_per_object`` of each object of
        ``names``, in the batches of ``lift_batches`` (each a new env of
        ``episodes_per_object * len(batch)`` envs, one object per env, seeded ``seed`` plus
        the index of its first object; closed after its episodes). The hooks are called for
        each batch's env in turn; the episodes are every batch's, in order (N =
        ``episodes_per_object * len(names)``), their ``target`` an index into ``names``. A
        bin run's evaluation plays its bins instead (``trainer eval``): an error here."""
        if self.cfg.env.task == "bin":
            raise TrainerError("a bin run: its evaluation episodes are rounds in the run's bins "
                               "(trainer eval), not one object per env")
        parts = []
        for start, chunk in self.lift_batches(names, episodes_per_object, max_envs):
            env = self.env(episodes_per_object * len(chunk), self.streams(seed + start), chunk)
            try:
                part = self.run(env, deterministic, actor=actor, on_reset=on_reset,
                                on_step=on_step, on_episode=on_episode)
            finally:
                env.close()
            parts.append(part._replace(target=part.target + start))
        return Episodes.cat(parts)

    def play_env(self, name: str, episodes: int,
                 seed: int) -> tuple[GraspTask, list[int], torch.Tensor | None]:
        """``trainer play --object NAME``'s env: (env, the envs that play NAME, the target
        slots (E,) long that make NAME their target for ``run(target_slots=...)``, -1
        elsewhere; None for a lift run). Lift: NAME alone in ``episodes`` envs, seeded
        ``streams(seed)``. Bin: the run's bins (``bin_env``), each with as many envs as it
        takes for the bins that hold NAME to have ``episodes`` envs between them, the envs (up
        to ``episodes``) whose bin holds NAME, episodes seeded ``seed``. A name outside the
        run's object set, or in none of its bins, is a one-line error naming the fix."""
        if self.cfg.env.task != "bin":
            return self.env(episodes, self.streams(seed), [name]), list(range(episodes)), None
        names = self.names()
        if name not in names:
            raise TrainerError(
                f"--object {name}: not in the object set {self.cfg.env.objects!r} of this bin "
                f"run: play one of its objects ({_listing(names)})"
            )
        # One env per bin first, to count the bins that hold NAME: every env steps, and with
        # ``episodes`` envs per bin a target in 5 of 64 bins ran 64 x 8 envs for 8 episodes
        # (6.5 minutes of a core). The bins are the same for any number of envs per bin.
        count = min(self.cfg.env.bin.layouts, self.cfg.env.num_envs)
        probe = self.bin_env(count)
        holding = int((probe.assignment.cpu() == probe.objects.names.index(name)).any(1).sum())
        if not holding:
            layouts, known = probe.layouts.cpu(), probe.objects.names
            probe.close()
            held = sorted({known[k] for k in layouts.unique().tolist()})
            raise TrainerError(
                f"--object {name}: none of the run's {len(layouts)} bins holds it (they hold "
                f"{_listing(held)}): play one of those"
            )
        probe.close()
        env = self.bin_env(count * -(-episodes // holding))
        holds = env.assignment.cpu() == env.objects.names.index(name)  # (E, K)
        ids = holds.any(1).nonzero()[:, 0][:episodes].tolist()
        slots = torch.full((env.num_envs,), -1, dtype=torch.long)
        slots[ids] = holds[ids].long().argmax(1)
        env.set_seed(seed)
        return env, ids, slots

    def run(
        self, env: GraspTask, deterministic: bool = True, *,
        actor: Callable[[TensorDictBase], TensorDictBase] | None = None,
        target_slots: torch.Tensor | None = None, watch: Sequence[int] | None = None,
        hold_finished: bool = False, on_reset: ResetHook | None = None,
        on_step: StepHook | None = None, on_episode: EpisodeHook | None = None,
    ) -> Episodes:
        """One episode in every env of ``env`` (``run_episodes``) with the session's policy,
        or ``actor``."""
        return run_episodes(
            env, self.actor if actor is None else actor, deterministic,
            target_slots=target_slots, watch=watch, hold_finished=hold_finished,
            on_reset=on_reset, on_step=on_step, on_episode=on_episode,
        )

    @contextlib.contextmanager
    def sampling(self, seed: int) -> Iterator[None]:
        """Inside: the global torch generators (the policy's sampling) seeded with the
        ``actions`` stream of ``seed``; restored after. A sampled evaluation repeats, and
        leaves the caller's streams alone."""
        where = torch.device(self.cfg.env.device)
        devices = [where.index or 0] if where.type == "cuda" else []
        with torch.random.fork_rng(devices=devices):
            self.streams(seed).seed_global_torch("actions")
            yield


def successes_first(ids: Sequence[int], success: torch.Tensor, count: int) -> list[int]:
    """The first ``count`` of the envs ``ids``, the successful ones (``success`` (E,) bool)
    first, each group in the order of ``ids``: what ``trainer play --tries`` films."""
    return sorted(ids, key=lambda i: not bool(success[i]))[:count]


def _listing(names: Sequence[str], most: int = 12) -> str:
    more = f", ... ({len(names)} in all)" if len(names) > most else ""
    return ", ".join(names[:most]) + more


def eval_parser(description: str) -> argparse.ArgumentParser:
    """The command line of a script that replays ``trainer eval``'s lift episodes
    (``EvalSession.lift_episodes``): ``run_dir``, ``--episodes-per-object`` [50],
    ``--iteration``, ``--objects``, ``--seed`` [trainer eval's]."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("run_dir", type=Path)
    parser.add_argument("--episodes-per-object", type=int, default=50)
    parser.add_argument("--iteration", type=int, default=None)
    parser.add_argument("--objects", default=None)
    parser.add_argument("--seed", type=int, default=EVAL_SEED, help="trainer eval's default")
    return parser
