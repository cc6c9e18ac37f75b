"""The UR5e arm with the SIH hand on its flange (the paper's robot), the arm commanded by the
Jacobian transpose toward the commanded palm pose.

The arm is built in code from its published DH parameters, with capsule links. Each link body
sits at the previous DH frame and turns about its local z (joint i turns about z_{i-1}); the
next body is offset by TransZ(d)·TransX(a)·RotX(alpha). So the MuJoCo body frames are exactly
the DH frames, and ``dh_forward`` is an independent check of the built model.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np
import torch

from geomgrasp import materials
from geomgrasp.rotations import axis_angle_to_quat
from trainer.assets.collision import BIT_ARM, BIT_OBJECT, BIT_STATIC
from trainer.config import RobotConfig
from trainer.errors import TrainerError
from trainer.kinematics import SiteKinematics, jacobian_transpose_step
from trainer.robots import sih
from trainer.robots.base import Robot, matrix_to_quat_np, quat_to_matrix_np

# --- Standard DH parameters published by Universal Robots (metres, radians) -----------------
# T_i = RotZ(q_i) · TransZ(d_i) · TransX(a_i) · RotX(alpha_i); joint i turns about z_{i-1}.
DH_D = (0.1625, 0.0, 0.0, 0.1333, 0.0997, 0.0996)
DH_A = (0.0, -0.425, -0.3922, 0.0, 0.0, 0.0)
DH_ALPHA = (math.pi / 2, 0.0, 0.0, math.pi / 2, -math.pi / 2, 0.0)
JOINT_RANGE = ((-2 * math.pi, 2 * math.pi),) * 2 + ((-math.pi, math.pi),) + (
    (-2 * math.pi, 2 * math.pi),
) * 3
JOINTS = (
    "shoulder_pan",
    "shoulder_lift",
    "elbow",
    "wrist_1",
    "wrist_2",
    "wrist_3",
)
"""Arm joint names in qpos order (the arm's actuators are ``a_<joint>``, in this order)."""
LINK_MASS = (3.761, 8.058, 2.846, 1.37, 1.3, 0.365)
"""Link masses (kg) of the UR5e URDF, shoulder .. wrist_3 (the base is fixed)."""
HOME = (0.6985, -1.4106, 1.2932, 0.1174, 0.6983, 1.5708)
"""The authors' UR5+SIH start configuration (thumb opposed, hand above the table), rad."""

# Flange (tool0) -> SIH palm frame, from the authors' URDF: tool0 -> optoforce z -0.0065,
# optoforce -> palm z +0.04875 with yaw +pi/2.
FLANGE_TO_PALM_POS = (0.0, 0.0, -0.0065 + 0.04875)
FLANGE_TO_PALM_YAW = math.pi / 2

LINK_RADIUS = (0.06, 0.054, 0.045, 0.04, 0.04, 0.035)
ARM_RGBA = (0.55, 0.6, 0.65, 1.0)


def _axis_angle_quat(axis: tuple[float, float, float], angle: float) -> np.ndarray:
    """Unit quaternion (4,) (w, x, y, z) of a rotation by ``angle`` rad about unit ``axis``."""
    return axis_angle_to_quat(torch.as_tensor(axis, dtype=torch.float64) * angle).numpy()


def add_ur5e(spec: mujoco.MjSpec, robot: RobotConfig) -> mujoco.MjsBody:
    """Add the arm at ``robot.base_pos``; return the last link body (its frame is DH frame 5,
    before the flange offset d6). A ``flange`` site marks tool0. The link capsules are tagged
    with the ``arm`` contact material."""
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
    for i, name in enumerate(JOINTS):
        link = parent.add_body()
        link.name = f"{name}_link"
        link.pos = offset_pos
        link.quat = offset_quat
        link.gravcomp = 1.0
        joint = link.add_joint()
        joint.name = name
        joint.type = mujoco.mjtJoint.mjJNT_HINGE
        joint.axis = (0.0, 0.0, 1.0)
        joint.range = JOINT_RANGE[i]
        joint.limited = mujoco.mjtLimited.mjLIMITED_TRUE
        joint.armature = robot.arm_armature
        d, a = DH_D[i], DH_A[i]
        geom = link.add_geom()
        geom.type = mujoco.mjtGeom.mjGEOM_CAPSULE
        # The DH path of link i runs along z by d, then along x by a; one capsule covers it.
        geom.fromto = (0.0, 0.0, 0.0, a, 0.0, d)
        geom.size = [LINK_RADIUS[i], 0, 0]
        geom.mass = LINK_MASS[i]
        geom.rgba = ARM_RGBA
        geom.contype = BIT_ARM
        geom.conaffinity = BIT_STATIC | BIT_OBJECT
        materials.tag(spec, geom, "arm")
        act = spec.add_actuator()
        act.name = f"a_{name}"
        act.target = name
        act.trntype = mujoco.mjtTrn.mjTRN_JOINT
        act.ctrlrange = JOINT_RANGE[i]
        act.ctrllimited = mujoco.mjtLimited.mjLIMITED_TRUE
        act.set_to_position(kp=robot.arm_kp, kv=robot.arm_damping)
        offset_pos = np.array([a, 0.0, d])
        offset_quat = _axis_angle_quat((1.0, 0.0, 0.0), DH_ALPHA[i])
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
        ca, sa = math.cos(DH_ALPHA[i]), math.sin(DH_ALPHA[i])
        a, d = DH_A[i], DH_D[i]
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
        np.array(FLANGE_TO_PALM_POS),
        _axis_angle_quat((0.0, 0.0, 1.0), FLANGE_TO_PALM_YAW),
    )


class UR5eRobot(Robot):
    """The UR5e + SIH hand: 6 arm position actuators first, then the 5 hand actuators. An
    action's palm-pose command becomes arm joint targets by ``jt_iterations``
    Jacobian-transpose refinements of the previous targets."""

    kind = "ur5e"

    def build(self, spec: mujoco.MjSpec) -> None:  # noqa: D102
        last_link = add_ur5e(spec, self.cfg)
        offset_pos, offset_quat = flange_to_palm()
        flange_pos = np.array([DH_A[5], 0.0, DH_D[5]])
        self.hand.build(spec, last_link, flange_pos + offset_pos, offset_quat)

    def home_joints(self, height: float | None = None, iterations: int = 300) -> np.ndarray:
        """Arm joints (6,) rad that put the hand at ``home_pose(height)``, by damped least
        squares on the DH model started from the authors' home configuration so the elbow
        stays up."""
        keypoint, target_rot = self.home_pose(height)
        target_pos = keypoint - target_rot @ np.array(sih.PALM_KEYPOINT)
        offset_pos, offset_quat = flange_to_palm()
        offset_rot = quat_to_matrix_np(offset_quat)
        base = np.array(self.cfg.base_pos)

        def palm(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            tool = dh_forward(q)
            return base + tool[:3, :3] @ offset_pos + tool[:3, 3], tool[:3, :3] @ offset_rot

        def error(q: np.ndarray) -> np.ndarray:
            pos, rot = palm(q)
            rot_err = np.empty(3)
            mujoco.mju_subQuat(rot_err, matrix_to_quat_np(target_rot), matrix_to_quat_np(rot))
            return np.concatenate([target_pos - pos, rot_err])

        q = np.array(HOME, dtype=np.float64)
        for _ in range(iterations):
            e = error(q)
            if np.linalg.norm(e) < 1e-9:
                break
            jac = np.empty((6, 6))
            for j in range(6):
                dq = np.zeros(6)
                dq[j] = 1e-6
                jac[:, j] = (e - error(q + dq)) / 1e-6
            q = q + jac.T @ np.linalg.solve(jac @ jac.T + 1e-6 * np.eye(6), e)
        if np.linalg.norm(error(q)) > 1e-5:
            raise TrainerError(
                f"the UR5e cannot reach the home hand pose from base {self.cfg.base_pos}: "
                "move [robot] base_pos or home_hand_height"
            )
        return (q + math.pi) % (2 * math.pi) - math.pi

    def _index_base(self, model: mujoco.MjModel) -> None:
        self.arm_qpos = torch.tensor(
            [int(model.joint(n).qposadr[0]) for n in JOINTS], device=self.device
        )
        self.arm_actuators = torch.tensor(
            [model.actuator(f"a_{n}").id for n in JOINTS], device=self.device
        )
        self.palm_kinematics = SiteKinematics(model, ["palm"], self.device)

    def _home_base(
        self, qpos: torch.Tensor, ctrl: torch.Tensor, keypoint: torch.Tensor, rot: torch.Tensor
    ) -> None:
        arm = torch.as_tensor(self.home_joints(float(keypoint[2])), dtype=torch.float32)
        qpos[self.arm_qpos] = arm.to(self.device)
        ctrl[self.arm_actuators] = arm.to(self.device)

    def _base_commands(
        self, ctrl: torch.Tensor, qpos: torch.Tensor, target_pos: torch.Tensor,
        target_rot: torch.Tensor,
    ) -> torch.Tensor:
        # UR5e joint targets by the Jacobian transpose, refining the previous targets.
        qpos = qpos.clone()
        qpos[:, self.arm_qpos] = ctrl[:, self.arm_actuators]
        ctrl[:, self.arm_actuators] = jacobian_transpose_step(
            self.palm_kinematics, qpos, self.arm_qpos, JOINTS, "palm",
            target_pos, target_rot, self.cfg.jt_iterations, self.cfg.jt_rotation_scale,
        )
        return ctrl
