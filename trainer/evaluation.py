"""Evaluation of a trained policy: deterministic actions (the Gaussian's mean; or sampled, as in
training), success counted per *target* object (the paper's Table I), and the episodes behind
rollout videos.

Lift: a fixed number of episodes per object (one object per env). Bin: the run's own bins (the
layouts its training drew, from the run's seed) with new episodes; each round gives every env a
target chosen to balance the objects (the fewest episodes so far first), until every object in
the bins has at least ``episodes_per_object`` episodes as the target, or ``max_rounds`` rounds
have run (then the result says it is short).
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path

import torch
from tensordict import TensorDictBase
from torchrl.envs.utils import ExplorationType, set_exploration_type, step_mdp

from geomgrasp.files import atomic_path
from trainer.config import EnvConfig, TrainConfig
from trainer.errors import TrainerError
from trainer.objects import resolve_names
from trainer.randomness import RandomStreams, run_streams
from trainer.report import task_label
from trainer.tasks import GraspTask, make_env
from trainer.training.checkpoint import load_agent
from trainer.training.run_dir import RunDir

MAX_ROUNDS = 20
"""Rounds of bin episodes at most (``trainer eval --max-rounds``)."""


@dataclasses.dataclass(frozen=True)
class EvalResult:
    """Per object (in the order of ``names``): episodes run with it as the target, successes.

    The task as the policy saw it (``task``, ``bin_objects``, ``context``, ``representation``),
    the rounds of episodes run (bin; 1 for lift) and whether every object reached the asked
    episodes (``short``: the objects of the bins that did not within ``max_rounds``; ``absent``:
    objects of the set that no bin holds, never a target)."""

    names: list[str]
    episodes: list[int]
    successes: list[int]
    task: str = "lift"
    representation: str = ""
    bin_objects: int | None = None
    context: str = "none"
    rounds: int = 1
    short: list[str] = dataclasses.field(default_factory=list)
    absent: list[str] = dataclasses.field(default_factory=list)
    success_text: str = ""
    """What counted as a success (``RewardConfig.success_text``)."""
    iteration: int | None = None
    """The checkpoint evaluated: that of this training iteration (None: the run's last)."""
    sampled: bool = False
    """Actions sampled from the policy's Gaussian (as in training) instead of its mean."""
    held: list[int] | None = None
    """Per object, the successes with >= 2 fingertip pads within 2 cm of the target's surface
    at the success step (``pads``; None: not measured)."""
    nearest_pad: list[float | None] | None = None
    """Per object, the median distance (m) of the nearest pad at the success steps (None
    where no success)."""

    @property
    def overall(self) -> float:
        return sum(self.successes) / max(1, sum(self.episodes))

    def rate(self, k: int) -> float:
        return self.successes[k] / max(1, self.episodes[k])

    @property
    def label(self) -> str:
        """``sq`` (lift), ``bin5-bbox``, ``bin5-bbox+ctx``: as ``trainer report`` names groups."""
        return task_label(self.task, self.representation, self.bin_objects, self.context)

    def describe(self) -> str:
        """One line: the task, what the policy sees, and (bin) the rounds run."""
        if self.task != "bin":
            return f"task {self.task}, representation {self.representation}"
        text = (
            f"task bin ({self.bin_objects} objects per bin), representation "
            f"{self.representation}, context {self.context}; {self.rounds} round"
            f"{'s' if self.rounds != 1 else ''} of episodes"
        )
        return text


def force_targets(env: GraspTask, slots: torch.Tensor) -> TensorDictBase:
    """Right after a reset: make slot ``slots[i]`` the target of env i's episode (rows with
    ``slots[i] < 0`` keep theirs); returns the reset observation of the new targets
    (``GraspTask.set_targets``)."""
    return env.set_targets(slots)


def run_episodes(
    env: GraspTask,
    actor: torch.nn.Module,
    deterministic: bool = True,
    on_step: Callable[[], None] | None = None,
    target_slots: torch.Tensor | None = None,
    watch: Sequence[int] | None = None,
    hold_finished: bool = False,
    at_success: Callable[[torch.Tensor], None] | None = None,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """One episode in every env from a fresh reset; returns (success (E,) bool, length (E,),
    target object id (E,), taken right after the reset), on the CPU.

    Envs that finish early keep stepping (nothing is reset) but their outcome is frozen; the
    rollout ends when every env (or every env of ``watch``) has finished. ``target_slots`` (E,):
    the target slot of each env's episode (``force_targets``; -1: the env's own draw).
    ``hold_finished``: a finished env holds its last commands (``GraspTask.hold_action``)
    instead of following the policy past its episode's end (videos: a lift stays lifted).
    ``at_success(mask)`` is called right after a step at which some episodes succeeded, with
    (E,) bool (CPU) marking them, the env in that step's state."""
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
    with torch.no_grad(), set_exploration_type(mode):
        for _ in range(env.cfg.max_steps):
            td = actor(td)
            if hold_finished and finished.any():
                held = finished.to(td.device)
                td["action"][held] = env.hold_action()[held]
            td = env.step(td)
            if on_step is not None:
                on_step()
            done = td["next", "done"][:, 0].cpu() & ~finished
            succeeded = done & td["next", "success"][:, 0].cpu()
            success |= succeeded
            if at_success is not None and bool(succeeded.any()):
                at_success(succeeded)
            length[~finished] += 1
            finished |= done
            if finished[watched].all():
                break
            td = step_mdp(td)
    return success, length, targets


def evaluate(
    run_dir: Path,
    episodes_per_object: int = 10,
    objects: str | None = None,
    seed: int = 12345,
    max_envs: int = 1024,
    device: str | None = None,
    max_rounds: int = MAX_ROUNDS,
    hold_tips: int | None = None,
    iteration: int | None = None,
    out: str | None = None,
    h_bar: float | None = None,
    sample: bool = False,
    pads: bool = False,
    lift_clearance: float | None = None,
) -> EvalResult:
    """Evaluate the run's last checkpoint (or that of ``iteration``) on its object set (or
    ``objects``), on ``device`` (default: the run's), for the run's task; writes
    ``per_object.csv`` and ``table.md`` in the run directory's folder ``out`` (default
    ``eval``; ``eval-sampled`` with ``sample``).

    ``sample``: actions sampled from the policy's Gaussian, as in training (the global torch
    generator seeded with ``seed`` for the evaluation, then restored), instead of its mean.
    ``pads``: also count, per object, the successes held by >= 2 fingertip pads within 2 cm of
    the target's surface at the success step (with ``hold_tips = 0``: which lifts are tosses).

    Success is the run's (``reward.h_bar``, ``hold_tips`` and ``lift_clearance`` of its
    config) unless one of them is given: e.g. ``hold_tips = 2`` evaluates a run trained on any
    rise by held lifts only, ``h_bar = 0.05`` how often the targets are lifted by 5 cm (the
    reward and the episode's end follow it, as in training at that curriculum target),
    ``lift_clearance = 0.01`` how many of those lifts raised the lowest point 1 cm (not tips).

    Lift: exactly ``episodes_per_object`` episodes of each object. Bin: rounds of episodes on
    the run's bins (drawn from ``objects`` instead when given), balanced over the targets, until
    every object in them has been the target ``episodes_per_object`` times or more, at most
    ``max_rounds`` rounds."""
    if episodes_per_object < 1:
        raise TrainerError(f"episodes_per_object must be >= 1, got {episodes_per_object}")
    if max_rounds < 1:
        raise TrainerError(f"max_rounds must be >= 1, got {max_rounds}")
    if out is None:
        out = "eval-sampled" if sample else "eval"
    if not out or Path(out).name != out or out in (".", ".."):
        raise TrainerError(f"out {out!r}: give a folder name inside the run directory, e.g. eval")
    cfg, agent = load_agent(run_dir, device, iteration)
    reward = cfg.env.reward
    if hold_tips is not None:
        reward = dataclasses.replace(reward, hold_tips=hold_tips)
    if lift_clearance is not None:
        reward = dataclasses.replace(reward, lift_clearance=lift_clearance)
    if h_bar is not None:
        # One height: the curriculum's start and hold_from (training's) may not exceed it.
        reward = dataclasses.replace(
            reward, h_bar=h_bar, h_bar_start=h_bar, hold_from=min(reward.hold_from, h_bar)
        )
    cfg = dataclasses.replace(cfg, env=dataclasses.replace(cfg.env, reward=reward))
    names = resolve_names(objects or cfg.env.objects, cfg.env.data_dir)
    collector = SuccessPads(len(names)) if pads else None
    streams = RandomStreams(seed, legacy=not cfg.run.random_streams)
    with _sampling(streams, cfg.env.device) if sample else contextlib.nullcontext():
        if cfg.env.task == "bin":
            result = _evaluate_bin(
                cfg, agent.actor, names, episodes_per_object, seed, max_envs, max_rounds,
                not sample, collector,
            )
        else:
            result = _evaluate_lift(
                cfg.env, agent.actor, names, episodes_per_object, seed, max_envs, not sample,
                collector, legacy=not cfg.run.random_streams,
            )
    result = dataclasses.replace(
        result, success_text=cfg.env.reward.success_text(), iteration=iteration, sampled=sample
    )
    if collector is not None:
        result = dataclasses.replace(result, held=collector.held(),
                                     nearest_pad=collector.nearest())
    write_eval(RunDir(Path(run_dir)), result, out)
    return result


@contextlib.contextmanager
def _sampling(streams: RandomStreams, device: str) -> Iterator[None]:
    """The global torch generators (the policy's sampling) seeded with the ``actions`` stream of
    the evaluation's seed inside, and restored after: a sampled evaluation repeats, and leaves
    the caller's streams alone."""
    where = torch.device(device)
    devices = [where.index or 0] if where.type == "cuda" else []
    with torch.random.fork_rng(devices=devices):
        streams.seed_global_torch("actions")
        yield


class SuccessPads:
    """Per object, the fingertip pads' distances to the target at the success steps
    (``run_episodes(at_success=...)``), for held-or-tossed counts."""

    def __init__(self, num_objects: int) -> None:
        self.num_objects = num_objects
        self.ids: list[torch.Tensor] = []
        self.pads: list[torch.Tensor] = []

    def hook(self, env: GraspTask, offset: int = 0) -> Callable[[torch.Tensor], None]:
        """The ``at_success`` callback for ``env``, its object ids shifted by ``offset``."""
        from trainer.grasps import keypoint_distances

        def at_success(mask: torch.Tensor) -> None:
            self.ids.append(env.target_objects().cpu()[mask] + offset)
            self.pads.append(keypoint_distances(env).cpu()[mask, 1:])

        return at_success

    def _per_object(self) -> tuple[torch.Tensor, torch.Tensor]:
        if not self.ids:
            return torch.zeros(0, dtype=torch.long), torch.zeros(0, 5)
        return torch.cat(self.ids), torch.cat(self.pads)

    def held(self) -> list[int]:
        """Per object: successes with >= 2 pads within 2 cm of the target's surface."""
        from trainer.grasps.outcomes import HELD_DISTANCE, HELD_PADS

        ids, pads = self._per_object()
        held = (pads < HELD_DISTANCE).sum(-1) >= HELD_PADS
        return torch.bincount(ids[held], minlength=self.num_objects).tolist()

    def nearest(self) -> list[float | None]:
        """Per object: the median distance (m) of the nearest pad at success (None: none)."""
        ids, pads = self._per_object()
        nearest = pads.amin(-1)
        return [float(nearest[ids == k].median()) if bool((ids == k).any()) else None
                for k in range(self.num_objects)]


def _evaluate_lift(
    cfg: EnvConfig, actor: torch.nn.Module, names: list[str], episodes_per_object: int,
    seed: int, max_envs: int, deterministic: bool = True, pads: SuccessPads | None = None,
    legacy: bool = False,
) -> EvalResult:
    """legacy: seed the envs as runs before the derived random streams did
    (``trainer.randomness``)."""
    episodes = [0] * len(names)
    successes = [0] * len(names)
    # Objects in batches of envs: each batch runs episodes_per_object episodes of each object.
    per_batch = max(1, max_envs // episodes_per_object)
    for start in range(0, len(names), per_batch):
        chunk = names[start : start + per_batch]
        env_cfg = dataclasses.replace(
            cfg, objects=",".join(chunk), num_envs=episodes_per_object * len(chunk)
        )
        env = make_env(env_cfg, seed=RandomStreams(seed + start, legacy=legacy))
        hook = pads.hook(env, start) if pads is not None else None
        success, _, ids = run_episodes(env, actor, deterministic, at_success=hook)
        for k in range(len(chunk)):
            episodes[start + k] += int((ids == k).sum())
            successes[start + k] += int(success[ids == k].sum())
        env.close()
    return EvalResult(names, episodes, successes, task=cfg.task,
                      representation=cfg.representation)


def run_bins(cfg: TrainConfig, num_envs: int, objects: Sequence[str] | None = None) -> GraspTask:
    """The bin env of a bin run with ``num_envs`` envs: the bins the run trained on (its seed
    draws the same layouts, whose settled states are cached), from ``objects`` instead of the
    run's object set when given. Seed its episodes with ``env.set_seed``."""
    env_cfg = dataclasses.replace(cfg.env, num_envs=num_envs)
    if objects is not None:
        env_cfg = dataclasses.replace(env_cfg, objects=",".join(objects))
    return make_env(env_cfg, seed=run_streams(cfg))


def successes_first(ids: Sequence[int], success: torch.Tensor, count: int) -> list[int]:
    """The first ``count`` of the envs ``ids``, the successful ones (``success`` (E,) bool)
    first, each group in the order of ``ids``: what ``trainer play --tries`` films."""
    return sorted(ids, key=lambda i: not bool(success[i]))[:count]


def play_bins(
    cfg: TrainConfig, name: str, episodes: int
) -> tuple[GraspTask, list[int], torch.Tensor]:
    """For ``trainer play --object NAME`` on a bin run: the run's bins (``run_bins``, each
    with ``episodes`` envs), the envs (up to ``episodes``) whose bin holds NAME, and the target
    slots that make NAME their target (``run_episodes(target_slots=...)``; -1 elsewhere). A name
    outside the run's object set, or in none of its bins, is a one-line error naming the fix."""
    names = resolve_names(cfg.env.objects, cfg.env.data_dir)
    if name not in names:
        raise TrainerError(
            f"--object {name}: not in the object set {cfg.env.objects!r} of this bin run: "
            f"play one of its objects ({_listing(names)})"
        )
    count = min(cfg.env.bin.layouts, cfg.env.num_envs)
    env = run_bins(cfg, count * episodes)
    holds = env.assignment.cpu() == env.objects.names.index(name)  # (E, K)
    ids = holds.any(1).nonzero()[:, 0][:episodes].tolist()
    if not ids:
        layouts, known = env.layouts.cpu(), env.objects.names
        env.close()
        held = sorted({known[k] for k in layouts.unique().tolist()})
        raise TrainerError(
            f"--object {name}: none of the run's {len(layouts)} bins holds it (they hold "
            f"{_listing(held)}): play one of those"
        )
    slots = torch.full((env.num_envs,), -1, dtype=torch.long)
    slots[ids] = holds[ids].long().argmax(1)
    return env, ids, slots


def _metres(value: float | None) -> str:
    return "" if value is None else f"{value:.4f}"


def _listing(names: Sequence[str], most: int = 12) -> str:
    more = f", ... ({len(names)} in all)" if len(names) > most else ""
    return ", ".join(names[:most]) + more


def balanced_targets(assignment: torch.Tensor, counts: torch.Tensor) -> torch.Tensor:
    """(E,) a target slot per env: env by env, the slot whose object has the fewest episodes
    (``counts`` (num_objects,), plus those already planned in this round); ties go to the
    lowest slot counted from the env's index, so that equal objects take turns."""
    E, K = assignment.shape
    planned = counts.clone()
    slots = torch.empty(E, dtype=torch.long)
    for i in range(E):
        row = assignment[i]
        order = (torch.arange(K) + i) % K
        k = int(order[planned[row[order]].argmin()])
        slots[i] = k
        planned[row[k]] += 1
    return slots


def _evaluate_bin(
    cfg: TrainConfig, actor: torch.nn.Module, names: list[str], episodes_per_object: int,
    seed: int, max_envs: int, max_rounds: int, deterministic: bool = True,
    pads: SuccessPads | None = None,
) -> EvalResult:
    env = run_bins(cfg, min(cfg.env.num_envs, max_envs), names)
    env.set_seed(seed)
    assignment = env.assignment.cpu()
    held = torch.zeros(len(names), dtype=torch.bool)
    held[env.layouts.cpu().unique()] = True
    episodes = torch.zeros(len(names), dtype=torch.long)
    successes = torch.zeros(len(names), dtype=torch.long)
    rounds = 0
    while rounds < max_rounds and bool((episodes[held] < episodes_per_object).any()):
        slots = balanced_targets(assignment, episodes)
        success, _, ids = run_episodes(
            env, actor, deterministic, target_slots=slots,
            at_success=pads.hook(env) if pads is not None else None,
        )
        episodes += torch.bincount(ids, minlength=len(names))
        successes += torch.bincount(ids[success], minlength=len(names))
        rounds += 1
    env.close()
    short = [n for k, n in enumerate(names) if held[k] and episodes[k] < episodes_per_object]
    absent = [n for k, n in enumerate(names) if not held[k]]
    return EvalResult(
        names, episodes.tolist(), successes.tolist(), task="bin",
        representation=cfg.env.representation, bin_objects=cfg.env.bin.num_objects,
        context=cfg.env.context, rounds=rounds, short=short, absent=absent,
    )


def write_eval(run: RunDir, result: EvalResult, folder: str = "eval") -> None:
    """``eval/per_object.csv`` (object, episodes, successes, success_rate, then the task as the
    policy saw it: task, bin_objects, context, representation) and ``eval/table.md`` (in
    ``folder`` instead of ``eval/`` when given)."""
    out = run.path / folder
    out.mkdir(parents=True, exist_ok=True)
    task = [result.task, result.bin_objects or "", result.context, result.representation]
    pads = result.held is not None and result.nearest_pad is not None
    with atomic_path(out / "per_object.csv") as tmp, open(tmp, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["object", "episodes", "successes", "success_rate", "task",
                         "bin_objects", "context", "representation",
                         *(["held_successes", "nearest_pad_median_m"] if pads else [])])
        for k, name in enumerate(result.names):
            rate = f"{result.rate(k):.4f}" if result.episodes[k] else ""
            extra = [] if not pads else [result.held[k], _metres(result.nearest_pad[k])]
            writer.writerow([name, result.episodes[k], result.successes[k], rate, *task, *extra])
    checkpoint = ("the last checkpoint" if result.iteration is None
                  else f"the checkpoint of iteration {result.iteration}")
    actions = "; actions sampled from the policy (as in training)" if result.sampled else ""
    lines = [
        f"Success per target object: {result.describe()}; {checkpoint}{actions}.",
        "",
        *([f"Success: the target {result.success_text}.", ""] if result.success_text else []),
        f"| object | episodes | {result.label} |",
        "|---|---:|---:|",
    ]
    for k, name in enumerate(result.names):
        rate = f"{result.rate(k):.2f}" if result.episodes[k] else "—"
        lines.append(f"| {name} | {result.episodes[k]} | {rate} |")
    lines.append(
        f"| **all ({sum(result.episodes)} episodes)** | {sum(result.episodes)} | "
        f"**{result.overall:.2f}** |"
    )
    if pads:
        lines += ["", "Successes held by two or more fingertip pads within 2 cm of the target at "
                  "the success step, and the nearest pad's median distance then:", "",
                  "| object | successes | held | nearest pad, median |", "|---|---:|---:|---:|"]
        for k, name in enumerate(result.names):
            near = result.nearest_pad[k]
            near_text = "—" if near is None else f"{100 * near:.1f} cm"
            lines.append(f"| {name} | {result.successes[k]} | {result.held[k]} | {near_text} |")
    if result.short:
        lines += ["", f"Fewer episodes than asked after {result.rounds} rounds: "
                  f"{', '.join(result.short)}."]
    if result.absent:
        lines += ["", f"In none of the bins (never a target): {', '.join(result.absent)}."]
    with atomic_path(out / "table.md") as tmp:
        tmp.write_text("\n".join(lines) + "\n")
