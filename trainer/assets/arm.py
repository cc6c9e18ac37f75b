"""The UR5e arm built in code from its published DH parameters, with capsule links.

Each link body sits at the previous DH frame and turns about its local z (joint i turns about
z_{i-1}); the next body is offset by TransZ(d)·TransX(a)·RotX(alpha). So the MuJoCo body frames
are exactly the DH frames, and ``dh_forward`` is an independent check of the built model.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np
import torch

from geomgrasp.rotations import axis_angle_to_quat
from trainer import constants as C
from trainer.config import PhysicsConfig, RobotConfig

LINK_RADIUS = (0.06, 0.054, 0.045, 0.04, 0.04, 0.035)
ARM_RGBA = (0.55, 0.6, 0.65, 1.0)


def _axis_angle_quat(axis: tuple[float, float, float], angle: float) -> np.ndarray:
    """Unit quaternion (4,) (w, x, y, z) of a rotation by ``angle`` rad about unit ``axis``."""
    return axis_angle_to_quat(torch.as_tensor(axis, dtype=torch.float64) * angle).numpy()


def add_ur5e(
    spec: mujoco.MjSpec, physics: PhysicsConfig, robot: RobotConfig
) -> mujoco.MjsBody:
    """Add the arm at ``robot.base_pos``; return the last link body (its frame is DH frame 5,
    before the flange offset d6). A ``flange`` site marks tool0."""
    base = spec.worldbody.add_body()
    base.name = "ur5e_base"
    base.pos = robot.base_pos
    pedestal = base.add_geom()
    pedestal.type = mujoco.mjtGeom.mjGEOM_CYLINDER
    pedestal.size = [0.075, 0.04, 0]
    pedestal.pos = (0.0, 0.0, -0.04)
    pedestal.rgba = ARM_RGBA
    pedestal.contype = 0
    pedestal.conaffinity = 0
    parent = base
    offset_pos = np.zeros(3)
    offset_quat = np.array([1.0, 0.0, 0.0, 0.0])
    for i, name in enumerate(C.UR5E_JOINTS):
        link = parent.add_body()
        link.name = f"{name}_link"
        link.pos = offset_pos
        link.quat = offset_quat
        link.gravcomp = 1.0
        joint = link.add_joint()
        joint.name = name
        joint.type = mujoco.mjtJoint.mjJNT_HINGE
        joint.axis = (0.0, 0.0, 1.0)
        joint.range = C.UR5E_JOINT_RANGE[i]
        joint.limited = mujoco.mjtLimited.mjLIMITED_TRUE
        joint.armature = robot.arm_armature
        d, a = C.UR5E_DH_D[i], C.UR5E_DH_A[i]
        geom = link.add_geom()
        geom.type = mujoco.mjtGeom.mjGEOM_CAPSULE
        # The DH path of link i runs along z by d, then along x by a; one capsule covers it.
        geom.fromto = (0.0, 0.0, 0.0, a, 0.0, d)
        geom.size = [LINK_RADIUS[i], 0, 0]
        geom.mass = C.UR5E_LINK_MASS[i]
        geom.rgba = ARM_RGBA
        geom.contype = C.BIT_ARM
        geom.conaffinity = C.BIT_STATIC | C.BIT_OBJECT
        geom.friction = physics.table_friction
        act = spec.add_actuator()
        act.name = f"a_{name}"
        act.target = name
        act.trntype = mujoco.mjtTrn.mjTRN_JOINT
        act.ctrlrange = C.UR5E_JOINT_RANGE[i]
        act.ctrllimited = mujoco.mjtLimited.mjLIMITED_TRUE
        act.set_to_position(kp=robot.arm_kp, kv=robot.arm_damping)
        offset_pos = np.array([a, 0.0, d])
        offset_quat = _axis_angle_quat((1.0, 0.0, 0.0), C.UR5E_DH_ALPHA[i])
        parent = link
    flange = parent.add_site()
    flange.name = "flange"
    flange.pos = offset_pos
    flange.quat = offset_quat
    flange.group = 4
    return parent


def dh_forward(q: np.ndarray) -> np.ndarray:
    """Pose of tool0 from the DH table: ``q`` (6,) rad -> (4, 4) homogeneous transform, metres,
    in the arm base frame."""
    transform = np.eye(4)
    for i in range(6):
        ct, st = math.cos(q[i]), math.sin(q[i])
        ca, sa = math.cos(C.UR5E_DH_ALPHA[i]), math.sin(C.UR5E_DH_ALPHA[i])
        a, d = C.UR5E_DH_A[i], C.UR5E_DH_D[i]
        step = np.array(
            [
                [ct, -st * ca, st * sa, a * ct],
                [st, ct * ca, -ct * sa, a * st],
                [0.0, sa, ca, d],
                [0.0, 0.0, 0.0, 1.0],
            ]
        )
        transform = transform @ step
    return transform


def flange_to_palm() -> tuple[np.ndarray, np.ndarray]:
    """The palm frame in the flange frame: (pos (3,), quat (4,) wxyz), from the authors' URDF."""
    return (
        np.array(C.FLANGE_TO_PALM_POS),
        _axis_angle_quat((0.0, 0.0, 1.0), C.FLANGE_TO_PALM_YAW),
    )
