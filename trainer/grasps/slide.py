"""The slide grasp (family ``slide``): a first step toward lifting a flat object whose rim
no fingertip gets under from above (the plate: its rim's underside is 12-20 mm above the table
in its convex decomposition, the SIH's distal links 20-27 mm thick). **It tips the plate; it
does not lift it yet.**

The hand comes from the robot's side, palm up, fingers pointing at the target's centre and
tilted down by ``pitch`` so that their backs skim the table. It slides in until the fingertips
press on the rim's edge (``slide``), curls the fingers so that their tips rise along the edge
(friction carries the rim up: the plate tips about its far foot), pushes on (``push``), closes
the thumb and lifts.

Measured on the plate (results/graspability-plate-2026-11-26/): the slide alone pushes the
plate 80-140 mm along the table and tips it 2 degrees (the finger-plate friction, 1.0, turns
the fingertips' contact force to within ~45 degrees of horizontal, so they push rather than
wedge under the edge); the curl then tips it 16-21 degrees in every trial, its near rim resting
on the curled fingertips. What is missing is a hold: the thumb cannot reach a rim that rests on
the fingertips, flattening the fingers to slide further under drops the rim, and so does curling
them on; the lift leaves the plate behind.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from trainer.grasps.geometry import ramp, steer, target_box
from trainer.tasks import GraspTask


@dataclass(frozen=True)
class SlideGrasp:
    """Timing (actions at 30 Hz) and geometry (m, rad; hand actions in [-1, 1]) of the slide
    grasp. Distances are horizontal, along the line from the robot's base to the target."""

    approach_steps: int = 50
    descend_steps: int = 30
    slide_steps: int = 50
    curl_steps: int = 30
    push_steps: int = 20
    close_steps: int = 30
    settle_steps: int = 5
    lift_steps: int = 60
    hold_steps: int = 30
    start: float = 0.30
    """Palm keypoint's distance from the target's centre at the end of the descent."""
    slide: float = 0.12
    """How far the palm slides in before the curl."""
    push: float = 0.05
    """How far it pushes on, under the tipped rim, after the curl."""
    height: float = 0.049
    """Palm keypoint's height above the table while sliding (the fingers' backs then skim the
    table at ``pitch``: 0.002 + 0.0225 cos(pitch) + 0.125 sin(pitch))."""
    pitch: float = 0.2
    """Fingers tilted down from horizontal."""
    lateral: float = 0.0
    """Palm offset across the line from the base (m, to the hand's left seen from the base)."""
    hover: float = 0.08
    fingers_open: float = -1.0
    fingers_curled: float = -0.5
    fingers_pushed: float = -0.5
    """The fingers' command at the end of the push (flattening them, -1, drops the rim)."""
    fingers_closed: float = -0.5
    """The fingers' command at the end of the close (curling them on, to 0.5, drops it)."""
    thumb_open: float = -1.0
    thumb_closed: float = 1.0
    slide_rate: float = 0.3
    lift: float = 0.3
    lift_rate: float = 0.5

    @property
    def total_steps(self) -> int:
        return (self.approach_steps + self.descend_steps + self.slide_steps + self.curl_steps
                + self.push_steps + self.close_steps + self.settle_steps + self.lift_steps
                + self.hold_steps)

    @property
    def close_window(self) -> tuple[int, int]:
        start = (self.approach_steps + self.descend_steps + self.slide_steps + self.curl_steps
                 + self.push_steps)
        return start, start + self.close_steps

    @property
    def pushed_at(self) -> int:
        """The last step of the descent: the slide moves the target by design."""
        return self.approach_steps + self.descend_steps - 1

    def plan(self, env: GraspTask) -> dict:
        """Per env: the palm keypoint at the end of the descent (E, 3), the unit slide
        direction (E, 3) and the palm orientation (E, 3, 3)."""
        center = target_box(env)[0]
        base = torch.tensor(env.cfg.robot.base_pos, device=center.device, dtype=center.dtype)
        inward = center - base
        inward[:, 2] = 0.0
        inward = inward / inward.norm(dim=-1, keepdim=True)
        up = torch.zeros_like(inward)
        up[:, 2] = 1.0
        left = torch.cross(up, inward, dim=-1)
        # Palm frame columns: x = y × z, y the palmar normal (up, tilted toward the target),
        # z the fingers (toward the target, tilted down).
        fingers = math.cos(self.pitch) * inward - math.sin(self.pitch) * up
        palmar = math.sin(self.pitch) * inward + math.cos(self.pitch) * up
        rot = torch.stack([torch.cross(palmar, fingers, dim=-1), palmar, fingers], -1)
        start = center.clone()
        start[:, 2] = self.height
        start = start - self.start * inward + self.lateral * left
        return {"start": start, "inward": inward, "rot": rot}

    def action(self, env: GraspTask, step: int, plan: dict) -> torch.Tensor:
        """The action (E, 11) for every env at episode step ``step``."""
        if step == 0:
            plan.update(self.plan(env))
        t_descend = self.approach_steps
        t_slide = t_descend + self.descend_steps
        t_curl = t_slide + self.slide_steps
        t_push = t_curl + self.curl_steps
        t_close, t_settle = self.close_window
        t_lift = t_settle + self.settle_steps
        up = torch.tensor([0.0, 0.0, 1.0], device=plan["start"].device)
        curl = ramp(step, t_curl, self.curl_steps)
        push = ramp(step, t_push, self.push_steps)
        close = ramp(step, t_close, self.close_steps)
        travel = self.slide * ramp(step, t_slide, self.slide_steps) + self.push * push
        goal = plan["start"] + travel * plan["inward"]
        rate = 1.0
        if step < t_descend:
            goal = goal + self.hover * up
        elif step < t_slide:
            goal = goal + self.hover * (1.0 - ramp(step, t_descend, self.descend_steps)) * up
        elif step < t_close:
            rate = self.slide_rate
        elif step >= t_lift:
            goal = goal + self.lift * up
            rate = self.lift_rate
        fingers = (self.fingers_open + curl * (self.fingers_curled - self.fingers_open)
                   + push * (self.fingers_pushed - self.fingers_curled)
                   + close * (self.fingers_closed - self.fingers_pushed))
        thumb = self.thumb_open + close * (self.thumb_closed - self.thumb_open)
        hand = torch.tensor([1.0, thumb, fingers, fingers, fingers], device=goal.device)
        return torch.cat([steer(env, goal, plan["rot"], rate),
                          hand.expand(env.num_envs, 5)], dim=-1)
