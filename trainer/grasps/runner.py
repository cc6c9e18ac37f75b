"""One episode runner for every grasp family: reset, step the family's actions, and (when
asked) record the trajectory that ``outcomes.classify`` reads."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Protocol

import torch
from tensordict import TensorDict

from geomgrasp.rotations import quat_to_matrix
from trainer.errors import TrainerError
from trainer.grasps.geometry import narrowest_horizontal, target_box
from trainer.grasps.top import TopGrasp
from trainer.tasks import GraspTask

if TYPE_CHECKING:
    from trainer.config import EnvConfig

WIDTH_DIRECTIONS = 36
"""Horizontal directions (every 5 degrees) over which ``GraspTrajectory.start_width`` takes the
target's narrowest width."""


class GraspScript(Protocol):
    """A grasp family's script: open-loop actions per step, planned at step 0 from the state
    after the reset (``plan`` starts empty for it to fill)."""

    @property
    def total_steps(self) -> int: ...

    @property
    def close_window(self) -> tuple[int, int]:
        """Steps [start, end) in which the hand closes."""
        ...

    @property
    def pushed_at(self) -> int:
        """The step whose sideways displacement of the target (from step 0's) tells
        *pushed* (``outcomes.classify``)."""
        ...

    def action(self, env: GraspTask, step: int, plan: dict) -> torch.Tensor:
        """The actions (E, 11) of every env at episode step ``step``."""
        ...


def keypoint_distances(env: GraspTask) -> torch.Tensor:
    """(E, 6) distances (m, >= 0) of the palm keypoint and the 5 fingertip pads to the
    target's surface (its SDF, the reward's query), in the env's current state."""
    qpos = env.backend.qpos
    obj_pos, obj_quat = env.target_pose(qpos)
    sites = env.kinematics.forward(qpos).site_pos
    return env.objects.sdf.query(sites, obj_pos, obj_quat, env.target_objects()).clamp_min(0)


@dataclass(frozen=True)
class GraspTrajectory:
    """What happened in each env after each action of a scripted episode (T actions, E envs)."""

    target_pos: torch.Tensor
    """(T, E, 3) m: the target's position in the world."""
    pad_height: torch.Tensor
    """(T, E, 5) m: height of the fingertip pad sites (thumb, index, middle, ring, little)."""
    success: torch.Tensor
    """(T, E) bool: the env's success flag (the task's: lifted by h_bar, held if its reward
    asks for it)."""
    success_distance: torch.Tensor
    """(E, 6) m: ``keypoint_distances`` (palm keypoint, then the 5 pads) at the env's first
    success; NaN where it never succeeded."""
    start_up: torch.Tensor | None = None
    """(E,) the world z component of the target's own z axis (its mesh's up) after the first
    action: negative for a target that starts upside down (a plate on its face)."""
    start_width: torch.Tensor | None = None
    """(E,) m: the narrowest horizontal width of the target's bounding box as it rests, after
    the first action (``geometry.narrowest_horizontal``): what a grasp from above must span."""

    @property
    def lifted(self) -> torch.Tensor:
        """(E,) bool: the env succeeded at some step."""
        return self.success.any(0)


class TrajectoryRecorder:
    """Collects a ``GraspTrajectory`` step by step (``capture`` after every action)."""

    def __init__(self, env: GraspTask) -> None:
        self.env = env
        self.target_pos: list[torch.Tensor] = []
        self.pad_height: list[torch.Tensor] = []
        self.success: list[torch.Tensor] = []
        self.success_distance = torch.full((env.num_envs, 6), float("nan"), device=env.device)
        self.succeeded = torch.zeros(env.num_envs, dtype=torch.bool, device=env.device)
        self.start_up: torch.Tensor | None = None
        self.start_width: torch.Tensor | None = None

    def capture(self, success: torch.Tensor) -> None:
        """Record the env's state after an action; ``success`` (E,) bool is that step's flag."""
        env = self.env
        pos, quat = env.target_pose()
        self.target_pos.append(pos.clone())
        self.pad_height.append(env.kinematics.forward(env.backend.qpos).site_pos[:, 1:, 2].clone())
        self.success.append(success.clone())
        if self.start_up is None:
            self.start_up = quat_to_matrix(quat)[:, 2, 2]
            _, axes, half = target_box(env)
            self.start_width = 2 * narrowest_horizontal(axes, half, WIDTH_DIRECTIONS)[0]
        new = success & ~self.succeeded
        if bool(new.any()):  # the SDF query only at the steps where some env first succeeds
            self.success_distance[new] = keypoint_distances(env)[new]
            self.succeeded |= new

    def trajectory(self) -> GraspTrajectory:
        return GraspTrajectory(
            torch.stack(self.target_pos).cpu(), torch.stack(self.pad_height).cpu(),
            torch.stack(self.success).cpu(), self.success_distance.cpu(),
            None if self.start_up is None else self.start_up.cpu(),
            None if self.start_width is None else self.start_width.cpu(),
        )


def run_scripted_grasp(
    env: GraspTask,
    script: GraspScript | None = None,
    on_step: Callable[[int], None] | None = None,
    recorder: TrajectoryRecorder | None = None,
    steps: int | None = None,
) -> torch.Tensor:
    """Reset every env and run ``script`` (default: the top grasp), or its first ``steps``
    actions; return (E,) bool: the env's success at some step. ``on_step(step)`` is called
    after every action (e.g. to render a frame); ``recorder`` captures the trajectory."""
    if env.cfg.robot.hand_action != "absolute":
        raise TrainerError(
            f"the scripted grasps command absolute hand targets, not [robot] hand_action = "
            f"{env.cfg.robot.hand_action!r}: run them with hand_action = \"absolute\""
        )
    script = script or TopGrasp()
    if script.total_steps > env.cfg.max_steps:
        raise TrainerError(
            f"the script runs {script.total_steps} actions, the env's episodes end at "
            f"max_steps = {env.cfg.max_steps}: build it with max_steps >= {script.total_steps} "
            f"(runner.episode_config)"
        )
    env.reset()
    plan: dict = {}
    lifted = torch.zeros(env.num_envs, dtype=torch.bool, device=env.device)
    for step in range(script.total_steps if steps is None else min(steps, script.total_steps)):
        action = script.action(env, step, plan)
        td = env.step(TensorDict({"action": action}, batch_size=env.batch_size))
        success = td["next", "success"][:, 0]
        lifted |= success
        if recorder is not None:
            recorder.capture(success)
        if on_step is not None:
            on_step(step)
    return lifted


def script_config(cfg: EnvConfig) -> EnvConfig:
    """``cfg`` with absolute hand actions, as the scripts command them. A config with relative
    hand actions has the same model and state (its targets are its running commands), so a
    script measures there what it measures in its own mode."""
    return replace(cfg, robot=replace(cfg.robot, hand_action="absolute"))


def episode_config(cfg: EnvConfig, script: GraspScript) -> EnvConfig:
    """``script_config(cfg)`` with episodes long enough for ``script`` (a scripted trial is one
    episode)."""
    return replace(script_config(cfg), max_steps=max(cfg.max_steps, script.total_steps))


def record_grasp(
    env: GraspTask, script: GraspScript, on_step: Callable[[int], None] | None = None
) -> GraspTrajectory:
    """``run_scripted_grasp`` with the trajectory recorded."""
    recorder = TrajectoryRecorder(env)
    run_scripted_grasp(env, script, on_step, recorder)
    return recorder.trajectory()
