"""What every grasp family needs to know about the target and to move the hand: the target's
bounding box in the world, its narrowest horizontal width, and the hand-pose part of an action
that steers the commanded palm toward a goal."""

from __future__ import annotations

import math

import torch

from geomgrasp.rotations import matrix_to_axis_angle, quat_to_matrix
from trainer.tasks import GraspTask


def target_box(env: GraspTask) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Per env, the target's bounding box in the world: centre (E, 3), axes as columns
    (E, 3, 3) and half-extents (E, 3)."""
    obj_pos, obj_quat = env.target_pose()
    rot = quat_to_matrix(obj_quat)
    ids = env.target_objects()
    center = obj_pos + (rot @ env.objects.bbox_center[ids][..., None])[..., 0]
    return center, rot @ env.objects.bbox_rotation[ids], 0.5 * env.objects.bbox_extents[ids]


def half_height(axes: torch.Tensor, half: torch.Tensor) -> torch.Tensor:
    """(E,) the box's vertical half-extent in the world (axes (E, 3, 3) as columns, half-extents
    (E, 3))."""
    return (axes[:, 2, :].abs() * half).sum(-1)


def narrowest_horizontal(
    axes: torch.Tensor, half: torch.Tensor, samples: int
) -> tuple[torch.Tensor, torch.Tensor]:
    """The box's narrowest horizontal half-width (E,) and its direction (E, 3), over
    ``samples`` directions in [0, pi) (either sign of the direction is as narrow)."""
    angles = torch.linspace(0, math.pi, samples + 1, device=axes.device)[:-1]
    dirs = torch.stack([angles.cos(), angles.sin(), torch.zeros_like(angles)], -1)  # (A, 3)
    width = ((dirs @ axes).abs() * half[:, None, :]).sum(-1)  # (E, A) half-widths
    k = width.argmin(-1)
    return width.gather(-1, k[:, None])[:, 0], dirs[k]


def steer(env: GraspTask, goal: torch.Tensor, rot: torch.Tensor, rate: float = 1.0) -> torch.Tensor:
    """The hand-pose part of the action (E, 6) that moves the commanded palm keypoint toward
    ``goal`` (E, 3) at up to ``rate`` of the full speed and turns the commanded orientation
    toward ``rot`` (E, 3, 3). It steers the command, not the measured hand: the command then
    settles on the goal exactly and the controllers bring the hand there, with no windup from
    tracking lag."""
    robot = env.cfg.robot
    command_pos, command_rot = env.state["target_pos"], env.state["target_rot"]
    move = ((goal - command_pos) / robot.pos_step).clamp(-rate, rate)
    turn = matrix_to_axis_angle(rot @ command_rot.transpose(1, 2)) / robot.rot_step
    return torch.cat([move, turn.clamp(-1.0, 1.0)], dim=-1)


def ramp(step: int, start: int, steps: int) -> float:
    """How much of a phase of ``steps`` actions that begins at action ``start`` is done after
    action ``step``: 0 before it, 1 from its last action on."""
    return min(max((step - start + 1) / steps, 0.0), 1.0)

