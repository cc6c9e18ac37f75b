"""A scripted top-down grasp, batched over environments: proof that the physics and the hand
can grasp at all, and the demo behind ``trainer demo``.

Phases (in actions at 30 Hz): move above the env's target object (``GraspTask.target_pose``:
the one object of ``lift``, the episode's target in a ``bin``) with the hand open and the thumb
opposed, descend onto its bounding box from above, close, lift, hold (1 s at the lift height, so
that a video shows what happens to the object after the lift rather than ending on it). The hand
turns about the vertical so that it squeezes the target across its narrowest horizontal width
(from its bounding box). In a bin the script ignores the other objects: it shows that the hand
reaches the target, not that it picks well from clutter.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import torch
from tensordict import TensorDict

from geomgrasp.rotations import matrix_to_axis_angle, quat_to_matrix
from trainer.robots import sih
from trainer.tasks import GraspTask


@dataclass(frozen=True)
class ScriptedGrasp:
    """Timing (actions) and geometry (m, palm frame) of the scripted grasp."""

    approach_steps: int = 40
    descend_steps: int = 35
    close_steps: int = 25
    lift_steps: int = 60
    hold_steps: int = 30
    """Actions after the lift with the grip and the lift goal held (1 s at 30 Hz)."""
    hover: float = 0.10
    """Height above the grasp pose at the end of the approach."""
    grasp_depth: float = 0.16
    """Object centre along the fingers (palm z) at the grasp: close enough to the palm that
    the fingers reach past the object's far side."""
    lateral: float = -0.03
    """Object centre across the palm (palm x), toward the thumb's side (the thumb sits at
    x = -0.03): centred on the fingers, a round object rolls past the thumb as they close."""
    palm_clearance: float = 0.016
    """Object top to the palm (palm y) is ``palm_clearance - 0.026``: the palm box ends at
    y = 0.026, so the palm presses lightly on the object and becomes a third support."""
    lift: float = 0.3
    lift_rate: float = 1.0
    """Fraction of the full hand speed (``pos_step`` per action) used while lifting."""
    thumb_open: float = 0.15
    """Thumb flexion (rad) on the way down: the thumb hangs almost straight down, beside the
    object, reaching below the equator of a 7 cm apple."""
    thumb_closed: float = 0.4
    """Thumb flexion target (rad) when closing: the SIH thumb is short, so it is a post at the
    object's near side that the fingers press the object against (full flexion would curl it
    above the object)."""

    @property
    def total_steps(self) -> int:
        return (
            self.approach_steps
            + self.descend_steps
            + self.close_steps
            + self.lift_steps
            + self.hold_steps
        )


def target_box(env: GraspTask) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Per env, the target's bounding box in the world: centre (E, 3), axes as columns
    (E, 3, 3) and half-extents (E, 3)."""
    obj_pos, obj_quat = env.target_pose()
    rot = quat_to_matrix(obj_quat)
    ids = env.target_objects()
    center = obj_pos + (rot @ env.objects.bbox_center[ids][..., None])[..., 0]
    return center, rot @ env.objects.bbox_rotation[ids], 0.5 * env.objects.bbox_extents[ids]


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


def grasp_frame(env: GraspTask) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Per env: the target's bbox centre (E, 3) and half-height (E,) in the world, and the
    palm-down rotation (E, 3, 3) whose finger axis lies across the target's narrowest
    horizontal width."""
    center, axes, half = target_box(env)
    half_height = (axes[:, 2, :].abs() * half).sum(-1)
    _, finger = narrowest_horizontal(axes, half, 12)
    # Of the two signs, take the one nearer the home direction (-y): less wrist turning.
    home_finger = env.home_rot[:, 2]
    finger = torch.where(((finger @ home_finger) < 0)[:, None], -finger, finger)
    down = torch.tensor([0.0, 0.0, -1.0], device=center.device).expand_as(finger)
    palm_x = torch.linalg.cross(down, finger, dim=-1)
    palm_rot = torch.stack([palm_x, down, finger], dim=-1)
    return center, half_height, palm_rot


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


def scripted_action(env: GraspTask, script: ScriptedGrasp, step: int, plan: dict) -> torch.Tensor:
    """The action (E, 11) for every env at episode step ``step``; ``plan`` holds the grasp
    frame computed at step 0."""
    if step == 0:
        center, half_height, palm_rot = grasp_frame(env)
        keypoint = torch.tensor(sih.PALM_KEYPOINT, device=center.device)
        grasp_local = torch.stack(
            [
                torch.full_like(half_height, script.lateral),
                half_height + script.palm_clearance,
                torch.full_like(half_height, script.grasp_depth),
            ],
            -1,
        )
        # Keypoint position that puts the object's centre at grasp_local in the palm frame.
        goal = center + (palm_rot @ (keypoint - grasp_local)[..., None])[..., 0]
        plan.update(goal=goal, rot=palm_rot)
    goal = plan["goal"].clone()
    closed = torch.ones(5, device=goal.device)
    closed[1] = 2 * script.thumb_closed / sih.THUMB_FLEX_RANGE[1] - 1
    hand = -torch.ones(env.num_envs, 5, device=goal.device)
    hand[:, 0] = 1.0  # thumb opposed throughout
    hand[:, 1] = 2 * script.thumb_open / sih.THUMB_FLEX_RANGE[1] - 1
    t = step
    if t < script.approach_steps:
        goal[:, 2] += script.hover
    elif t < script.approach_steps + script.descend_steps:
        frac = (t - script.approach_steps + 1) / script.descend_steps
        goal[:, 2] += script.hover * (1.0 - frac)
    elif t < script.approach_steps + script.descend_steps + script.close_steps:
        hand[:] = closed
    else:  # lift, then hold: the command settles on the lift goal and stays there
        hand[:] = closed
        goal[:, 2] += script.lift
    lifting = t >= script.approach_steps + script.descend_steps + script.close_steps
    rate = script.lift_rate if lifting else 1.0
    return torch.cat([steer(env, goal, plan["rot"], rate), hand], dim=-1)


def run_scripted_grasp(
    env: GraspTask,
    script: ScriptedGrasp | None = None,
    on_step: Callable[[int], None] | None = None,
    action_fn: Callable[[GraspTask, Any, int, dict], torch.Tensor] = scripted_action,
) -> torch.Tensor:
    """Reset every env, run the script; return (E,) bool: the target was lifted by h_bar at
    some step (the env's ``success``). ``on_step(step)`` is called after every action (e.g. to
    render a frame). ``action_fn(env, script, step, plan)`` gives the actions (E, 11) of another
    script (with a ``total_steps``); ``plan`` starts empty after the reset, for it to fill at
    step 0."""
    script = script or ScriptedGrasp()
    env.reset()
    plan: dict = {}
    lifted = torch.zeros(env.num_envs, dtype=torch.bool, device=env.device)
    for step in range(script.total_steps):
        action = action_fn(env, script, step, plan)
        td = env.step(TensorDict({"action": action}, batch_size=env.batch_size))
        lifted |= td["next", "success"][:, 0]
        if on_step is not None:
            on_step(step)
    return lifted
