"""Batched rotation helpers in torch. Quaternions are (w, x, y, z); matrices rotate column
vectors (``world = R @ local``); every function takes any leading batch shape ``(...)``."""

from __future__ import annotations

import torch

# One quaternion convention across the project: the SDF lookup's (normalises, w first).
from geomprep.sdf_lookup import quat_to_matrix

__all__ = [
    "axis_angle_to_matrix",
    "matrix_to_axis_angle",
    "matrix_to_euler_xyz",
    "matrix_to_quat",
    "quat_to_matrix",
    "rotation_6d",
]


def matrix_to_quat(rot: torch.Tensor) -> torch.Tensor:
    """(..., 3, 3) rotation matrices -> (..., 4) unit quaternions with w >= 0."""
    m = rot
    trace = m[..., 0, 0] + m[..., 1, 1] + m[..., 2, 2]
    # Four candidate formulas; each is accurate where its pivot is largest (Shepperd's method).
    candidates = torch.stack(
        [
            torch.stack([1 + trace, m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0],
                         m[..., 1, 0] - m[..., 0, 1]], -1),
            torch.stack([m[..., 2, 1] - m[..., 1, 2], 1 + 2 * m[..., 0, 0] - trace,
                         m[..., 0, 1] + m[..., 1, 0], m[..., 0, 2] + m[..., 2, 0]], -1),
            torch.stack([m[..., 0, 2] - m[..., 2, 0], m[..., 0, 1] + m[..., 1, 0],
                         1 + 2 * m[..., 1, 1] - trace, m[..., 1, 2] + m[..., 2, 1]], -1),
            torch.stack([m[..., 1, 0] - m[..., 0, 1], m[..., 0, 2] + m[..., 2, 0],
                         m[..., 1, 2] + m[..., 2, 1], 1 + 2 * m[..., 2, 2] - trace], -1),
        ],
        dim=-2,
    )
    pivots = torch.stack([trace, m[..., 0, 0], m[..., 1, 1], m[..., 2, 2]], -1)
    best = pivots.argmax(-1)
    quat = torch.gather(candidates, -2, best[..., None, None].expand(*best.shape, 1, 4))[..., 0, :]
    quat = quat / quat.norm(dim=-1, keepdim=True)
    return torch.where(quat[..., :1] < 0, -quat, quat)


def axis_angle_to_matrix(vec: torch.Tensor) -> torch.Tensor:
    """(..., 3) rotation vectors (axis * angle, rad) -> (..., 3, 3) (Rodrigues' formula)."""
    angle = vec.norm(dim=-1, keepdim=True)[..., None]
    small = angle < 1e-8
    safe = torch.where(small, torch.ones_like(angle), angle)
    x, y, z = vec.unbind(-1)
    zero = torch.zeros_like(x)
    skew = torch.stack([zero, -z, y, z, zero, -x, -y, x, zero], -1).reshape(*vec.shape[:-1], 3, 3)
    eye = torch.eye(3, dtype=vec.dtype, device=vec.device).expand_as(skew)
    sin_term = torch.where(small, torch.ones_like(angle), torch.sin(safe) / safe)
    cos_term = torch.where(small, 0.5 * torch.ones_like(angle), (1 - torch.cos(safe)) / safe**2)
    return eye + sin_term * skew + cos_term * (skew @ skew)


def matrix_to_axis_angle(rot: torch.Tensor) -> torch.Tensor:
    """(..., 3, 3) -> (..., 3) rotation vectors with angle in [0, pi]."""
    quat = matrix_to_quat(rot)
    vec = quat[..., 1:]
    sin_half = vec.norm(dim=-1, keepdim=True)
    angle = 2 * torch.atan2(sin_half, quat[..., :1])
    # Near the identity angle / sin(angle / 2) -> 2.
    ratio = angle / sin_half.clamp_min(1e-12)
    scale = torch.where(sin_half < 1e-8, torch.full_like(angle, 2.0), ratio)
    return vec * scale


def matrix_to_euler_xyz(rot: torch.Tensor) -> torch.Tensor:
    """(..., 3, 3) -> (..., 3) extrinsic xyz Euler angles (R = Rz · Ry · Rx), as scipy's
    ``Rotation.as_euler("xyz")``, which geomprep uses for superquadric rotations."""
    beta = torch.asin((-rot[..., 2, 0]).clamp(-1.0, 1.0))
    alpha = torch.atan2(rot[..., 2, 1], rot[..., 2, 2])
    gamma = torch.atan2(rot[..., 1, 0], rot[..., 0, 0])
    return torch.stack([alpha, beta, gamma], -1)


def rotation_6d(rot: torch.Tensor) -> torch.Tensor:
    """(..., 3, 3) -> (..., 6): the first two columns, a continuous rotation encoding for
    networks (quaternions jump between q and -q)."""
    return rot[..., :, :2].transpose(-1, -2).reshape(*rot.shape[:-2], 6)
