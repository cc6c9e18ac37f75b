"""The robot interface: what a task needs from the robot it drives.

A robot builds its MJCF part into the scene's ``MjSpec``, names its joints, actuators and sites,
gives its home state, and turns an action into actuator targets (and mocap targets, for a
robot moved by one). Every robot here carries the SIH hand (``trainer.robots.sih``) and is
commanded the same way: the action is 6 deltas of the commanded palm pose (3 translation,
3 rotation; ``RobotConfig.pos_step`` / ``rot_step`` at |a| = 1), then the hand's DoF; what
differs is what moves the palm there (``_base_commands``: an arm's joint targets, or a mocap
body that the hand is welded to).

Adding a robot: subclass ``Robot``, implement ``build``, ``_index_base``, ``_home_base`` and
``_base_commands`` (and ``mocap`` if it has mocap bodies), register it in
``trainer.robots.ROBOTS`` and list its name in ``trainer.config.ROBOTS``.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import ClassVar, NamedTuple

import mujoco
import numpy as np
import torch

from geomgrasp.rotations import axis_angle_to_matrix, matrix_to_quat, quat_to_matrix
from trainer.config import RobotConfig
from trainer.robots.sih import FINGERTIPS, SIHHand

PALM_DOWN = np.array([[-1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, -1.0, 0.0]])
"""Palm-down pose of the hand at reset, as in the authors' home configuration: palmar side
(+y_palm) faces the table, fingers (+z_palm) point away from the robot (-y), thumb toward -x.
Columns are the palm axes in the world frame."""


def matrix_to_quat_np(rot: np.ndarray) -> np.ndarray:
    """(3, 3) -> (4,) (w, x, y, z), through the project's rotation module, in float64."""
    return matrix_to_quat(torch.as_tensor(rot, dtype=torch.float64)).numpy()


def quat_to_matrix_np(quat: np.ndarray) -> np.ndarray:
    """(4,) (w, x, y, z) -> (3, 3), through the project's rotation module, in float64."""
    return quat_to_matrix(torch.as_tensor(quat, dtype=torch.float64)).numpy()


class Home(NamedTuple):
    """The robot's state at reset."""

    qpos: torch.Tensor
    """(nq,) the whole model's qpos0 with the robot's joints at home (float32)."""
    ctrl: torch.Tensor
    """(nu,) actuator targets holding the home pose."""
    keypoint: torch.Tensor
    """(3,) the commanded palm keypoint (the ``palm`` site), m, world frame."""
    rot: torch.Tensor
    """(3, 3) the commanded palm orientation (columns: palm axes in the world)."""


class Robot(ABC):
    """A robot carrying the SIH hand, commanded by palm-pose deltas and hand DoF targets.

    ``index(model, device)`` must run before ``home`` and ``commands``.
    """

    kind: ClassVar[str] = ""
    sites: ClassVar[tuple[str, ...]] = ("palm", *FINGERTIPS)
    """The tracked sites: the palm keypoint, then the fingertip pads (observation order)."""

    def __init__(self, cfg: RobotConfig) -> None:
        self.cfg = cfg
        self.hand = SIHHand(cfg)

    @property
    def action_dim(self) -> int:
        """6 palm-pose deltas, then the hand's DoF."""
        return 6 + self.hand.action_dim

    def home_pose(self, height: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The reset pose of the hand: the palm keypoint ``height`` (default
        ``home_hand_height``) above the table centre, palm down. Returns (keypoint position
        (3,) m, palm rotation (3, 3)), world."""
        height = self.cfg.home_hand_height if height is None else height
        return np.array([0.0, 0.0, height]), PALM_DOWN

    # --- the model -------------------------------------------------------------------------
    @abstractmethod
    def build(self, spec: mujoco.MjSpec) -> None:
        """Add the robot (bodies, joints, actuators, sites, equalities) to ``spec``; tag its
        collision geoms with their material group (``geomgrasp.materials.tag``)."""

    def index(self, model: mujoco.MjModel, device: torch.device) -> None:
        """Find the robot's qpos entries and actuators in a compiled model (the same in every
        env's model)."""
        self.device = device
        self.hand.index(model, device)
        self._index_base(model)

    @abstractmethod
    def _index_base(self, model: mujoco.MjModel) -> None:
        """``index`` for what carries the hand."""

    @property
    def hand_qpos(self) -> torch.Tensor:
        """(11,) qpos addresses of the hand's joints (``sih.JOINTS``)."""
        return self.hand.qpos

    def home(self, model: mujoco.MjModel, height: float | None = None) -> Home:
        """Robot qpos and ctrl at reset: hand open, thumb opposed, palm down ``height`` (default
        ``home_hand_height``) above the table."""
        qpos = torch.as_tensor(model.qpos0, dtype=torch.float32, device=self.device).clone()
        ctrl = torch.zeros(model.nu, device=self.device)
        self.hand.home(qpos, ctrl)
        keypoint, palm_rot = self.home_pose(height)
        keypoint = torch.as_tensor(keypoint, dtype=torch.float32, device=self.device)
        palm_rot = torch.as_tensor(palm_rot, dtype=torch.float32, device=self.device)
        self._home_base(qpos, ctrl, keypoint, palm_rot)
        return Home(qpos, ctrl, keypoint, palm_rot)

    @abstractmethod
    def _home_base(
        self, qpos: torch.Tensor, ctrl: torch.Tensor, keypoint: torch.Tensor, rot: torch.Tensor
    ) -> None:
        """Write into qpos (nq,) and ctrl (nu,) what puts the palm at keypoint (3,), rot (3, 3)."""

    # --- actions -----------------------------------------------------------------------------
    def commands(
        self,
        action: torch.Tensor,
        palm_pos: torch.Tensor,
        target_pos: torch.Tensor,
        target_rot: torch.Tensor,
        ctrl: torch.Tensor,
        qpos: torch.Tensor,
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """The new commanded palm pose (E, 3) m, (E, 3, 3) and actuator targets (E, nu) from
        the action (E, action_dim) in [-1, 1]: a pure tensor function (``torch.compile``
        fuses it when ``cfg.compile``).

        palm_pos: measured at the last observation (the current state); target_pos,
        target_rot: the last command; ctrl (E, nu) the last targets; qpos (E, nq)."""
        robot = self.cfg
        # The command accumulates, so small tracking errors do not drift; a leash keeps it near
        # the measured hand when the hand is blocked (by the table or the object).
        lag = (target_pos - palm_pos).clamp(-robot.leash, robot.leash)
        target_pos = palm_pos + lag + action[:, :3] * robot.pos_step
        target_rot = axis_angle_to_matrix(action[:, 3:6] * robot.rot_step) @ target_rot
        ctrl = self.hand.command(action[:, 6:], ctrl)
        ctrl = self._base_commands(ctrl, qpos, target_pos, target_rot)
        return target_pos, target_rot, ctrl

    @abstractmethod
    def _base_commands(
        self, ctrl: torch.Tensor, qpos: torch.Tensor, target_pos: torch.Tensor,
        target_rot: torch.Tensor,
    ) -> torch.Tensor:
        """``ctrl`` (E, nu, a fresh copy: may be written in place) with the targets of what
        carries the hand toward the commanded palm pose (E, 3), (E, 3, 3)."""

    def mocap(
        self, pos: torch.Tensor, rot: torch.Tensor
    ) -> tuple[torch.Tensor | None, torch.Tensor | None]:
        """The mocap targets (n, nmocap, 3), (n, nmocap, 4) for commanded palm poses (n, 3),
        (n, 3, 3), or Nones for a robot without mocap bodies."""
        return None, None

    def hold_action(self, ctrl: torch.Tensor) -> torch.Tensor:
        """(E, action_dim) the action that keeps the commands: no palm motion and the hand's
        targets in ``ctrl`` (E, nu)."""
        action = torch.zeros(ctrl.shape[0], self.action_dim, device=ctrl.device)
        action[:, 6:] = self.hand.action(ctrl)
        return action
