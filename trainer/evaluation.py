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
import datetime
from pathlib import Path
from typing import Any

import torch
from tensordict import TensorDictBase

from geomgrasp.files import atomic_path
from geomgrasp.machine import code_version, cpu_model
from geomgrasp.rotations import quat_to_matrix
from trainer.errors import TrainerError
from trainer.grasps.outcomes import HELD_DISTANCE, HELD_PADS
from trainer.grasps.runner import keypoint_distances
from trainer.labels import task_label
from trainer.session import EVAL_SEED, MAX_ENVS, Episodes, EvalSession
from trainer.tasks import GraspTask
from trainer.training.run_dir import BY_START_COLUMNS, RunDir, evaluated_on

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
    new_bins: bool = False
    """Bin: the episodes ran in bins the run never trained on (``--new-bins``)."""
    success_text: str = ""
    """What counted as a success (``RewardConfig.success_text``)."""
    iteration: int | None = None
    """The checkpoint evaluated: that of this training iteration (None: the run's last; 0: the
    agent the run started from)."""
    sampled: bool = False
    """Actions sampled from the policy's Gaussian (as in training) instead of its mean."""
    held: list[int] | None = None
    """Per object, the successes with >= 2 fingertip pads within 2 cm of the target's surface
    at the success step (``pads``; None: not measured)."""
    nearest_pad: list[float | None] | None = None
    """Per object, the median distance (m) of the nearest pad at the success steps (None
    where no success)."""
    endings: dict[str, list[int]] | None = None
    """Per ending (``ENDINGS``: success, never reached, never lifted, dropped, stalled, knocked
    off; never reached only where the run has SDF grids to measure it), per object: the
    episodes that ended so (``EpisodeEndings``; None: not measured)."""
    face_up: list[tuple[int, int]] | None = None
    """Per object, (episodes, successes) of the episodes whose target started face up: its
    mesh's up axis pointing up after the first action (lift; None: not measured). A plate
    that settles upside down is a dome no grasp of this hand has lifted
    (results/cpu-plate-source-2026-11-28/): its held rate is capped by its face-up share."""

    def upside_down(self, k: int) -> tuple[int, int]:
        """(episodes, successes) of object ``k``'s episodes that started upside down."""
        assert self.face_up is not None
        up, up_held = self.face_up[k]
        return self.episodes[k] - up, self.successes[k] - up_held

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
            f"{' in new bins (never trained on)' if self.new_bins else ''}"
        )
        return text


def evaluate(
    run_dir: Path,
    episodes_per_object: int = 10,
    objects: str | None = None,
    seed: int = EVAL_SEED,
    max_envs: int = MAX_ENVS,
    device: str | None = None,
    max_rounds: int = MAX_ROUNDS,
    hold_tips: int | None = None,
    iteration: int | None = None,
    out: str | None = None,
    h_bar: float | None = None,
    sample: bool = False,
    pads: bool = False,
    lift_clearance: float | None = None,
    bin_objects: int | None = None,
    new_bins: bool = False,
) -> EvalResult:
    """Evaluate the run's last checkpoint (or that of ``iteration``; 0: the agent the run
    started from, its ``init_agent``, before any training) on its object set (or ``objects``),
    on ``device`` (default: the run's), for the run's task; writes ``per_object.csv`` and
    ``table.md`` in the run directory's folder ``out`` (default ``eval``; ``eval-sampled``
    with ``sample``; ``eval-start`` for iteration 0).

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
    the run's bins (drawn from ``objects`` instead when given; of ``bin_objects`` objects each
    instead of the run's when given, then written to ``eval-binN`` by default; with
    ``new_bins`` bins the run never trained on, ``session.NEW_BINS_SEED_OFFSET``, written to
    ``eval-new`` / ``eval-binN-new``), balanced over the targets, until every object in them
    has been the target ``episodes_per_object`` times or more, at most ``max_rounds``
    rounds."""
    if episodes_per_object < 1:
        raise TrainerError(f"episodes_per_object must be >= 1, got {episodes_per_object}")
    if max_rounds < 1:
        raise TrainerError(f"max_rounds must be >= 1, got {max_rounds}")
    if bin_objects is not None and bin_objects < 1:
        raise TrainerError(f"bin_objects must be >= 1, got {bin_objects}")
    if out is None:
        out = "eval-sampled" if sample else "eval-start" if iteration == 0 else "eval"
        if bin_objects is not None:
            out = f"{out}-bin{bin_objects}"
        if new_bins:
            out = f"{out}-new"
    if not out or Path(out).name != out or out in (".", ".."):
        raise TrainerError(f"out {out!r}: give a folder name inside the run directory, e.g. eval")
    session = EvalSession.load(run_dir, device, iteration, h_bar=h_bar, hold_tips=hold_tips,
                               lift_clearance=lift_clearance)
    cfg = session.cfg
    if bin_objects is not None and cfg.env.task != "bin":
        raise TrainerError(f"{run_dir} is a {cfg.env.task} run: only a bin run's evaluation "
                           "takes a number of objects per bin")
    if new_bins and cfg.env.task != "bin":
        raise TrainerError(f"{run_dir} is a {cfg.env.task} run: only a bin run has bins to "
                           "draw anew (drop --new-bins)")
    names = session.names(objects)
    collector = SuccessPads() if pads else None
    start_up, endings = StartsFaceUp(), EpisodeEndings()
    hooks = chain_hooks(start_up.hooks(), endings.hooks(),
                        collector.hooks() if collector is not None else {})
    with session.sampling(seed) if sample else contextlib.nullcontext():
        if cfg.env.task == "bin":
            result, episodes = _evaluate_bin(
                session, names, episodes_per_object, seed, max_envs, max_rounds, not sample,
                hooks, bin_objects, new_bins,
            )
        else:
            episodes = session.lift_episodes(names, episodes_per_object, seed,
                                             deterministic=not sample, max_envs=max_envs,
                                             **hooks)
            result = EvalResult(names, *counts_by_object(episodes, len(names)), task=cfg.env.task,
                                representation=cfg.env.representation,
                                face_up=start_up.counts(episodes, len(names)))
    result = dataclasses.replace(
        result, success_text=cfg.env.reward.success_text(), iteration=iteration, sampled=sample,
        endings=endings.counts(episodes, len(names)),
    )
    if collector is not None:
        result = dataclasses.replace(result, held=collector.held(episodes, len(names)),
                                     nearest_pad=collector.nearest(episodes, len(names)))
    write_eval(RunDir(Path(run_dir)), result, out)
    return result


def counts_by_object(episodes: Episodes, num_objects: int) -> tuple[list[int], list[int]]:
    """Per object: (episodes with it as the target, successes)."""
    target = episodes.target
    return (torch.bincount(target, minlength=num_objects).tolist(),
            torch.bincount(target[episodes.success], minlength=num_objects).tolist())


def chain_hooks(*hook_sets: dict[str, Any]) -> dict[str, Any]:
    """The hooks of several collectors (``{"on_reset": f, ...}`` each) as one set: each hook
    calls theirs in order."""
    merged: dict[str, Any] = {}
    for hooks in hook_sets:
        for name, hook in hooks.items():
            before = merged.get(name)
            merged[name] = hook if before is None else (
                lambda *args, _before=before, _hook=hook: (_before(*args), _hook(*args)))
    return merged


class StartsFaceUp:
    """Per episode, whether the target started face up (the z axis of its mesh pointing up
    after the first action, before the hand can have turned it; as scripts/eval_upright.py
    read it): the ``on_step`` hook of ``run_episodes`` / ``EvalSession.lift_episodes``
    (``hooks()``), counted per object over the episodes they returned (``counts``)."""

    def __init__(self) -> None:
        self.parts: list[torch.Tensor] = []
        """Per run, (E,) bool: env i's target started face up."""

    def hooks(self) -> dict[str, Any]:
        return {"on_step": self.on_step}

    def on_step(self, env: GraspTask, step: int, td: TensorDictBase) -> None:
        if step == 0:
            self.parts.append(quat_to_matrix(env.target_pose()[1])[:, 2, 2].cpu() >= 0)

    def counts(self, episodes: Episodes, num_objects: int) -> list[tuple[int, int]]:
        """Per object: (episodes that started face up, their successes)."""
        up = torch.cat(self.parts)
        target = episodes.target[up]
        return list(zip(torch.bincount(target, minlength=num_objects).tolist(),
                        torch.bincount(target[episodes.success[up]],
                                       minlength=num_objects).tolist(), strict=True))


ENDINGS = ("success", "never reached", "never lifted", "dropped", "stalled", "knocked off")
"""How an episode ends (``EpisodeEndings``). ``never reached`` and ``never lifted`` split the
episodes whose target never rose: the hand never came into a holding pose on it (a policy
that does not find the object), or it did and the target still did not rise (one that finds
it but cannot grasp it). Evaluations before 2026-11-30 have ``never lifted`` for both."""
LIFTED_RISE = 0.01
"""A target whose centre never rose this far (m) over its episode was ``never lifted``."""
DROP = 0.03
"""A target that rose and ended this far (m) below its highest point was ``dropped``."""
KNOCKED_OFF = 0.05
"""A target that ended this far (m) below where it started left the table: ``knocked off``."""


def classify_endings(
    start: torch.Tensor, top: torch.Tensor, last: torch.Tensor, success: torch.Tensor,
    lifted: float = LIFTED_RISE, drop: float = DROP, knocked_off: float | None = KNOCKED_OFF,
    reached: torch.Tensor | None = None,
) -> torch.Tensor:
    """(E,) each episode's ending (an index into ``ENDINGS``) from its target centre's height
    (m) at the start, its highest and at the end, and whether it succeeded: ``success``; then
    ``knocked off`` (ended ``knocked_off`` below its start; None: not a class); ``never
    lifted`` (never rose ``lifted``), ``never reached`` instead where ``reached`` (E,) bool is
    given and false (the pads never came into a holding pose on it; None: not a class);
    ``dropped`` (ended more than ``drop`` below its highest); else ``stalled``."""
    out = torch.full(success.shape, ENDINGS.index("stalled"), dtype=torch.long)
    out[last < top - drop] = ENDINGS.index("dropped")
    never = top - start < lifted
    out[never] = ENDINGS.index("never lifted")
    if reached is not None:
        out[never & ~reached] = ENDINGS.index("never reached")
    if knocked_off is not None:
        out[last < start - knocked_off] = ENDINGS.index("knocked off")
    out[success] = ENDINGS.index("success")
    return out


class EpisodeEndings:
    """Per episode, how it ended (``classify_endings``: success, knocked off the table, never
    reached, never lifted, dropped, or stalled up short of success), by the target centre's
    height and whether ``HELD_PADS`` fingertip pads were ever within ``HELD_DISTANCE`` of its
    surface together (the pose a hold needs: ``reached``). The ``on_reset``, ``on_step`` and
    ``on_episode`` hooks of ``run_episodes`` (``hooks()``), counted per object over the
    episodes they returned (``counts``). scripts/episode_outcomes.py prints each episode's
    details with the same classes."""

    def __init__(self) -> None:
        self.parts: list[torch.Tensor] = []
        """Per run, (E,) long: env i's ending (index into ``ENDINGS``; -1: not ended yet)."""

    def hooks(self) -> dict[str, Any]:
        return {"on_reset": self.on_reset, "on_step": self.on_step,
                "on_episode": self.on_episode}

    def on_reset(self, env: GraspTask, td: TensorDictBase) -> None:
        z = env.target_pose()[0][:, 2].cpu()
        self.start, self.top, self.last = z, z.clone(), z
        self.reached = _in_reach(env)  # None: the run loads no SDF grids, nothing to measure
        self.parts.append(torch.full((env.num_envs,), -1, dtype=torch.long))

    def on_step(self, env: GraspTask, step: int, td: TensorDictBase) -> None:
        self.last = env.target_pose()[0][:, 2].cpu()
        self.top = torch.maximum(self.top, self.last)
        if self.reached is not None:
            self.reached |= _in_reach(env)

    def on_episode(self, env: GraspTask, ended: torch.Tensor, success: torch.Tensor) -> None:
        ending = self.parts[-1]
        new = ended & (ending < 0)
        ending[new] = self._classify(success)[new]

    def _classify(self, success: torch.Tensor) -> torch.Tensor:
        """(E,) the ending of each env were its episode over now."""
        return classify_endings(self.start, self.top, self.last, success, reached=self.reached)

    def endings(self) -> torch.Tensor:
        """(N,) every episode's ending, in the order of the runs (an episode still running at
        the last action: its state then, never a success)."""
        if not self.parts:
            return torch.zeros(0, dtype=torch.long)
        last = self.parts[-1]
        open_ = last < 0
        last[open_] = self._classify(torch.zeros_like(open_))[open_]
        return torch.cat(self.parts)

    def counts(self, episodes: Episodes, num_objects: int) -> dict[str, list[int]]:
        """Per ending, per object: the episodes that ended so (without ``never reached`` where
        the run has no SDF grids to measure it with)."""
        endings = self.endings()
        measured = [e for e in ENDINGS if e != "never reached" or self.reached is not None]
        return {name: torch.bincount(episodes.target[endings == ENDINGS.index(name)],
                                     minlength=num_objects).tolist()
                for name in measured}


def _in_reach(env: GraspTask) -> torch.Tensor | None:
    """(E,) bool on the CPU: ``HELD_PADS`` or more fingertip pads within ``HELD_DISTANCE`` of
    the target's surface now; None where the run loads no SDF grids (a run with the
    centre-of-mass reward and no hold test)."""
    if env.objects.sdf is None:
        return None
    pads = keypoint_distances(env)[:, 1:]
    return ((pads < HELD_DISTANCE).sum(-1) >= HELD_PADS).cpu()


class SuccessPads:
    """Per episode, the fingertip pads' distances (m) to the target at its success step: the
    ``on_reset`` and ``on_episode`` hooks of ``run_episodes`` / ``EvalSession.lift_episodes``
    (``hooks()``), for held-or-tossed counts over the episodes they returned (``held``,
    ``nearest``)."""

    def __init__(self) -> None:
        self.parts: list[torch.Tensor] = []
        """Per run, (E, 5) the pads' distances at each env's success step (NaN: none)."""

    def hooks(self) -> dict[str, object]:
        """The keyword arguments that make a run call this collector."""
        return {"on_reset": self.on_reset, "on_episode": self.on_episode}

    def on_reset(self, env: GraspTask, td: TensorDictBase) -> None:
        self.parts.append(torch.full((env.num_envs, 5), float("nan")))

    def on_episode(self, env: GraspTask, ended: torch.Tensor, success: torch.Tensor) -> None:
        if bool(success.any()):
            self.parts[-1][success] = keypoint_distances(env).cpu()[success, 1:]

    def distances(self) -> torch.Tensor:
        """(N, 5) per episode, in the order of the runs (NaN where none succeeded)."""
        return torch.cat(self.parts) if self.parts else torch.zeros(0, 5)

    def _successes(self, episodes: Episodes) -> tuple[torch.Tensor, torch.Tensor]:
        """(target (S,), pads' distances (S, 5)) of the S successful episodes."""
        return episodes.target[episodes.success], self.distances()[episodes.success]

    def held(self, episodes: Episodes, num_objects: int) -> list[int]:
        """Per object: successes with >= 2 pads within 2 cm of the target's surface."""
        ids, pads = self._successes(episodes)
        held = (pads < HELD_DISTANCE).sum(-1) >= HELD_PADS
        return torch.bincount(ids[held], minlength=num_objects).tolist()

    def nearest(self, episodes: Episodes, num_objects: int) -> list[float | None]:
        """Per object: the median distance (m) of the nearest pad at success (None: none)."""
        ids, pads = self._successes(episodes)
        nearest = pads.amin(-1)
        return [float(nearest[ids == k].median()) if bool((ids == k).any()) else None
                for k in range(num_objects)]


def evaluated_line() -> str:
    """The machine, code and time of an evaluation, for its table.md: the same checkpoint and
    seed end some contact-rich episodes differently on another CPU model (its floating point),
    and the same episodes on one machine (13 runs checked: results/cpu-comparison-2026-11-29/,
    2026-11-30)."""
    now = datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC")
    return evaluated_on(cpu_model(), code_version(), now)


def _metres(value: float | None) -> str:
    return "" if value is None else f"{value:.4f}"


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
    session: EvalSession, names: list[str], episodes_per_object: int, seed: int,
    max_envs: int, max_rounds: int, deterministic: bool = True, hooks: dict | None = None,
    bin_objects: int | None = None, new_bins: bool = False,
) -> tuple[EvalResult, Episodes]:
    """The bin evaluation's rounds on the run's bins (or new ones, ``session.bin_env``): the
    result, and every round's episodes one after another (their ``target`` an index into
    ``names``)."""
    cfg = session.cfg
    env = session.bin_env(min(cfg.env.num_envs, max_envs), names, bin_objects, new_bins)
    env.set_seed(seed)
    assignment = env.assignment.cpu()
    held = torch.zeros(len(names), dtype=torch.bool)
    held[env.layouts.cpu().unique()] = True
    episodes = torch.zeros(len(names), dtype=torch.long)
    successes = torch.zeros(len(names), dtype=torch.long)
    parts: list[Episodes] = []
    while len(parts) < max_rounds and bool((episodes[held] < episodes_per_object).any()):
        slots = balanced_targets(assignment, episodes)
        part = session.run(env, deterministic, target_slots=slots, **(hooks or {}))
        episodes += torch.bincount(part.target, minlength=len(names))
        successes += torch.bincount(part.target[part.success], minlength=len(names))
        parts.append(part)
    env.close()
    short = [n for k, n in enumerate(names) if held[k] and episodes[k] < episodes_per_object]
    absent = [n for k, n in enumerate(names) if not held[k]]
    result = EvalResult(
        names, episodes.tolist(), successes.tolist(), task="bin",
        representation=cfg.env.representation, bin_objects=env.cfg.bin.num_objects,
        context=cfg.env.context, rounds=len(parts), short=short, absent=absent,
        new_bins=new_bins,
    )
    return result, Episodes.cat(parts)


def write_eval(run: RunDir, result: EvalResult, folder: str = "eval") -> None:
    """``eval/per_object.csv`` (object, episodes, successes, success_rate, then the task as the
    policy saw it: task, bin_objects, context, representation) and ``eval/table.md`` (in
    ``folder`` instead of ``eval/`` when given); with the start poses measured (lift),
    ``by_start.csv`` (object, face-up episodes and successes, upside-down ones); with the
    endings measured, ``endings.csv`` (object, episodes, then the episodes of each of
    ``ENDINGS``)."""
    out = run.path / folder
    out.mkdir(parents=True, exist_ok=True)
    if result.face_up is not None:
        with atomic_path(out / "by_start.csv") as tmp, open(tmp, "w", newline="") as handle:
            writer = csv.writer(handle)
            writer.writerow(BY_START_COLUMNS)
            for k, name in enumerate(result.names):
                writer.writerow([name, *result.face_up[k], *result.upside_down(k)])
    if result.endings is not None:
        with atomic_path(out / "endings.csv") as tmp, open(tmp, "w", newline="") as handle:
            writer = csv.writer(handle)
            writer.writerow(["object", "episodes",
                             *(e.replace(" ", "_") for e in result.endings)])
            for k, name in enumerate(result.names):
                writer.writerow([name, result.episodes[k],
                                 *(by_object[k] for by_object in result.endings.values())])
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
                  else "the agent the run started from (iteration 0: before its training)"
                  if result.iteration == 0
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
    if result.endings is not None:
        reach = ("" if "never reached" not in result.endings else
                 f"never reached: {HELD_PADS} fingertip pads never within "
                 f"{100 * HELD_DISTANCE:.0f} cm of the target together, and its centre never "
                 f"rose {100 * LIFTED_RISE:.0f} cm; ")
        lines += ["", f"How the episodes ended ({reach}the target's centre: never lifted "
                  f"{100 * LIFTED_RISE:.0f} cm, dropped {100 * DROP:.0f} cm below its highest, "
                  f"stalled up but short of success, knocked off {100 * KNOCKED_OFF:.0f} cm "
                  "below its start):", "",
                  "| object | episodes | " + " | ".join(result.endings) + " |",
                  "|---|---:|" + "---:|" * len(result.endings)]
        for k, name in enumerate(result.names):
            lines.append(f"| {name} | {result.episodes[k]} | "
                         + " | ".join(str(by[k]) for by in result.endings.values()) + " |")
    if result.short:
        lines += ["", f"Fewer episodes than asked after {result.rounds} rounds: "
                  f"{', '.join(result.short)}."]
    if result.absent:
        lines += ["", f"In none of the bins (never a target): {', '.join(result.absent)}."]
    lines += ["", evaluated_line()]
    with atomic_path(out / "table.md") as tmp:
        tmp.write_text("\n".join(lines) + "\n")
