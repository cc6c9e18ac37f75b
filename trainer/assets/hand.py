"""The Schunk SIH right hand built in code from its published kinematics (``sih_hand.md``).

Collision geometry is capsules and a box of the real link sizes (the published meshes are
binary STLs we do not ship). Frames: the palm body's frame is the SIH palm frame, fingers along
+z, palmar side +y. Fingers sit at their physical x (see the x-mirror note in ``constants``).
"""

from __future__ import annotations

import mujoco
import numpy as np

from trainer import constants as C
from trainer.config import PhysicsConfig, RobotConfig

FINGER_RADIUS = 0.0105
FINGER_AXIS_Y = 0.006
"""Finger capsules run along z at this y, so their pad reaches y = 0.0165, next to the sites."""
THUMB_RADIUS = 0.0095
PALM_HALF = (0.048, 0.018, 0.0625)
PALM_CENTER = (-0.006, 0.008, 0.0625)
HAND_RGBA = (0.25, 0.25, 0.28, 1.0)


def _capsule(
    body: mujoco.MjsBody,
    start: tuple[float, ...],
    end: tuple[float, ...],
    radius: float,
    mass: float,
    physics: PhysicsConfig,
) -> None:
    geom = body.add_geom()
    geom.type = mujoco.mjtGeom.mjGEOM_CAPSULE
    geom.fromto = np.concatenate([start, end])
    geom.size = [radius, 0, 0]
    geom.mass = mass
    _hand_contact(geom, physics)


def _hand_contact(geom: mujoco.MjsGeom, physics: PhysicsConfig) -> None:
    geom.contype = C.BIT_HAND
    geom.conaffinity = C.BIT_STATIC | C.BIT_OBJECT | C.BIT_HAND
    geom.friction = physics.finger_friction
    geom.condim = physics.condim
    geom.solref = physics.solref
    geom.solimp = physics.solimp
    geom.rgba = HAND_RGBA


def _hinge(
    body: mujoco.MjsBody, name: str, axis: tuple[float, float, float], limits: tuple[float, float]
) -> None:
    joint = body.add_joint()
    joint.name = name
    joint.type = mujoco.mjtJoint.mjJNT_HINGE
    joint.axis = axis
    joint.range = limits
    joint.limited = mujoco.mjtLimited.mjLIMITED_TRUE
    joint.damping = (C.SIH_JOINT_DAMPING, 0.0, 0.0)
    joint.armature = C.SIH_JOINT_ARMATURE


def _link(
    parent: mujoco.MjsBody,
    name: str,
    pos: tuple[float, ...],
    joint: str,
    axis: tuple[float, float, float],
    limits: tuple[float, float],
) -> mujoco.MjsBody:
    """A gravity-compensated child body turning on one hinge at its origin."""
    body = parent.add_body()
    body.name = name
    body.pos = pos
    body.gravcomp = 1.0
    _hinge(body, joint, axis, limits)
    return body


def _site(body: mujoco.MjsBody, name: str, pos: tuple[float, ...]) -> None:
    site = body.add_site()
    site.name = name
    site.pos = pos
    site.size = [0.004, 0, 0]
    site.rgba = (1.0, 0.3, 0.1, 1.0)
    site.group = 4


def add_sih_hand(
    spec: mujoco.MjSpec,
    parent: mujoco.MjsBody,
    pos: tuple[float, float, float],
    quat: tuple[float, float, float, float],
    physics: PhysicsConfig,
    robot: RobotConfig,
) -> mujoco.MjsBody:
    """Add the hand's palm as a child of ``parent`` at ``pos``/``quat`` (wxyz); return the palm.

    Adds 11 hinge joints (``constants.SIH_JOINTS``), 6 coupling equalities, 5 position actuators
    (``constants.SIH_ACTUATORS``), the fingertip sites (``constants.FINGERTIPS``), a ``palm``
    site at the palm keypoint, and the published self-collision exclusions.
    """
    palm = parent.add_body()
    palm.name = "palm"
    palm.pos = pos
    palm.quat = quat
    palm.gravcomp = 1.0
    box = palm.add_geom()
    box.type = mujoco.mjtGeom.mjGEOM_BOX
    box.size = PALM_HALF
    box.pos = PALM_CENTER
    box.mass = 0.35
    _hand_contact(box, physics)
    _site(palm, "palm", C.SIH_PALM_KEYPOINT)

    th_base = _link(
        palm, "th_proximal", C.SIH_THUMB_BASE_POS, "th_rot", (0.0, 0.0, 1.0),
        C.SIH_THUMB_ROT_RANGE,
    )
    _capsule(th_base, (0.0, 0.0, 0.0), C.SIH_THUMB_INTER_POS, THUMB_RADIUS, 0.02, physics)
    th_inter = _link(
        th_base, "th_inter", C.SIH_THUMB_INTER_POS, "th_flex", (0.0, 1.0, 0.0),
        C.SIH_THUMB_FLEX_RANGE,
    )
    _capsule(th_inter, (0.0, 0.0, 0.0), C.SIH_THUMB_DISTAL_POS, THUMB_RADIUS, 0.02, physics)
    th_distal = _link(
        th_inter, "th_distal", C.SIH_THUMB_DISTAL_POS, "th_distal", (0.0, 1.0, 0.0),
        C.SIH_THUMB_FLEX_RANGE,
    )
    _capsule(th_distal, (0.0, 0.0, 0.003), (-0.02, 0.0, 0.006), THUMB_RADIUS, 0.015, physics)
    _site(th_distal, "tip_th", C.SIH_THUMB_TIP_POS)
    # The published list, plus palm <-> th_inter: our palm box is coarser than the palm mesh
    # and touches the thumb's middle link when the thumb is abducted.
    excluded = [("palm", "th_proximal"), ("th_proximal", "th_distal"), ("palm", "th_inter")]

    for finger, (x, z_mcp, proximal_len, distal_len) in C.SIH_FINGERS.items():
        name = f"{finger}_proximal"
        proximal = _link(palm, name, (x, 0.0, z_mcp), name, (1.0, 0.0, 0.0), C.SIH_FINGER_RANGE)
        _capsule(
            proximal,
            (0.0, FINGER_AXIS_Y, 0.0),
            (0.0, FINGER_AXIS_Y, proximal_len),
            FINGER_RADIUS,
            0.02,
            physics,
        )
        name = f"{finger}_distal"
        distal = _link(
            proximal, name, (0.0, 0.0, proximal_len), name, (1.0, 0.0, 0.0), C.SIH_FINGER_RANGE
        )
        _capsule(
            distal,
            (0.0, FINGER_AXIS_Y, 0.0),
            (0.0, FINGER_AXIS_Y, distal_len - 0.008),
            FINGER_RADIUS,
            0.015,
            physics,
        )
        _site(distal, f"tip_{finger}", (0.0, C.SIH_PAD_Y, distal_len))
        excluded += [("palm", proximal.name), (proximal.name, distal.name)]

    for body1, body2 in excluded:
        exclude = spec.add_exclude()
        exclude.bodyname1 = body1
        exclude.bodyname2 = body2
    for follower, leader in C.SIH_COUPLINGS:
        eq = spec.add_equality()
        eq.name = f"couple_{follower}"
        eq.type = mujoco.mjtEq.mjEQ_JOINT
        eq.name1 = follower
        eq.name2 = leader
        eq.data[:5] = [0.0, 1.0, 0.0, 0.0, 0.0]
    for name, joint, open_value, closed_value in C.SIH_ACTUATORS:
        act = spec.add_actuator()
        act.name = name
        act.target = joint
        act.trntype = mujoco.mjtTrn.mjTRN_JOINT
        low, high = sorted((open_value, closed_value))
        act.ctrlrange = (low, high)
        act.ctrllimited = mujoco.mjtLimited.mjLIMITED_TRUE
        act.forcerange = (-robot.hand_forcerange, robot.hand_forcerange)
        act.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE
        act.set_to_position(kp=robot.hand_kp)
    return palm
