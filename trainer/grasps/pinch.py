"""The fingertip pinch (family ``pinch``): thumb tip against index tip at table height, the way
a person picks a coin, for the small and flat objects the top grasp closes beside or over (the
dice, the knife, the tuna can; the plate at its rim). Measured in results/scripted-table1/.

* **Joint targets.** Thumb rotated to ``thumb_rot`` (-1.29 rad: its tip then meets the index
  tip), ring and little finger curled away (-1.571), the middle finger curled away or moving with
  the index (``middle``). Open: thumb flexion ``open[0]``, index flexion ``open[1]``; the close
  ramps the commands linearly to ``closed`` (past the configuration where the tips meet, so the
  servos keep squeezing). Thumb and index tips meet ~4 cm along the fingers from the palm
  keypoint and ~5 cm below it: the squeeze runs roughly along the finger axis.
* **Orientation.** Palm down, then pitched ``pitch`` degrees fingertips-down and rolled ``roll``
  degrees about the finger axis, so that the thumb and index tips are the hand's lowest points,
  level with each other (the untilted thumb tip hangs ~2 cm below the index tip and would meet
  the table first) with the next-lowest link (the thumb's middle link) ~1 cm higher. The hand
  turns about the vertical so that the squeeze runs across the target's narrowest horizontal
  width (the plate: radially across its rim, see below).
* **Height.** Forward kinematics of the hand (MuJoCo on the env's model, hand joints only) gives,
  for every point of the closing ramp, the lowest point of the two fingertip capsules; the palm
  command follows it so that the fingertips stay ``clearance`` above the table while they close
  (they would otherwise rise ~1 cm). The pinch point (the middle of the two tip pads where their
  gap equals the target's width) goes to the target's centre.
* **The plate** (flat and wider than the hand opens: ``RIM_MIN_WIDTH``, ``RIM_MAX_HEIGHT``): the
  pinch point goes to its rim on the side toward the robot, ``rim_inset`` inside its outer
  radius, the thumb outside and the index inside, squeezing the rim radially. Lifted, the plate
  turns about the pinch and hangs from it (results/graspability-plate-rim-2026-11-26/).
* **Turn** (optional, ``turn`` degrees, after the lift): the held hand rolled about the squeeze
  direction, so that the fingers' flexion planes, which the lift's load lies in, turn toward the
  horizontal; the target's weight (and the hold probe's pull) then loads the pads' friction
  along the flexion joints' axes, not the position servos (measured in
  results/hold-turned-2026-11-26/).
* Phases: approach above the pinch pose (hand open), descend, close, settle, lift ``lift``,
  (turn), hold 1 s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np
import torch

from geomgrasp.rotations import axis_angle_to_matrix, quat_to_matrix
from trainer.grasps.geometry import half_height, narrowest_horizontal, ramp, steer, target_box
from trainer.robots import sih
from trainer.tasks import GraspTask

RIM_MIN_WIDTH = 0.15
"""Flat targets whose narrowest horizontal width (m) exceeds this (the plate) are pinched at the
rim ..."""
RIM_MAX_HEIGHT = 0.05
"""... if their bounding box's height (m) is below this."""


@dataclass(frozen=True)
class Pinch:
    """Timing (actions), joint targets (rad) and geometry (m, degrees) of the pinch."""

    approach_steps: int = 45
    descend_steps: int = 35
    close_steps: int = 40
    settle_steps: int = 10
    """Actions with the grip closed before the lift."""
    lift_steps: int = 60
    hold_steps: int = 30
    hover: float = 0.08
    lift: float = 0.35
    lift_rate: float = 0.5
    pitch: float = 20.0
    """Fingertips-down tilt of the palm (degrees)."""
    roll: float = 5.0
    """Tilt about the finger axis (degrees; positive lowers the index side)."""
    thumb_rot: float = -1.29
    open: tuple[float, float] = (0.0, -0.4)
    """Thumb flexion, index flexion when open."""
    closed: tuple[float, float] = (0.8, -1.2)
    """Thumb flexion, index flexion commanded at the end of the close."""
    middle: str = "curled"
    """``curled`` (out of the way) or ``index`` (moves with the index finger)."""
    clearance: float = 0.003
    """Lowest fingertip point above the table during the close (negative: pressed into it,
    the table holds the tips down)."""
    rim_inset: float = 0.015
    """Plate: pinch point this far inside the rim's outer radius."""
    turn: float = 0.0
    """Degrees the lifted hand rolls about the squeeze direction before the hold (0: none)."""
    turn_steps: int = 0
    """Actions of the turn (the rotation command moves at most ``rot_step`` per action)."""
    handle: bool = False
    """Long flat objects: pinch the middle of the thicker half (the knife's handle) instead of
    the bounding box's centre."""
    follow: bool = False
    """Lower the palm with the fingertips' rise through the whole close, not only until the
    pads' gap reaches the target's width (they ride over a small object instead of stopping)."""

    @property
    def total_steps(self) -> int:
        return (self.approach_steps + self.descend_steps + self.close_steps + self.settle_steps
                + self.lift_steps + self.turn_steps + self.hold_steps)

    @property
    def close_window(self) -> tuple[int, int]:
        """Steps [start, end) in which the fingertips close."""
        start = self.approach_steps + self.descend_steps
        return start, start + self.close_steps

    @property
    def pushed_at(self) -> int:
        """The step whose sideways displacement of the target tells *pushed*: the last of the
        descent (in a pinch the first tip to arrive moves the object by design)."""
        return self.close_window[0] - 1

    def joints(self, frac: float) -> np.ndarray:
        """Actuator targets (5,) at closing fraction ``frac`` (0 open, 1 closed)."""
        th = self.open[0] + frac * (self.closed[0] - self.open[0])
        index = self.open[1] + frac * (self.closed[1] - self.open[1])
        middle = index if self.middle == "index" else -1.571
        return np.array([self.thumb_rot, th, index, middle, -1.571])

    def down(self) -> np.ndarray:
        """The world's down direction in the palm frame (palm down = +y)."""
        a, b = math.radians(self.pitch), math.radians(self.roll)
        return np.array([math.sin(b), math.cos(b) * math.cos(a), math.cos(b) * math.sin(a)])

    def action(self, env: GraspTask, step: int, plan: dict) -> torch.Tensor:
        """The action (E, 11) for every env at episode step ``step``; ``plan`` is filled at
        step 0 (``plan_pinch``)."""
        if step == 0:
            plan.update(plan_pinch(env, self))
        goal = plan["goal"].clone()
        t0 = self.approach_steps
        t1 = t0 + self.descend_steps
        t2 = t1 + self.close_steps
        t3 = t2 + self.settle_steps
        t4 = t3 + self.lift_steps
        frac = ramp(step, t1, self.close_steps)
        k = int(round(frac * (len(plan["fracs"]) - 1)))
        goal[:, 2] = plan["height"][:, k]
        if step < t0:
            goal[:, 2] += self.hover
        elif step < t1:
            goal[:, 2] += self.hover * (1.0 - (step - t0 + 1) / self.descend_steps)
        elif step >= t3:
            goal[:, 2] += self.lift
        act = torch.tensor(self.joints(frac), dtype=torch.float32)
        hand = 2 * (act - env.robot.hand.open) / (env.robot.hand.closed - env.robot.hand.open) - 1
        rate = self.lift_rate if step >= t3 else 1.0
        rot = plan["rot_turned"] if self.turn and step >= t4 else plan["rot"]
        return torch.cat([steer(env, goal, rot, rate), hand.expand(env.num_envs, 5)], dim=-1)


class HandFK:
    """Palm-frame forward kinematics of the hand (the 1:1 couplings applied), from the model."""

    def __init__(self, model: mujoco.MjModel) -> None:
        self.model = model
        self.data = mujoco.MjData(model)
        self.adr = {n: int(model.joint(n).qposadr[0]) for n in sih.JOINTS}
        self.palm = model.body("palm").id
        self.tip_geoms = [g for g in range(model.ngeom)
                          if model.geom_bodyid[g] in (model.body("th_distal").id,
                                                      model.body("if_distal").id)]

    def __call__(self, act: np.ndarray, down: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        """(thumb pad, index pad) positions (3,) in the palm frame and the lowest point (m) of
        the fingertip capsules along ``down`` (palm frame) for actuator targets ``act`` (5,)."""
        driven = [joint for _, joint, _, _ in sih.ACTUATORS]
        values = dict(zip(driven, act, strict=True))
        values.update({follower: values[leader] for follower, leader in sih.COUPLINGS})
        for name, value in values.items():
            self.data.qpos[self.adr[name]] = value
        mujoco.mj_kinematics(self.model, self.data)
        rot, origin = self.data.xmat[self.palm].reshape(3, 3), self.data.xpos[self.palm]

        def local(x: np.ndarray) -> np.ndarray:
            return rot.T @ (x - origin)

        low = -np.inf
        for g in self.tip_geoms:
            axis = rot.T @ self.data.geom_xmat[g].reshape(3, 3)[:, 2]
            centre = local(self.data.geom_xpos[g])
            radius, half = self.model.geom_size[g][:2]
            low = max(low, abs(axis @ down) * half + centre @ down + radius)
        pads = [local(self.data.site_xpos[self.model.site(s).id]) for s in ("tip_th", "tip_if")]
        return pads[0], pads[1], float(low)


def pinch_targets(
    env: GraspTask, rim_inset: float, handle: bool = False
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Per env: the pinch point (E, 3, world; its height unused), the horizontal squeeze
    direction from the index pad to the thumb pad (E, 3) and the width to pinch (E,), m."""
    center, axes, half = target_box(env)
    narrow, squeeze = narrowest_horizontal(axes, half, 24)
    # The squeeze points (index -> thumb) roughly against the fingers; keep the fingers near
    # their home direction (home palm z, away from the robot): squeeze toward the robot.
    home_finger = env.home_rot[:, 2]
    squeeze = torch.where(((squeeze @ home_finger) > 0)[:, None], -squeeze, squeeze)
    # ``narrow`` is a half-width. (Until 2026-11-26 it was compared with the full width
    # RIM_MIN_WIDTH, so the plate, 0.26 m wide, was pinched at its centre, never at its rim.)
    rim = (2 * narrow > RIM_MIN_WIDTH) & (2 * half_height(axes, half) < RIM_MAX_HEIGHT)
    if handle:
        # Long, flat objects (the knife): pinch the thicker half's middle (the handle, not
        # the thin blade), from the surface samples' heights along the long horizontal axis.
        obj_pos, obj_quat = env.target_pose()
        rot = quat_to_matrix(obj_quat)
        local = env.objects.points[env.target_objects()]
        pts = obj_pos[:, None] + (rot[:, None] @ local[..., None])[..., 0]
        long_dir = torch.linalg.cross(squeeze, torch.tensor([0.0, 0.0, 1.0]).expand_as(squeeze),
                                      dim=-1)
        along = ((pts - center[:, None]) * long_dir[:, None]).sum(-1)  # (E, P)
        top_pos = torch.where(along > 0, pts[..., 2], -1.0).amax(-1)
        top_neg = torch.where(along < 0, pts[..., 2], -1.0).amax(-1)
        sign = torch.where(top_pos > top_neg, 1.0, -1.0)
        half_len = along.abs().amax(-1)
        elongated = (half_len > 2 * narrow) & ~rim
        shift = torch.where(elongated, sign * 0.5 * half_len, torch.zeros_like(half_len))
        center = center + shift[:, None] * long_dir
    # Plate: a point on its rim toward the robot (-home finger), squeezing radially outward.
    outward = -home_finger.expand_as(squeeze)
    radius = ((outward[:, None, :] @ axes).abs()[:, 0] * half).sum(-1)
    rim_point = center + outward * (radius[:, None] - rim_inset)
    point = torch.where(rim[:, None], rim_point, center)
    squeeze = torch.where(rim[:, None], outward, squeeze)
    return point, squeeze, torch.where(rim, torch.full_like(narrow, 0.01), 2 * narrow)


def palm_rotation(script: Pinch, squeeze_palm: np.ndarray, squeeze: torch.Tensor) -> torch.Tensor:
    """(E, 3, 3) palm orientations: the palm-frame ``down`` to world -z and the palm-frame
    squeeze direction (horizontal part) to the world ``squeeze`` (E, 3)."""
    down = script.down()
    s = squeeze_palm - (squeeze_palm @ down) * down
    s /= np.linalg.norm(s)
    palm = torch.tensor(np.stack([s, np.cross(down, s), down], -1), dtype=torch.float32)
    world_down = torch.tensor([0.0, 0.0, -1.0]).expand_as(squeeze)
    world = torch.stack([squeeze, torch.linalg.cross(world_down, squeeze, dim=-1), world_down], -1)
    return world @ palm.T


def plan_pinch(env: GraspTask, script: Pinch) -> dict:
    """Per env, from the target's pose after the reset: the keypoint goal (E, 3), the palm
    orientation (E, 3, 3) and the keypoint height (E, F) over the closing fractions (F,)."""
    fk = HandFK(env.model)
    point, squeeze, width = pinch_targets(env, script.rim_inset, script.handle)
    down = script.down()
    fracs = np.linspace(0.0, 1.0, 41)
    table = [fk(script.joints(f), down) for f in fracs]
    gaps = np.array([np.linalg.norm(t[0] - t[1]) for t in table])
    last = int(gaps.argmin()) + 1  # past it the commanded tips would pass through each other
    keypoint = np.array(sih.PALM_KEYPOINT)
    # Closing fraction at which the pad gap equals each target's width (contact).
    contact = np.interp(-width.numpy(), -gaps[:last], fracs[:last])  # gaps fall with frac
    squeeze_palm = table[0][0] - table[0][1]
    rot = palm_rotation(script, squeeze_palm, squeeze)
    # Per env: the table row where the pads touch the target, the keypoint's offset from the
    # pinch point there (world), and the keypoint height for every closing fraction.
    pads = np.array([t[0] + t[1] for t in table]) * 0.5  # (F, 3) pinch points, palm frame
    lows = np.array([t[2] for t in table])
    j = np.clip(np.searchsorted(fracs, contact), 0, len(fracs) - 1)  # (E,)
    local = torch.tensor(keypoint - pads[j], dtype=torch.float32)  # (E, 3)
    offset = (rot @ local[..., None])[..., 0]
    stop = np.full_like(j, len(fracs) - 1) if script.follow else j  # the fingers stop at contact
    low = lows[np.minimum(np.arange(len(fracs))[None, :], stop[:, None])]  # (E, F)
    height = script.clearance + low - keypoint @ down
    goal = point + offset
    # The turn: a roll of the whole hand about the world squeeze direction (E, 3).
    turned = axis_angle_to_matrix(squeeze * math.radians(script.turn)) @ rot
    return {"goal": goal, "rot": rot, "rot_turned": turned,
            "height": torch.tensor(height, dtype=torch.float32), "fracs": fracs}
