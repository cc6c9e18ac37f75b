"""Where episodes start: the start strategies a ``GraspTask`` applies to the envs it resets.

A reset restarts some envs (``ids``); the task's strategies then run in order, each over those
envs, every one behind the same interface (``StartStrategy.apply``):

- ``SettledStart`` (always, first; the paper's): a settled state of the env's layout from the
  bank (``trainer.init_states``), turned about the vertical axis, the robot at the home that
  state starts from, and a new target.
- ``FixedDrop`` (training only, ``[run] fixed_drops``; the authors' public bin task, not the
  paper's): in place of ``SettledStart``, each env keeps one settled state of its layout for
  good, unturned.
- ``GraspStart`` (training only, ``[run] grasp_starts``; not the paper's): a fraction of the
  envs instead starts from a recorded state along a scripted grasp of its object
  (``GraspStarts``, recorded by ``trainer.training.grasp_starts``). Evidence:
  results/cpu-grasp-starts-2026-11-27/, results/cpu-together-starts50-2026-11-27/.
- ``StaggeredStart`` (training only, ``[ppo] stagger_episodes``): once, at the first full reset,
  each episode starts at a random step, so that episodes do not all end in the same step.

A strategy with random draws keeps its generator and checkpoints it (``state_dict``).
"""

from __future__ import annotations

import pickle
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import torch
from tensordict import TensorDict

from geomgrasp.files import atomic_path
from trainer.config import EnvConfig
from trainer.errors import TrainerError
from trainer.init_states import Homes, turned
from trainer.robots import Robot
from trainer.sim.backend import SimBackend
from trainer.tasks.terms import RewardTerm, previous_key

TASK_STATE_KEYS = ("start_height", "start_low", "target_slot", "target_pos", "target_rot",
                   "ctrl", "palm_pos")
"""The task's per-env state a grasp start carries (those the task has); ``step_count`` restarts
at 0 and ``contact_prev`` at its reset marker."""


def initial_state(cfg: EnvConfig, terms: Mapping[str, RewardTerm], homes: Homes,
                  device: torch.device) -> TensorDict:
    """The task's per-env state (E = ``cfg.num_envs``) before its first reset, every env at the
    first home: ``step_count``, ``start_height``, ``target_slot``, the palm's and hand's
    commands (``target_pos``, ``target_rot``, ``ctrl``) and ``palm_pos``; with
    ``reward.lift_clearance`` ``start_low``; per ``difference`` reward term its previous value
    (``trainer.tasks.terms.previous_key``). Keys exist only where used, so that runs without
    an option keep their saved task state."""
    E = cfg.num_envs
    state = TensorDict(
        {
            "step_count": torch.zeros(E, dtype=torch.long),
            "start_height": torch.zeros(E),
            "target_slot": torch.zeros(E, dtype=torch.long),
            "target_pos": homes.keypoint[0].repeat(E, 1),
            "target_rot": homes.rot.repeat(E, 1, 1),
            "ctrl": homes.ctrl[0].repeat(E, 1),
            "palm_pos": homes.keypoint[0].repeat(E, 1),
        },
        batch_size=[E],
        device=device,
    )
    for name, term in terms.items():
        if term.difference:  # NaN right after a reset: the next observation sets it
            state[previous_key(name)] = torch.full((E,), float("nan"), device=device)
    if cfg.reward.lift_clearance > 0:  # the target's lowest surface point at the start, m
        state["start_low"] = torch.zeros(E, device=device)
    return state


class ResettingTask(Protocol):
    """What a start strategy reads and writes of the task it starts (a ``GraspTask``)."""

    cfg: EnvConfig
    device: torch.device
    state: TensorDict
    backend: SimBackend
    robot: Robot
    banks: torch.Tensor
    env_layout: torch.Tensor
    assignment: torch.Tensor
    slot_qpos: torch.Tensor
    home_qpos: torch.Tensor
    home_ctrl: torch.Tensor
    home_keypoint: torch.Tensor
    home_rot: torch.Tensor
    home_index: torch.Tensor
    h_bar: torch.Tensor
    _rng: torch.Generator
    """The reset generator: settled states, yaws, targets and staggered steps draw from it."""

    def _reset_yaw(self, n: int) -> torch.Tensor: ...
    def _choose_targets(self, n: int) -> torch.Tensor: ...
    def _episode_start(self, poses: torch.Tensor, target_slot: torch.Tensor,
                       object_id: torch.Tensor) -> dict[str, torch.Tensor]: ...
    def target_objects(self, target_slot: torch.Tensor | None = None) -> torch.Tensor: ...


class StartStrategy:
    """One way of starting the episodes of the envs a reset restarts."""

    def apply(self, task: ResettingTask, ids: torch.Tensor, full: bool) -> None:
        """Start the episodes of envs ``ids`` (n,) of ``task``; ``full``: every env was reset
        (a collector's first reset)."""
        raise NotImplementedError

    def state_dict(self) -> dict[str, Any]:
        """What a checkpoint keeps of the strategy (its generators)."""
        return {}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Continue from ``state_dict``'s ``state``."""


class SettledStart(StartStrategy):
    """The robot home and the objects in a settled state of the env's layout (drawn from the
    task's reset generator), turned about the vertical axis; the episode's target chosen by
    the task."""

    def states(self, task: ResettingTask, ids: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(n,) the bank index of each env's settled state and (n,) its turn (rad): drawn."""
        n = len(ids)
        pick = torch.randint(task.banks.shape[1], (n,), generator=task._rng, device=task.device)
        return pick, task._reset_yaw(n)

    def apply(self, task: ResettingTask, ids: torch.Tensor, full: bool) -> None:
        n = len(ids)
        if n == 0:
            return
        pick, yaw = self.states(task, ids)
        pose = task.banks[task.env_layout[ids], pick]  # (n, K, 7)
        pose = turned(pose, yaw)
        home = task.home_index[task.env_layout[ids], pick]
        qpos = task.home_qpos[home]
        qpos[:, task.slot_qpos] = pose
        target_slot = task._choose_targets(n)
        object_id = task.assignment[ids].gather(1, target_slot[:, None])[:, 0]
        fresh = TensorDict(
            {
                "step_count": torch.zeros(n, dtype=torch.long, device=task.device),
                **task._episode_start(pose, target_slot, object_id),
                "target_slot": target_slot,
                "target_pos": task.home_keypoint[home],
                "target_rot": task.home_rot.expand(n, 3, 3),
                "ctrl": task.home_ctrl[home],
                "palm_pos": task.home_keypoint[home],
            },
            batch_size=[n],
            device=task.device,
        )
        if "grasp_start" in task.state.keys():  # noqa: SIM118 (a TensorDict)
            fresh["grasp_start"] = torch.zeros(n, dtype=torch.bool, device=task.device)
        task.state[ids] = fresh
        mocap = task.robot.mocap(fresh["target_pos"], fresh["target_rot"])
        task.backend.set_state(
            ids, qpos, torch.zeros(n, task.backend.nv, device=task.device), fresh["ctrl"], *mocap
        )


class FixedDrop(SettledStart):
    """``SettledStart`` with each env's own settled state for good, as it settled (no turn):
    the authors' public bin task keeps each env's first drop. The envs of a layout take its
    bank's states in turn (env j of the layout: state j mod the bank's size), so the envs
    cover the bank before any state repeats. The target is still drawn per episode. Training
    only (``[run] fixed_drops``): ``trainer eval`` draws its states."""

    def states(self, task: ResettingTask, ids: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        layout = task.env_layout  # (E,) non-decreasing: a layout's envs are contiguous
        first = torch.searchsorted(layout, layout)  # each env's layout's first env
        within = torch.arange(len(layout), device=layout.device) - first
        pick = within[ids] % task.banks.shape[1]
        return pick, torch.zeros(len(ids), device=task.device)


class DamagedStarts(TrainerError):
    """A grasp-starts file (``GraspStarts.save``) that does not read back: cut short, other
    bytes, parts missing or of other shapes (one line)."""

    def __init__(self, path: Path, reason: str) -> None:
        super().__init__(f"{path} is damaged ({reason}): delete it, and the run that uses it "
                         f"records its grasp starts again")
        self.path, self.reason = path, reason


def _first_sentence(exc: Exception) -> str:
    """An exception as a short phrase for a one-line message: its type and its message's first
    sentence (torch's unpickling errors run over many lines)."""
    text = str(exc).strip().split("\n")[0].split(". ")[0]
    return f"{type(exc).__name__}: {text[:100]}" if text else type(exc).__name__


@dataclass(frozen=True)
class GraspStarts:
    """Scripted-grasp states of E envs, S captures each (S = rounds x captures per round)."""

    qpos: torch.Tensor
    """(E, S, nq) the simulation's positions."""
    qvel: torch.Tensor
    """(E, S, nv) its velocities."""
    task: TensorDict
    """(E, S) the task's state (``TASK_STATE_KEYS`` it has)."""
    valid: torch.Tensor
    """(E, S) bool: the capture belongs to a trial that lifted its object."""
    lifted: torch.Tensor
    """(E, rounds) bool: each round's trial lifted the env's object (what the scripts achieved
    in this task's physics)."""
    lift: torch.Tensor | None = None
    """(E, S) m: the target's lift at each capture, as the task's reward reads it (a start is
    used only below the object's current lift target); None in files recorded before it was
    kept (every valid capture is used)."""

    def rows(self, first: int, stop: int) -> GraspStarts:
        """The starts of envs ``first`` to ``stop`` - 1 (a process's slice of a distributed
        run's envs)."""
        return GraspStarts(self.qpos[first:stop], self.qvel[first:stop], self.task[first:stop],
                           self.valid[first:stop], self.lifted[first:stop],
                           None if self.lift is None else self.lift[first:stop])

    def save(self, path: Path) -> None:
        """Write to ``path`` whole or not at all (``atomic_path``)."""
        with atomic_path(path) as tmp:
            torch.save({"qpos": self.qpos, "qvel": self.qvel, "task": self.task.to_dict(),
                        "valid": self.valid, "lifted": self.lifted,
                        **({} if self.lift is None else {"lift": self.lift})}, tmp)

    @staticmethod
    def load(path: Path) -> GraspStarts:
        """What ``save`` wrote (on the CPU); a file that does not read back whole, or whose
        parts disagree in shape, is a one-line ``DamagedStarts``."""
        try:
            d = torch.load(path, map_location="cpu", weights_only=True)
        # (torch.load: OSError or RuntimeError for a cut zip, UnpicklingError or KeyError for
        # other bytes; a file that is missing or may not be read is not damaged)
        except (FileNotFoundError, PermissionError):
            raise
        except (OSError, RuntimeError, pickle.UnpicklingError, EOFError, ValueError, KeyError,
                TypeError, AttributeError, IndexError) as exc:
            raise DamagedStarts(path, f"unreadable: {_first_sentence(exc)}") from None
        parts = ("qpos", "qvel", "task", "valid", "lifted")
        missing = [k for k in parts if not isinstance(d, dict) or k not in d]
        if missing:
            raise DamagedStarts(path, f"no {', '.join(missing)}")
        try:
            task = TensorDict(d["task"], batch_size=d["valid"].shape)
            starts = GraspStarts(d["qpos"], d["qvel"], task, d["valid"], d["lifted"],
                                 d.get("lift"))
            E, S = starts.valid.shape
            shapes = [starts.qpos.shape[:2], starts.qvel.shape[:2], starts.lifted.shape[:1],
                      *([] if starts.lift is None else [starts.lift.shape])]
            fits = all(tuple(shape) == (E, S)[:len(shape)] for shape in shapes)
        except (RuntimeError, ValueError, TypeError, AttributeError, IndexError):
            fits = False
        if not fits:
            raise DamagedStarts(path, "parts that do not fit together")
        return starts

    def to(self, device: torch.device) -> GraspStarts:
        return GraspStarts(self.qpos.to(device), self.qvel.to(device), self.task.to(device),
                           self.valid.to(device), self.lifted.to(device),
                           None if self.lift is None else self.lift.to(device))


class GraspStart(StartStrategy):
    """Each reset env starts, with probability ``fraction`` (drawn from ``rng``), from one of
    its own valid recorded states in ``starts`` (the same object and layout), drawn uniformly
    among those whose target had not yet risen to its object's current lift target
    (``task.h_bar``): a state past it would start an episode that has already succeeded. The
    task's ``grasp_start`` state flags those episodes."""

    def __init__(self, starts: GraspStarts, fraction: float, rng: torch.Generator) -> None:
        self.starts, self.fraction, self.rng = starts, fraction, rng

    def apply(self, task: ResettingTask, ids: torch.Tensor, full: bool) -> None:
        if len(ids) == 0:
            return
        starts = self.starts
        valid = starts.valid[ids]  # (n, S)
        if starts.lift is not None:
            below = task.h_bar[task.target_objects()[ids]]  # (n,) m
            valid = valid & (starts.lift[ids] < below[:, None])
        draw = torch.rand(len(ids), generator=self.rng, device=task.device)
        chosen = (draw < self.fraction) & valid.any(1)
        pick = torch.multinomial(valid.float() + 1e-12, 1, generator=self.rng)[:, 0]
        ids, pick = ids[chosen], pick[chosen]
        if len(ids) == 0:
            return
        state = starts.task[ids, pick]
        for key in state.keys():  # noqa: SIM118 (a TensorDict)
            task.state[key][ids] = state[key]
        task.state["grasp_start"][ids] = True
        qpos, qvel = starts.qpos[ids, pick], starts.qvel[ids, pick]
        mocap = task.robot.mocap(state["target_pos"], state["target_rot"])
        task.backend.set_state(ids, qpos, qvel, state["ctrl"], *mocap)

    def state_dict(self) -> dict[str, Any]:
        return {"grasp_rng": self.rng.get_state()}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        if "grasp_rng" in state:
            self.rng.set_state(state["grasp_rng"])


class StaggeredStart(StartStrategy):
    """At the next full reset only: each env's episode starts at a random step in
    [0, ``max_steps``) (drawn from the task's reset generator), so the episodes reach
    ``max_steps`` spread over the following rollouts instead of all in the same step."""

    def __init__(self) -> None:
        self.pending = True

    def apply(self, task: ResettingTask, ids: torch.Tensor, full: bool) -> None:
        if not (self.pending and full):
            return
        self.pending = False
        task.state["step_count"] = torch.randint(
            task.cfg.max_steps, (task.cfg.num_envs,), generator=task._rng, device=task.device
        )
