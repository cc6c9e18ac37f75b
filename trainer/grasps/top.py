"""The top grasp (family ``top``), batched over environments: proof that the physics and the
hand can grasp at all, and the demo behind ``trainer demo``.

Phases (in actions at 30 Hz): move above the env's target object (``GraspTask.target_pose``:
the one object of ``lift``, the episode's target in a ``bin``) with the hand open and the thumb
opposed, descend onto its bounding box from above, close, lift, hold (1 s at the lift height, so
that a video shows what happens to the object after the lift rather than ending on it). The hand
turns about the vertical so that it squeezes the target across its narrowest horizontal width
(from its bounding box). In a bin the script ignores the other objects: it shows that the hand
reaches the target, not that it picks well from clutter.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from trainer.grasps.geometry import half_height, narrowest_horizontal, steer, target_box
from trainer.robots import sih
from trainer.tasks import GraspTask


@dataclass(frozen=True)
class TopGrasp:
    """Timing (actions) and geometry (m, palm frame) of the top grasp."""

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

    @property
    def close_window(self) -> tuple[int, int]:
        """Steps [start, end) in which the hand closes on the target."""
        start = self.approach_steps + self.descend_steps
        return start, start + self.close_steps

    @property
    def pushed_at(self) -> int:
        """The step whose sideways displacement of the target tells *pushed* (the last of the
        close: the approach, descent or closing fingers knocked it)."""
        return self.close_window[1] - 1

    def action(self, env: GraspTask, step: int, plan: dict) -> torch.Tensor:
        """The action (E, 11) for every env at episode step ``step``; ``plan`` holds the grasp
        frame computed at step 0."""
        if step == 0:
            center, box_half_height, palm_rot = grasp_frame(env)
            keypoint = torch.tensor(sih.PALM_KEYPOINT, device=center.device)
            grasp_local = torch.stack(
                [
                    torch.full_like(box_half_height, self.lateral),
                    box_half_height + self.palm_clearance,
                    torch.full_like(box_half_height, self.grasp_depth),
                ],
                -1,
            )
            # Keypoint position that puts the object's centre at grasp_local in the palm frame.
            goal = center + (palm_rot @ (keypoint - grasp_local)[..., None])[..., 0]
            plan.update(goal=goal, rot=palm_rot)
        goal = plan["goal"].clone()
        closed = torch.ones(5, device=goal.device)
        closed[1] = 2 * self.thumb_closed / sih.THUMB_FLEX_RANGE[1] - 1
        hand = -torch.ones(env.num_envs, 5, device=goal.device)
        hand[:, 0] = 1.0  # thumb opposed throughout
        hand[:, 1] = 2 * self.thumb_open / sih.THUMB_FLEX_RANGE[1] - 1
        t = step
        if t < self.approach_steps:
            goal[:, 2] += self.hover
        elif t < self.approach_steps + self.descend_steps:
            frac = (t - self.approach_steps + 1) / self.descend_steps
            goal[:, 2] += self.hover * (1.0 - frac)
        elif t < self.approach_steps + self.descend_steps + self.close_steps:
            hand[:] = closed
        else:  # lift, then hold: the command settles on the lift goal and stays there
            hand[:] = closed
            goal[:, 2] += self.lift
        lifting = t >= self.approach_steps + self.descend_steps + self.close_steps
        rate = self.lift_rate if lifting else 1.0
        return torch.cat([steer(env, goal, plan["rot"], rate), hand], dim=-1)


def grasp_frame(env: GraspTask) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Per env: the target's bbox centre (E, 3) and half-height (E,) in the world, and the
    palm-down rotation (E, 3, 3) whose finger axis lies across the target's narrowest
    horizontal width."""
    center, axes, half = target_box(env)
    height = half_height(axes, half)
    _, finger = narrowest_horizontal(axes, half, 12)
    # Of the two signs, take the one nearer the home direction (-y): less wrist turning.
    home_finger = env.home_rot[:, 2]
    finger = torch.where(((finger @ home_finger) < 0)[:, None], -finger, finger)
    down = torch.tensor([0.0, 0.0, -1.0], device=center.device).expand_as(finger)
    palm_x = torch.linalg.cross(down, finger, dim=-1)
    palm_rot = torch.stack([palm_x, down, finger], dim=-1)
    return center, height, palm_rot
