"""PPO on the batched grasping environment, with TorchRL's collector, GAE and ClipPPOLoss.

Reading order: ``train`` is the whole algorithm, top to bottom: collect a rollout of
``frames_per_env`` steps from every env, compute advantages (GAE, values in reward units),
normalize the value targets, run ``epochs`` passes of minibatch updates, update the observation
statistics, log, checkpoint. The run directory layout is in ``RunDir``.

Resuming: a checkpoint holds the networks, optimizer, normalizers, every random generator and
the whole simulation state of every env, so ``train(..., resume=True)`` continues a killed run
exactly as if it had never stopped (``tests/test_ppo.py`` checks this bit for bit). Checkpoints
are written atomically; an unreadable ``last.pt`` falls back to the newest readable
``iter_NNNNNN.pt``.
"""

from __future__ import annotations

import csv
import dataclasses
import json
import math
import shutil
import sys
import time
from collections import deque
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
from torch.utils.tensorboard import SummaryWriter
from torchrl.collectors import Collector
from torchrl.objectives import ClipPPOLoss
from torchrl.objectives.value import GAE
from tqdm import tqdm

from geomgrasp.files import atomic_path
from trainer.config import (
    TrainConfig,
    check_device,
    config_dict,
    predated_fields,
    read_train_config,
)
from trainer.errors import TrainerError
from trainer.models import Agent
from trainer.tasks import GraspTask, make_env, observation_spec

METRICS = (
    "iteration", "env_steps", "wall_time_s", "fps", "success_rate", "object_success_rate", "h_bar",
    "target_success_rate", "episodes", "episode_return", "episode_length", "unstable_resets",
    "loss_objective", "loss_critic", "loss_entropy", "entropy", "kl_approx", "clip_fraction",
    "action_std", "lr",
)
LOSS_KEYS = ("loss_objective", "loss_critic", "loss_entropy", "entropy", "kl_approx", "clip_fraction")  # noqa: E501
CHECKPOINT_KEYS = (
    "iteration", "wall_time_s", "agent", "optimizer", "shuffle_rng", "torch_rng", "outcomes",
    "episode_return", "episode_length", "env",
)
"""Keys every checkpoint has (a file without them is not one; the curriculum's are optional)."""


class ObjectOutcomes:
    """Success at the task's lift height per target object: each object's last ``window``
    episodes.

    ``rate`` is the mean over the objects of their own success rates (the paper's "average
    success rate across all objects"). The plain rate over the last ended episodes
    (``success_rate``) over-counts the objects that are lifted: a lifted object's episode ends
    early, so it ends more episodes per iteration than one that is not (in a run with 300-step
    episodes, ~35 steps against 300)."""

    def __init__(self, window: int) -> None:
        self.window = window
        self.by_object: dict[int, deque[bool]] = {}

    def extend(self, object_ids: list[int], successes: list[bool]) -> None:
        for object_id, success in zip(object_ids, successes, strict=True):
            if object_id not in self.by_object:
                self.by_object[object_id] = deque(maxlen=self.window)
            self.by_object[object_id].append(success)

    def rate(self) -> float:
        """Mean over the objects with an ended episode of their success rates (NaN: none)."""
        rates = [sum(d) / len(d) for d in self.by_object.values() if d]
        return sum(rates) / len(rates) if rates else float("nan")

    def state(self) -> dict[int, list[bool]]:
        return {k: list(v) for k, v in self.by_object.items()}

    def load(self, state: dict[int, list[bool]]) -> None:
        for object_id, values in state.items():
            self.by_object[int(object_id)] = deque(values, maxlen=self.window)


class LiftCurriculum:
    """The training lift target (m): starts at ``reward.h_bar_start`` and rises by
    ``h_bar_increment`` whenever the running success at it reaches ``h_bar_promote`` over a
    full window of ended episodes, until it is ``reward.h_bar``. One target for every object
    over the last ``window`` episodes, or (``reward.curriculum_per_object``) one per object id
    over that object's last ``window / num_objects`` episodes (at least 16)."""

    MIN_OBJECT_WINDOW = 16

    def __init__(self, reward, num_objects: int, window: int) -> None:  # noqa: ANN001
        self.reward = reward
        self.per_object = reward.curriculum_per_object
        self.h_bars = [reward.h_bar_start] * num_objects
        if self.per_object:
            window = max(self.MIN_OBJECT_WINDOW, math.ceil(window / num_objects))
        self.window = window
        self.outcomes: deque[bool] = deque(maxlen=window)
        self.by_object = ObjectOutcomes(window)

    @property
    def active(self) -> bool:
        """Some object's target is still below the task's ``h_bar``."""
        return min(self.h_bars) < self.reward.h_bar

    def targets(self) -> float | list[float]:
        """What ``GraspTask.set_lift_target`` takes."""
        return list(self.h_bars) if self.per_object else self.h_bars[0]

    def mean_h_bar(self) -> float:
        return sum(self.h_bars) / len(self.h_bars)

    def record(self, object_ids: list[int], successes: list[bool]) -> None:
        """Ended episodes: their target object and success at the target they trained for."""
        self.outcomes.extend(successes)
        self.by_object.extend(object_ids, successes)

    def rate(self) -> float:
        """Running success at the current target(s): over all episodes, or the mean of the
        objects' own rates (0 before any episode ended)."""
        if self.per_object:
            rate = self.by_object.rate()
            return 0.0 if math.isnan(rate) else rate
        return sum(self.outcomes) / len(self.outcomes) if self.outcomes else 0.0

    def promote(self) -> bool:
        """Raise every target whose window is full and successful enough; True if any rose
        (its window then starts again)."""
        if not self.per_object:
            h_bar = _next_lift_target(
                self.h_bars[0], self.rate(), len(self.outcomes) == self.window, self.reward
            )
            if h_bar == self.h_bars[0]:
                return False
            self.h_bars = [h_bar] * len(self.h_bars)
            self.outcomes.clear()
            return True
        changed = False
        for object_id, window in self.by_object.by_object.items():
            h_bar = _next_lift_target(
                self.h_bars[object_id], sum(window) / max(len(window), 1),
                len(window) == self.window, self.reward,
            )
            if h_bar != self.h_bars[object_id]:
                self.h_bars[object_id] = h_bar
                window.clear()
                changed = True
        return changed

    def state(self) -> dict:
        if self.per_object:
            return {"h_bar": list(self.h_bars), "target_outcomes": self.by_object.state()}
        return {"h_bar": self.h_bars[0], "target_outcomes": list(self.outcomes)}

    def load(self, checkpoint: dict) -> None:
        """From a checkpoint's ``h_bar`` and ``target_outcomes`` (those from before the
        curriculum existed lack both: the task's ``h_bar``, nothing recorded)."""
        h_bar = checkpoint.get("h_bar", self.reward.h_bar)
        outcomes = checkpoint.get("target_outcomes", [])
        if isinstance(h_bar, (int, float)) == self.per_object:
            raise TrainerError(
                "checkpoint: its lift curriculum is "
                f"{'one target for all objects' if self.per_object else 'per object'}, the "
                "config's is not; resume with the run's own reward.curriculum_per_object"
            )
        if self.per_object:
            self.h_bars = [float(h) for h in h_bar]
            self.by_object.load(outcomes)
        else:
            self.h_bars = [float(h_bar)] * len(self.h_bars)
            self.outcomes.extend(outcomes)


@dataclass(frozen=True)
class RunDir:
    """A training run on disk: ``config.json`` (the resolved config), ``metrics.csv`` (one row
    per iteration), ``tb/`` (TensorBoard), ``checkpoints/iter_NNNNNN.pt`` and ``last.pt``."""

    path: Path

    @property
    def config(self) -> Path:
        return self.path / "config.json"

    @property
    def metrics(self) -> Path:
        return self.path / "metrics.csv"

    @property
    def checkpoints(self) -> Path:
        return self.path / "checkpoints"

    @property
    def last(self) -> Path:
        return self.checkpoints / "last.pt"

    def checkpoint(self, iteration: int) -> Path:
        """The checkpoint written at the end of ``iteration``."""
        return self.checkpoints / f"iter_{iteration:06d}.pt"

    def load_config(self) -> TrainConfig:
        if not self.path.is_dir():
            raise TrainerError(
                f"{self.path}: no such run directory: pass one written by trainer run"
            )
        return read_train_config(self.config)

    def holds_run(self) -> bool:
        """Whether a run (even one killed before its first checkpoint) wrote here."""
        return any(p.exists() for p in (self.config, self.metrics, self.checkpoints))

    def clear(self) -> None:
        """Delete what a run writes here (nothing else in the directory)."""
        for path in (self.config, self.metrics):
            path.unlink(missing_ok=True)
        for path in (self.checkpoints, self.path / "tb", self.path / "eval"):
            shutil.rmtree(path, ignore_errors=True)


def iteration_frames(cfg: TrainConfig) -> int:
    return cfg.env.num_envs * cfg.ppo.frames_per_env


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
) -> RunDir:
    """Train (or, with ``resume``, continue) the run in ``run_dir``; returns it.

    With ``resume``, ``cfg`` is None (the run's config.json) or that config with a larger
    ``run.total_steps`` or ``run.max_minutes`` (extend the run). Without it, a directory that
    already holds a run is refused unless ``overwrite`` (which deletes that run first):
    appending to its metrics would mix two runs.

    ``stop_after``: leave after this many iterations of this call, as a killed run would (the
    work since the last checkpoint is lost); used by the resume test."""
    run = RunDir(Path(run_dir))
    checkpoint = None
    if resume:
        stored = run.load_config()
        for dotted, value in predated_fields(run.config).items():
            parent, name = dotted.rsplit(".", 1)
            raise TrainerError(
                f"{run.path} predates {dotted} (it trained with {name} = {value}, not today's "
                f"default): to resume it as it ran, add \"{name}\": {json.dumps(value)} under "
                f"{parent} in its config.json"
            )
        if cfg is None:
            cfg = stored
        _check_same_run(run, stored, cfg)
        checkpoint = _load_checkpoint(run)
        done, frames = checkpoint["iteration"], iteration_frames(cfg)
        if done >= math.ceil(cfg.run.total_steps / frames):
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
    elif run.holds_run():
        if not overwrite:
            can_resume = run.checkpoints.is_dir() and any(run.checkpoints.glob("*.pt"))
            how = f"resume it with --resume {run.path}, or " if can_resume else ""
            raise TrainerError(
                f"{run.path} already holds a run: {how}start it afresh with --overwrite, or "
                "choose another --run-dir or --seed"
            )
        run.clear()
    assert cfg is not None
    check_device(
        cfg.env.device, f"device {cfg.env.device!r} of {run.path}",
        "resume it where that device exists" if resume else "train with --device cpu",
    )
    torch.set_num_threads(cfg.run.torch_threads)
    torch.manual_seed(cfg.run.seed)
    ppo = cfg.ppo
    # The env first: a config it refuses (a bin larger than the object set, a missing object)
    # leaves no run directory behind that a corrected rerun would have to --overwrite.
    env = make_env(cfg.env, seed=cfg.run.seed)
    run.path.mkdir(parents=True, exist_ok=True)
    with atomic_path(run.config) as tmp:
        tmp.write_text(json.dumps(config_dict(cfg), indent=2))
    device = env.device
    agent = Agent(env.observation_spec, ppo).to(device)
    optimizer = torch.optim.Adam(agent.parameters(), lr=ppo.lr)
    advantage = GAE(gamma=ppo.gamma, lmbda=ppo.lmbda, value_network=agent.critic_denorm)
    loss_module = ClipPPOLoss(
        agent.actor, agent.critic, clip_epsilon=ppo.clip_epsilon,
        entropy_bonus=True, entropy_coeff=ppo.entropy_coef,
        critic_coeff=ppo.critic_coef, loss_critic_type="l2", normalize_advantage=True,
    )
    # Every tensor of the loop lives on the env's device; the minibatch order is drawn there too.
    shuffle = torch.Generator(device=device).manual_seed(cfg.run.seed)
    frames = iteration_frames(cfg)
    total_iterations = math.ceil(cfg.run.total_steps / frames)
    minibatch = minibatch_size(cfg)
    window = cfg.run.success_window or cfg.env.num_envs
    # Success at the task's lift height (the paper's measure) and, for the curriculum, at the
    # current training target.
    outcomes: deque[bool] = deque(maxlen=window)
    object_outcomes = ObjectOutcomes(window)
    curriculum = LiftCurriculum(cfg.env.reward, len(env.objects.names), window)
    episode_return = torch.zeros(cfg.env.num_envs, device=device)
    episode_length = torch.zeros(cfg.env.num_envs, device=device)
    iteration, wall_offset = 0, 0.0
    if checkpoint is not None:
        agent.load_state_dict(checkpoint["agent"])
        optimizer.load_state_dict(checkpoint["optimizer"])
        shuffle.set_state(checkpoint["shuffle_rng"])
        outcomes.extend(checkpoint["outcomes"])
        curriculum.load(checkpoint)
        object_outcomes.load(checkpoint.get("object_outcomes", {}))  # (older checkpoints: none)
        episode_return = checkpoint["episode_return"].to(device)
        episode_length = checkpoint["episode_length"].to(device)
        iteration, wall_offset = checkpoint["iteration"], checkpoint["wall_time_s"]
        env.restore_on_next_reset(checkpoint["env"])
        _truncate_metrics(run.metrics, iteration)
    elif ppo.stagger_episodes:
        env.stagger_next_reset()  # (a resumed run's envs continue where they stood)
    env.set_lift_target(curriculum.targets())
    collector = Collector(
        env, agent.actor, frames_per_batch=frames, total_frames=-1,
        auto_register_policy_transforms=False,
    )
    if checkpoint is not None:
        torch.set_rng_state(checkpoint["torch_rng"])  # after the collector's own set-up
        if device.type == "cuda" and "cuda_rng" in checkpoint:
            torch.cuda.set_rng_state(checkpoint["cuda_rng"], device)
    writer = SummaryWriter(str(run.path / "tb"), purge_step=iteration + 1 if resume else None)
    bar = tqdm(
        total=total_iterations * frames, initial=iteration * frames, unit="step",
        unit_scale=True, disable=not progress, dynamic_ncols=True,
    )
    start = time.perf_counter() - wall_offset
    last_time, last_steps = time.perf_counter(), iteration * frames
    try:
        for data in collector:
            if iteration >= total_iterations or (stop_after is not None and stop_after <= 0):
                break
            if stop_after is not None:
                stop_after -= 1
            iteration += 1
            # data: (E, T). Advantages with values in reward units; the critic learns the
            # normalized targets.
            with torch.no_grad():
                advantage(data)
            agent.value_norm.update(data["value_target"])
            data["value_target"] = agent.value_norm(data["value_target"])
            data["state_value"] = agent.value_norm(data["state_value"])
            # The collector's own bookkeeping (trajectory ids) stays on the CPU: not a loss input.
            flat = data.exclude("collector").reshape(-1)
            # Loss statistics stay on the device (a float() per minibatch would wait for the
            # GPU every time); they are read once per epoch (the learning-rate schedule).
            losses: dict[str, list[torch.Tensor]] = {k: [] for k in LOSS_KEYS}
            for _ in range(ppo.epochs):
                order = torch.randperm(flat.shape[0], generator=shuffle, device=device)
                epoch_kl: list[torch.Tensor] = []
                for index in order.split(minibatch):
                    out = loss_module(flat[index])
                    loss = out["loss_objective"] + out["loss_critic"]
                    if "loss_entropy" in out:
                        loss = loss + out["loss_entropy"]
                    optimizer.zero_grad(set_to_none=True)
                    loss.backward()
                    torch.nn.utils.clip_grad_norm_(agent.parameters(), ppo.max_grad_norm)
                    optimizer.step()
                    for key in LOSS_KEYS:
                        if key in out:
                            losses[key].append(out[key].detach().mean())
                    epoch_kl.append(losses["kl_approx"][-1])
                if ppo.lr_schedule == "adaptive":
                    _adapt_lr(optimizer, float(torch.stack(epoch_kl).mean()), ppo)
            agent.obs_norm.update(*(data[key] for key in agent.obs_keys))

            stats = _episode_stats(
                data, cfg.env.reward.h_bar, outcomes, curriculum, object_outcomes,
                episode_return, episode_length,
            )
            curriculum_on = curriculum.active
            row_h_bar, target_rate = curriculum.mean_h_bar(), curriculum.rate()
            row_h_bars = list(curriculum.h_bars)
            if curriculum.promote():
                env.set_lift_target(curriculum.targets())
            now = time.perf_counter()
            steps = iteration * frames
            row = {
                "iteration": iteration,
                "env_steps": steps,
                "wall_time_s": now - start,
                "fps": (steps - last_steps) / max(now - last_time, 1e-9),
                "success_rate": sum(outcomes) / len(outcomes) if outcomes else float("nan"),
                "object_success_rate": object_outcomes.rate(),
                "h_bar": row_h_bar,
                "target_success_rate": target_rate,
                **stats,
                **{k: (float(torch.stack(v).mean()) if v else float("nan"))
                   for k, v in losses.items()},
                "action_std": float(agent.policy_net.log_std.detach().exp().mean()),
                "lr": optimizer.param_groups[0]["lr"],
            }
            last_time, last_steps = now, steps
            _append_metrics(run.metrics, row)
            for key, value in row.items():
                if key != "iteration":
                    writer.add_scalar(key, value, iteration)
            if curriculum.per_object:  # each object's own target ("h_bar" is their mean)
                for name, value in zip(env.objects.names, row_h_bars, strict=True):
                    writer.add_scalar(f"h_bar/{name}", value, iteration)
            bar.update(frames)
            # No rate before the first episode ends: "nan" would read as a broken run.
            success = f"{row['object_success_rate']:.2f}" if outcomes else "-"
            postfix = {"success": success, "it": iteration}
            if curriculum_on:
                postfix.update(h_bar=f"{row_h_bar:.2f}", at_h_bar=f"{target_rate:.2f}")
            bar.set_postfix(postfix)
            for message in env.backend.drain_warnings():  # e.g. Warp buffers to enlarge
                bar.write(f"warning: {message}")
            out_of_time = _out_of_time(cfg, row["wall_time_s"])
            if (iteration % cfg.run.checkpoint_every == 0 or iteration == total_iterations
                    or out_of_time):
                _save_checkpoint(
                    run, iteration, agent, optimizer, shuffle, outcomes, curriculum,
                    object_outcomes, episode_return, episode_length, env,
                    row["wall_time_s"],
                )
            if out_of_time and iteration < total_iterations:
                bar.write(
                    f"stopped: time budget of {cfg.run.max_minutes:g} minutes used "
                    f"({steps:,} env steps, iteration {iteration}); extend it with "
                    f"--resume {run.path} --minutes M"
                )
                break
    finally:
        bar.close()
        writer.close()
        collector.shutdown()
    return run


def _out_of_time(cfg: TrainConfig, wall_time_s: float) -> bool:
    """The run's time budget (``run.max_minutes``; 0: none) is used up."""
    return cfg.run.max_minutes > 0 and wall_time_s >= 60 * cfg.run.max_minutes


def _adapt_lr(optimizer: torch.optim.Optimizer, kl: float, ppo) -> None:  # noqa: ANN001
    """Keep the policy's step size near ``ppo.kl_target`` (rl_games' adaptive schedule)."""
    low, high = ppo.lr_bounds
    for group in optimizer.param_groups:
        if kl > 2.0 * ppo.kl_target:
            group["lr"] = max(group["lr"] / 1.5, low)
        elif kl < 0.5 * ppo.kl_target:
            group["lr"] = min(group["lr"] * 1.5, high)


def _next_lift_target(h_bar: float, target_rate: float, window_full: bool, reward) -> float:  # noqa: ANN001, E501
    """The curriculum's rule: raise a training lift target once the running success at it
    reaches ``reward.h_bar_promote`` over a full window of episodes."""
    if h_bar >= reward.h_bar or not window_full or target_rate < reward.h_bar_promote:
        return h_bar
    return round(min(h_bar + reward.h_bar_increment, reward.h_bar), 6)  # no 0.09000000000000001


def _episode_stats(
    data, task_h_bar: float, outcomes: deque, curriculum: LiftCurriculum,  # noqa: ANN001
    object_outcomes: ObjectOutcomes, episode_return: torch.Tensor, episode_length: torch.Tensor,
) -> dict[str, float]:
    """Walk the rollout in time (a loop over T steps, not over envs): accumulate returns, record
    the episodes that ended. Updates ``outcomes`` (lifted by the task's ``task_h_bar``),
    ``curriculum`` (by the current training target), ``object_outcomes`` (as
    ``outcomes``, per target object) and the running return/length in place."""
    reward = data["next", "reward"][..., 0]
    done = data["next", "done"][..., 0]
    target_success = data["next", "success"][..., 0]
    success = target_success & (data["next", "lift_height"][..., 0] >= task_h_bar)
    # On the device, without a host sync per step: the return and length each env has at each
    # step, then one transfer of the ended episodes.
    return_at = torch.empty_like(reward)
    length_at = torch.empty_like(reward)
    for t in range(reward.shape[1]):
        episode_return += reward[:, t]
        episode_length += 1
        return_at[:, t] = episode_return
        length_at[:, t] = episode_length
        keep = (~done[:, t]).to(episode_return.dtype)
        episode_return.mul_(keep)
        episode_length.mul_(keep)
    # Episodes in the order they ended (time first, then env).
    ended = done.T.cpu()
    ended_returns = return_at.T.cpu()[ended]
    ended_lengths = length_at.T.cpu()[ended]
    ended_success = success.T.cpu()[ended].tolist()
    outcomes.extend(ended_success)
    # The target of an ended episode is in its last step's "next" (the reset comes after).
    ended_objects = data["next", "object_id"][..., 0].T.cpu()[ended].tolist()
    object_outcomes.extend(ended_objects, ended_success)
    curriculum.record(ended_objects, target_success.T.cpu()[ended].tolist())
    return {
        "episodes": int(ended.sum()),
        "episode_return": float(ended_returns.mean()) if len(ended_returns) else float("nan"),
        "episode_length": float(ended_lengths.mean()) if len(ended_lengths) else float("nan"),
        "unstable_resets": int(data["next", "unstable"].sum()),
    }


def _append_metrics(path: Path, row: dict) -> None:
    new = not path.is_file()
    with open(path, "a", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=METRICS)
        if new:
            writer.writeheader()
        writer.writerow({k: row[k] for k in METRICS})


def _truncate_metrics(path: Path, iteration: int) -> None:
    """Drop the rows a killed run wrote after its last checkpoint (they will be redone)."""
    if not path.is_file():
        return
    with open(path, newline="") as handle:
        rows = [r for r in csv.DictReader(handle) if int(r["iteration"]) <= iteration]
    with atomic_path(path) as tmp, open(tmp, "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=METRICS)
        writer.writeheader()
        writer.writerows(rows)


def _save_checkpoint(
    run: RunDir, iteration: int, agent: Agent, optimizer: torch.optim.Optimizer,
    shuffle: torch.Generator, outcomes: deque, curriculum: LiftCurriculum,
    object_outcomes: ObjectOutcomes, episode_return: torch.Tensor,
    episode_length: torch.Tensor, env: GraspTask, wall_time_s: float,
) -> None:
    state = {
        "iteration": iteration,
        "wall_time_s": wall_time_s,
        "agent": agent.state_dict(),
        "optimizer": optimizer.state_dict(),
        "shuffle_rng": shuffle.get_state(),
        "torch_rng": torch.get_rng_state(),
        **({"cuda_rng": torch.cuda.get_rng_state(env.device)} if env.device.type == "cuda" else {}),
        "outcomes": list(outcomes),
        **curriculum.state(),
        "object_outcomes": object_outcomes.state(),
        "episode_return": episode_return.clone(),
        "episode_length": episode_length.clone(),
        "env": env.snapshot(),
    }
    run.checkpoints.mkdir(parents=True, exist_ok=True)
    with atomic_path(run.checkpoint(iteration)) as tmp:
        torch.save(state, tmp)
    with atomic_path(run.last) as tmp:
        torch.save(state, tmp)


def _check_same_run(run: RunDir, stored: TrainConfig, cfg: TrainConfig) -> None:
    """A resumed run continues bit for bit only with its own config; its length may grow."""
    changed = [
        k for k in _changed_keys(config_dict(stored), config_dict(cfg))
        if k not in ("run.total_steps", "run.max_minutes")
    ]
    if changed:
        raise TrainerError(
            f"{run.path}: a resumed run keeps its config.json, but {', '.join(changed)} differ: "
            "start a new run to change them"
        )


def _changed_keys(a: dict[str, Any], b: dict[str, Any], prefix: str = "") -> list[str]:
    changed = []
    for key in sorted(set(a) | set(b)):
        if isinstance(a.get(key), dict) and isinstance(b.get(key), dict):
            changed += _changed_keys(a[key], b[key], f"{prefix}{key}.")
        elif a.get(key) != b.get(key):
            changed.append(prefix + key)
    return changed


def _load_checkpoint(run: RunDir, map_location: str | None = None) -> dict[str, Any]:
    """The state in ``last.pt`` or, if that is missing or unreadable (a truncated, empty or
    corrupt file), in the newest readable ``iter_NNNNNN.pt``; a fallback is reported on
    stderr."""
    candidates = [run.last, *sorted(run.checkpoints.glob("iter_*.pt"), reverse=True)]
    unreadable = []
    for path in candidates:
        if not path.is_file():
            continue
        state = _read_checkpoint(path, map_location)
        if isinstance(state, str):
            unreadable.append(f"{path.name} ({state})")
            continue
        if unreadable:
            print(
                f"warning: {run.checkpoints}: unreadable {', '.join(unreadable)}; using "
                f"{path.name} (iteration {state['iteration']})", file=sys.stderr, flush=True,
            )
        return state
    if unreadable:
        raise TrainerError(
            f"{run.checkpoints}: no readable checkpoint ({', '.join(unreadable)}): start the run "
            f"again with --overwrite"
        )
    raise TrainerError(f"{run.path}: no checkpoint yet ({run.last}): train it with trainer run")


def _read_checkpoint(path: Path, map_location: str | None) -> dict[str, Any] | str:
    """The state in the checkpoint file ``path``, or why it is not one (a reason, not raised:
    ``_load_checkpoint`` then tries the next file)."""
    try:
        state = torch.load(path, weights_only=False, map_location=map_location)
    except Exception as exc:  # noqa: BLE001 (whatever torch.load raises, the file is bad)
        # An EOFError must not escape: click would turn it into "aborted", as for Ctrl-C.
        return type(exc).__name__
    if not isinstance(state, dict) or any(k not in state for k in CHECKPOINT_KEYS):
        return "not a checkpoint"
    return state


def _load_iteration(run: RunDir, iteration: int) -> dict[str, Any]:
    """The state of the checkpoint of ``iteration``, exactly that one."""
    path = run.checkpoint(iteration)
    if not path.is_file():
        kept = sorted(int(p.stem[5:]) for p in run.checkpoints.glob("iter_*.pt"))
        listed = ", ".join(map(str, kept)) if len(kept) <= 4 else (
            f"{kept[0]}, {kept[1]}, ..., {kept[-1]}")
        have = f"it has iterations {listed}" if kept else "it has none"
        raise TrainerError(f"{run.path}: no checkpoint of iteration {iteration} ({have})")
    state = _read_checkpoint(path, map_location="cpu")  # whatever device it was trained on
    if isinstance(state, str):
        raise TrainerError(f"{path}: unreadable ({state})")
    return state


def load_agent(
    run_dir: Path, device: str | None = None, iteration: int | None = None
) -> tuple[TrainConfig, Agent]:
    """A trained run's config and agent (networks + normalizers) from its last readable
    checkpoint (or that of ``iteration``), on ``device`` (default: the run's), which the
    returned config names."""
    run = RunDir(Path(run_dir))
    cfg = run.load_config()
    if device is not None:
        cfg = dataclasses.replace(cfg, env=dataclasses.replace(cfg.env, device=device))
    check_device(
        cfg.env.device, f"device {cfg.env.device!r} of {run.path}", "pass --device cpu"
    )
    if iteration is None:
        state = _load_checkpoint(run, map_location="cpu")  # whatever device it was trained on
    else:
        state = _load_iteration(run, iteration)
    agent = Agent(observation_spec(cfg.env, 1)["observation"], cfg.ppo)
    agent.load_state_dict(state["agent"])
    agent.eval()
    return cfg, agent.to(cfg.env.device)
