"""Rotations in torch, the one rotation module of the project (geomprep and trainer).

Conventions:
- Quaternions are (w, x, y, z), scalar first (MuJoCo's order; scipy's ``as_quat()`` is
  (x, y, z, w)). Functions that take quaternions normalise them; functions that return them
  return unit quaternions.
- A rotation matrix R rotates column vectors: ``world = R @ local``; its columns are the local
  axes in the world frame (MuJoCo's ``xmat``, scipy's ``as_matrix()``).
- Axis-angle is the rotation vector ``axis * angle``, radians (scipy's ``as_rotvec()``).
- Euler angles are extrinsic xyz, radians: ``R = Rz(c) @ Ry(b) @ Rx(a)`` for angles (a, b, c),
  i.e. scipy's ``Rotation.from_euler("xyz", (a, b, c))``, the convention of geomprep's
  superquadric parameters (``geomprep.superquadric.geometry``).
- Every function takes any leading batch shape ``(...)``, including none; float32 in gives
  float32 out and float64 in gives float64 out; outputs stay on the input's device.

numpy callers convert at the boundary, ``f(torch.as_tensor(x, dtype=torch.float64)).numpy()``;
there are deliberately no numpy copies of these functions.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

__all__ = [
    "axis_angle_to_matrix",
    "axis_angle_to_quat",
    "euler_xyz_to_matrix",
    "matrix_to_axis_angle",
    "matrix_to_euler_xyz",
    "matrix_to_quat",
    "quat_multiply",
    "quat_to_matrix",
    "random_quats",
    "rotation_6d",
]

# Below this angle (rad) the small-angle limits of sin(t) / t and friends are used.
_SMALL_ANGLE = 1e-8


def quat_to_matrix(quat: torch.Tensor) -> torch.Tensor:
    """Rotation matrices from quaternions.

    quat: (..., 4) quaternions (w, x, y, z), any nonzero norm (normalised here, so slightly
    denormalised ones from an integrator are fine).
    Returns (..., 3, 3) rotation matrices R with ``world = R @ local``.
    """
    q = quat / quat.norm(dim=-1, keepdim=True)
    w, x, y, z = q.unbind(-1)
    return torch.stack(
        [
            1 - 2 * (y * y + z * z),
            2 * (x * y - w * z),
            2 * (x * z + w * y),
            2 * (x * y + w * z),
            1 - 2 * (x * x + z * z),
            2 * (y * z - w * x),
            2 * (x * z - w * y),
            2 * (y * z + w * x),
            1 - 2 * (x * x + y * y),
        ],
        dim=-1,
    ).reshape(*q.shape[:-1], 3, 3)


def matrix_to_quat(rot: torch.Tensor) -> torch.Tensor:
    """Quaternions of rotation matrices (Shepperd's method).

    rot: (..., 3, 3) rotation matrices.
    Returns (..., 4) unit quaternions (w, x, y, z) with w >= 0 (of the two quaternions of a
    rotation, the one with the non-negative scalar part).
    """
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
    """Rotation matrices of rotation vectors (Rodrigues' formula).

    vec: (..., 3) rotation vectors, ``axis * angle`` (unit axis, angle in rad, any sign and
    size); the zero vector is the identity.
    Returns (..., 3, 3) rotation matrices.
    """
    angle = vec.norm(dim=-1, keepdim=True)[..., None]
    small = angle < _SMALL_ANGLE
    safe = torch.where(small, torch.ones_like(angle), angle)
    x, y, z = vec.unbind(-1)
    zero = torch.zeros_like(x)
    skew = torch.stack([zero, -z, y, z, zero, -x, -y, x, zero], -1).reshape(*vec.shape[:-1], 3, 3)
    eye = torch.eye(3, dtype=vec.dtype, device=vec.device).expand_as(skew)
    sin_term = torch.where(small, torch.ones_like(angle), torch.sin(safe) / safe)
    # (1 - cos t) / t^2 written as 2 sin^2(t / 2) / t^2, which does not cancel for small t.
    half_sinc = torch.sin(0.5 * safe) / (0.5 * safe)
    cos_term = torch.where(small, 0.5 * torch.ones_like(angle), 0.5 * half_sinc**2)
    return eye + sin_term * skew + cos_term * (skew @ skew)


def matrix_to_axis_angle(rot: torch.Tensor) -> torch.Tensor:
    """Rotation vectors of rotation matrices.

    rot: (..., 3, 3) rotation matrices.
    Returns (..., 3) rotation vectors ``axis * angle`` with the angle in [0, pi] rad (at exactly
    pi, either of the two opposite vectors).
    """
    quat = matrix_to_quat(rot)
    vec = quat[..., 1:]
    sin_half = vec.norm(dim=-1, keepdim=True)
    angle = 2 * torch.atan2(sin_half, quat[..., :1])
    # Near the identity angle / sin(angle / 2) -> 2.
    ratio = angle / sin_half.clamp_min(1e-12)
    scale = torch.where(sin_half < _SMALL_ANGLE, torch.full_like(angle, 2.0), ratio)
    return vec * scale


def axis_angle_to_quat(vec: torch.Tensor) -> torch.Tensor:
    """Quaternions of rotation vectors (the exponential map).

    vec: (..., 3) rotation vectors ``axis * angle`` (rad).
    Returns (..., 4) unit quaternions (w, x, y, z) = (cos(t / 2), sin(t / 2) * axis), t the
    angle: not sign-canonicalised, so w < 0 for angles beyond pi.
    """
    angle = vec.norm(dim=-1, keepdim=True)
    small = angle < _SMALL_ANGLE
    safe = torch.where(small, torch.ones_like(angle), angle)
    # sin(t / 2) / t, -> 1 / 2 as t -> 0.
    scale = torch.where(small, torch.full_like(angle, 0.5), torch.sin(0.5 * safe) / safe)
    return torch.cat([torch.cos(0.5 * angle), vec * scale], dim=-1)


def euler_xyz_to_matrix(angles: torch.Tensor) -> torch.Tensor:
    """Rotation matrices of extrinsic xyz Euler angles.

    angles: (..., 3) angles (a, b, c) in rad about the fixed x, y and z axes, applied in that
    order (scipy's ``Rotation.from_euler("xyz", ...)``).
    Returns (..., 3, 3) rotation matrices ``Rz(c) @ Ry(b) @ Rx(a)``.
    """
    a, b, c = angles.unbind(-1)
    ca, sa, cb, sb, cc, sc = a.cos(), a.sin(), b.cos(), b.sin(), c.cos(), c.sin()
    return torch.stack(
        [
            cc * cb, cc * sb * sa - sc * ca, cc * sb * ca + sc * sa,
            sc * cb, sc * sb * sa + cc * ca, sc * sb * ca - cc * sa,
            -sb, cb * sa, cb * ca,
        ],
        dim=-1,
    ).reshape(*angles.shape[:-1], 3, 3)


def matrix_to_euler_xyz(rot: torch.Tensor) -> torch.Tensor:
    """Extrinsic xyz Euler angles of rotation matrices, the inverse of ``euler_xyz_to_matrix``
    (scipy's ``Rotation.as_euler("xyz")``).

    rot: (..., 3, 3) rotation matrices.
    Returns (..., 3) angles (a, b, c) in rad, a and c in [-pi, pi], b in [-pi/2, pi/2], with
    ``rot = Rz(c) @ Ry(b) @ Rx(a)``. At gimbal lock (b = +-pi/2) only c -+ a is determined; a
    comes from rounding noise there and c is computed from a so that the angles still give
    back the matrix.
    """
    alpha = torch.atan2(rot[..., 2, 1], rot[..., 2, 2])
    # atan2 rather than asin(-r20): well conditioned near b = +-pi/2 as well.
    beta = torch.atan2(-rot[..., 2, 0], torch.hypot(rot[..., 0, 0], rot[..., 1, 0]))
    # gamma from the matrix with the x rotation undone, R @ Rx(a)^T = Rz(c) @ Ry(b), whose middle
    # column is (-sin c, cos c, 0): exact for the alpha found even where alpha is arbitrary.
    ca, sa = alpha.cos(), alpha.sin()
    gamma = torch.atan2(
        sa * rot[..., 0, 2] - ca * rot[..., 0, 1], ca * rot[..., 1, 1] - sa * rot[..., 1, 2]
    )
    return torch.stack([alpha, beta, gamma], -1)


def rotation_6d(rot: torch.Tensor) -> torch.Tensor:
    """The continuous 6-d rotation encoding of Zhou et al. 2019, for networks (quaternions jump
    between q and -q).

    rot: (..., 3, 3) rotation matrices.
    Returns (..., 6): the first column of ``rot`` followed by its second column.
    """
    return rot[..., :, :2].transpose(-1, -2).reshape(*rot.shape[:-2], 6)


def quat_multiply(q1: torch.Tensor, q2: torch.Tensor) -> torch.Tensor:
    """Hamilton product ``q1 * q2``: the rotation q2 followed by q1, so that
    ``quat_to_matrix(quat_multiply(q1, q2)) == quat_to_matrix(q1) @ quat_to_matrix(q2)``.

    q1, q2: (..., 4) quaternions (w, x, y, z), batch shapes broadcast against each other.
    Returns (..., 4), not normalised or sign-canonicalised (unit in, unit out up to rounding).
    """
    w1, x1, y1, z1 = q1.unbind(-1)
    w2, x2, y2, z2 = q2.unbind(-1)
    return torch.stack(
        [
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
        ],
        dim=-1,
    )


def random_quats(
    n: int | Sequence[int],
    generator: torch.Generator | None = None,
    dtype: torch.dtype = torch.float32,
    device: str | torch.device | None = None,
) -> torch.Tensor:
    """Uniformly distributed rotations (Haar measure) as unit quaternions.

    n: how many, or a batch shape. generator: a ``torch.Generator`` for reproducible draws
    (the same seed gives the same quaternions); it must live on ``device``, which defaults to
    the generator's device (else the CPU).
    Returns (n, 4) (or (*n, 4)) unit quaternions (w, x, y, z), normalised standard normal
    4-vectors, so uniform on the 3-sphere: both signs of w occur.
    """
    shape = (n,) if isinstance(n, int) else tuple(n)
    if device is None and generator is not None:
        device = generator.device
    quat = torch.randn(*shape, 4, generator=generator, dtype=dtype, device=device)
    return quat / quat.norm(dim=-1, keepdim=True)
