"""Forward kinematics, site Jacobians and the Jacobian-transpose arm controller, batched in torch.

The kinematic tree (body offsets, hinge axes) is read from the compiled ``MjModel``, so the
torch model cannot drift from the simulated one; ``tests/test_robot.py`` checks both against
MuJoCo's own ``site_xpos`` and the UR5e DH table.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import mujoco
import numpy as np
import torch

from geomgrasp.rotations import matrix_to_axis_angle, quat_to_matrix


@dataclass
class Poses:
    """World poses of the tracked bodies and sites for a batch of E states."""

    body_pos: list[torch.Tensor]
    """Per tracked body, (E, 3) metres."""
    body_rot: list[torch.Tensor]
    """Per tracked body, (E, 3, 3)."""
    site_pos: torch.Tensor
    """(E, S, 3) metres, sites in the order given to ``SiteKinematics``."""
    site_rot: torch.Tensor
    """(E, S, 3, 3)."""


class SiteKinematics:
    """World poses of a set of sites as a function of ``qpos``, for trees of hinge joints that
    hang from the world or from a free joint (the floating hand)."""

    def __init__(
        self, model: mujoco.MjModel, sites: Sequence[str], device: str | torch.device = "cpu"
    ) -> None:
        self.site_names = list(sites)
        site_ids = [model.site(name).id for name in sites]
        chain: list[int] = []
        for site_id in site_ids:
            body = int(model.site_bodyid[site_id])
            path = []
            while body != 0:
                path.append(body)
                body = int(model.body_parentid[body])
            for b in reversed(path):
                if b not in chain:
                    chain.append(b)
        chain.sort()  # MuJoCo numbers parents before children
        self.body_ids = chain
        index = {b: i for i, b in enumerate(chain)}
        self._parent = [index.get(int(model.body_parentid[b]), -1) for b in chain]
        self._joint: list[tuple[str, int, int]] = []  # (kind, qpos address, dof address)
        axes = []
        for b in chain:
            n_joints = int(model.body_jntnum[b])
            if n_joints == 0:
                self._joint.append(("fixed", -1, -1))
                axes.append(np.zeros(3))
                continue
            if n_joints > 1:
                raise ValueError(f"body {model.body(b).name} has {n_joints} joints: unsupported")
            j = int(model.body_jntadr[b])
            kind = int(model.jnt_type[j])
            if kind == mujoco.mjtJoint.mjJNT_HINGE:
                if np.abs(model.jnt_pos[j]).max() > 1e-12:
                    raise ValueError(f"joint {model.joint(j).name}: off-origin hinges unsupported")
                self._joint.append(("hinge", int(model.jnt_qposadr[j]), int(model.jnt_dofadr[j])))
            elif kind == mujoco.mjtJoint.mjJNT_FREE:
                self._joint.append(("free", int(model.jnt_qposadr[j]), int(model.jnt_dofadr[j])))
            else:
                raise ValueError(f"joint {model.joint(j).name}: only hinge and free supported")
            axes.append(model.jnt_axis[j])
        as_tensor = lambda a: torch.as_tensor(np.asarray(a), dtype=torch.float32, device=device)  # noqa: E731
        self._body_pos = as_tensor(model.body_pos[chain])
        self._body_rot = quat_to_matrix(as_tensor(model.body_quat[chain]))
        self._axis = as_tensor(np.stack(axes))
        # A hinge body's rotation is body_rot · R(q) = B + sin q · B K + (1 - cos q) · B K²
        # (Rodrigues, K the skew matrix of the unit axis): three constant matrices per hinge,
        # so all hinge rotations of a batch come from one vectorized expression.
        self._hinges = [i for i, (kind, _, _) in enumerate(self._joint) if kind == "hinge"]
        self._hinge_qpos = torch.tensor(
            [self._joint[i][1] for i in self._hinges], dtype=torch.long, device=device
        )
        skew = torch.zeros(len(self._hinges), 3, 3, device=device)
        for h, i in enumerate(self._hinges):
            x, y, z = (self._axis[i] / self._axis[i].norm()).tolist()
            skew[h] = torch.tensor([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
        base = self._body_rot[self._hinges]
        self._hinge_terms = torch.stack([base, base @ skew, base @ skew @ skew], dim=1)
        self._site_body = [index[int(model.site_bodyid[s])] for s in site_ids]
        self._site_pos = as_tensor(model.site_pos[site_ids])
        self._site_rot = quat_to_matrix(as_tensor(model.site_quat[site_ids]))
        self.joint_body = {
            model.joint(int(model.body_jntadr[b])).name: i
            for i, b in enumerate(chain)
            if model.body_jntnum[b] == 1
        }

    def forward(self, qpos: torch.Tensor) -> Poses:
        """Poses for ``qpos`` (E, nq) (float32 or float64; computed in float32)."""
        qpos = qpos.to(self._body_pos.device, torch.float32)
        positions: list[torch.Tensor] = []
        rotations: list[torch.Tensor] = []
        batch = qpos.shape[0]
        angles = qpos[:, self._hinge_qpos]
        coef = torch.stack([torch.ones_like(angles), angles.sin(), 1.0 - angles.cos()], dim=-1)
        # (E, H, 3, 3): each hinge body's rotation relative to its parent.
        local = (coef[..., None, None] * self._hinge_terms).sum(2)
        hinge_rot = dict(zip(self._hinges, local.unbind(1), strict=True))
        for i, (kind, qadr, _) in enumerate(self._joint):
            if kind == "free":
                pos = qpos[:, qadr : qadr + 3]
                rot = quat_to_matrix(qpos[:, qadr + 3 : qadr + 7])
            else:
                relative = hinge_rot[i] if kind == "hinge" else self._body_rot[i]
                parent = self._parent[i]
                if parent < 0:
                    pos = self._body_pos[i].expand(batch, 3)
                    rot = relative.expand(batch, 3, 3)
                else:
                    pos = positions[parent] + (rotations[parent] @ self._body_pos[i])
                    rot = rotations[parent] @ relative
            positions.append(pos)
            rotations.append(rot)
        site_pos = torch.stack(
            [
                positions[b] + rotations[b] @ self._site_pos[k]
                for k, b in enumerate(self._site_body)
            ],
            dim=1,
        )
        site_rot = torch.stack(
            [rotations[b] @ self._site_rot[k] for k, b in enumerate(self._site_body)], dim=1
        )
        return Poses(positions, rotations, site_pos, site_rot)

    def jacobian(self, poses: Poses, site: str, joints: Sequence[str]) -> torch.Tensor:
        """Geometric Jacobian (E, 6, J) of ``site`` (rows: linear velocity in m/rad, then
        angular velocity) with respect to the hinge ``joints``, at ``poses``."""
        k = self.site_names.index(site)
        site_pos = poses.site_pos[:, k]
        columns = []
        for name in joints:
            b = self.joint_body[name]
            axis = poses.body_rot[b] @ self._axis[b]
            linear = torch.linalg.cross(axis, site_pos - poses.body_pos[b], dim=-1)
            columns.append(torch.cat([linear, axis], dim=-1))
        return torch.stack(columns, dim=-1)


def pose_error(
    target_pos: torch.Tensor, target_rot: torch.Tensor, pos: torch.Tensor, rot: torch.Tensor
) -> torch.Tensor:
    """(E, 6): position error (m) and rotation error as a world-frame rotation vector (rad)
    taking ``rot`` to ``target_rot``."""
    return torch.cat(
        [target_pos - pos, matrix_to_axis_angle(target_rot @ rot.transpose(-1, -2))], dim=-1
    )


def jacobian_transpose_step(
    kinematics: SiteKinematics,
    qpos: torch.Tensor,
    arm_qpos_index: torch.Tensor,
    arm_joints: Sequence[str],
    site: str,
    target_pos: torch.Tensor,
    target_rot: torch.Tensor,
    iterations: int,
    rotation_scale: float = 0.2,
) -> torch.Tensor:
    """Arm joint targets (E, 6) that move ``site`` toward the target pose, by the Jacobian
    transpose method: dq = alpha · J^T e with the step alpha = <e, J J^T e> / |J J^T e|^2 that
    minimises |e - alpha J J^T e| (Buss 2004), repeated ``iterations`` times on the model.
    Rotation rows are scaled by ``rotation_scale`` (m/rad) so both errors weigh alike."""
    qpos = qpos.to(torch.float32).clone()
    weight = torch.tensor([1.0, 1.0, 1.0, *(3 * [rotation_scale])], device=qpos.device)
    k = kinematics.site_names.index(site)
    for _ in range(iterations):
        poses = kinematics.forward(qpos)
        error = pose_error(target_pos, target_rot, poses.site_pos[:, k], poses.site_rot[:, k])
        error = error * weight
        jac = kinematics.jacobian(poses, site, arm_joints) * weight[:, None]
        direction = (jac.transpose(1, 2) @ error[..., None])[..., 0]  # J^T e, (E, 6)
        moved = (jac @ direction[..., None])[..., 0]  # J J^T e, (E, 6)
        alpha = (error * moved).sum(-1, keepdim=True) / (
            (moved * moved).sum(-1, keepdim=True).clamp_min(1e-12)
        )
        qpos[:, arm_qpos_index] += alpha * direction
    return qpos[:, arm_qpos_index]
