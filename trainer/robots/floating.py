"""The SIH hand alone on a floating base: a free body ``hand_base`` (at the palm keypoint)
welded to the mocap body ``hand_target``, which the commanded palm pose moves directly. No arm:
only the 5 hand actuators."""

from __future__ import annotations

import mujoco
import numpy as np
import torch

from geomgrasp.rotations import matrix_to_quat
from trainer.robots import sih
from trainer.robots.base import Robot, matrix_to_quat_np


class FloatingHand(Robot):
    """The SIH hand on a 6-DoF mocap base (``RobotConfig.weld_solref`` sets the weld's
    softness)."""

    kind = "floating"

    def build(self, spec: mujoco.MjSpec) -> None:  # noqa: D102
        keypoint, palm_rot = self.home_pose()
        quat = matrix_to_quat_np(palm_rot)
        target = spec.worldbody.add_body()
        target.name = "hand_target"
        target.mocap = True
        target.pos = keypoint
        target.quat = quat
        base = spec.worldbody.add_body()
        base.name = "hand_base"
        base.pos = keypoint
        base.quat = quat
        base.gravcomp = 1.0
        base.add_freejoint().name = "hand_free"
        inertial_geom = base.add_geom()
        inertial_geom.type = mujoco.mjtGeom.mjGEOM_SPHERE
        inertial_geom.size = (0.01, 0, 0)
        inertial_geom.mass = 0.5
        inertial_geom.contype = 0
        inertial_geom.conaffinity = 0
        inertial_geom.group = 4
        self.hand.build(spec, base, -np.array(sih.PALM_KEYPOINT), (1.0, 0.0, 0.0, 0.0))
        weld = spec.add_equality()
        weld.name = "hand_weld"
        weld.type = mujoco.mjtEq.mjEQ_WELD
        weld.objtype = mujoco.mjtObj.mjOBJ_BODY
        weld.name1 = "hand_base"
        weld.name2 = "hand_target"
        weld.solref = self.cfg.weld_solref

    def _index_base(self, model: mujoco.MjModel) -> None:
        self.base_qpos = int(model.joint("hand_free").qposadr[0])

    def _home_base(
        self, qpos: torch.Tensor, ctrl: torch.Tensor, keypoint: torch.Tensor, rot: torch.Tensor
    ) -> None:
        qpos[self.base_qpos : self.base_qpos + 3] = keypoint
        qpos[self.base_qpos + 3 : self.base_qpos + 7] = matrix_to_quat(rot)

    def _base_commands(
        self, ctrl: torch.Tensor, qpos: torch.Tensor, target_pos: torch.Tensor,
        target_rot: torch.Tensor,
    ) -> torch.Tensor:
        return ctrl  # the mocap target (``mocap``) moves the hand

    def mocap(
        self, pos: torch.Tensor, rot: torch.Tensor
    ) -> tuple[torch.Tensor | None, torch.Tensor | None]:
        """The mocap body at the commanded palm pose: (n, 1, 3) and (n, 1, 4)."""
        n = pos.shape[0]
        return pos.reshape(n, 1, 3), matrix_to_quat(rot).reshape(n, 1, 4)
