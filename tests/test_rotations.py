"""Tests for geomgrasp.rotations: every function against scipy's Rotation on random rotations,
in float64 and float32 and over the batch shapes (), (5,) and (2, 3); round trips through the
hard cases (angle 0 and near pi, Euler angles at and next to gimbal lock); the uniformity and
determinism of random_quats."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy import stats
from scipy.spatial.transform import Rotation

from geomgrasp.rotations import (
    axis_angle_to_matrix,
    axis_angle_to_quat,
    euler_xyz_to_matrix,
    matrix_to_axis_angle,
    matrix_to_euler_xyz,
    matrix_to_quat,
    quat_multiply,
    quat_to_matrix,
    random_quats,
    rotation_6d,
)

SHAPES = [(), (5,), (2, 3)]
DTYPES = [torch.float64, torch.float32]
TOL = {torch.float64: 1e-10, torch.float32: 1e-5}


def _random(shape: tuple[int, ...], seed: int) -> Rotation:
    """A stack of math.prod(shape) (at least 1) uniformly random scipy rotations."""
    return Rotation.random(max(math.prod(shape), 1), random_state=seed)


def _tensor(values: np.ndarray, shape: tuple[int, ...], dtype: torch.dtype) -> torch.Tensor:
    """(N, *trailing) float64 array -> tensor of shape (*shape, *trailing) in dtype."""
    return torch.as_tensor(values).reshape(*shape, *values.shape[1:]).to(dtype)


def _wxyz(xyzw: np.ndarray) -> np.ndarray:
    return xyzw[..., [3, 0, 1, 2]]


def _check(got: torch.Tensor, want: np.ndarray, shape: tuple[int, ...], dtype: torch.dtype) -> None:
    """got has the batch shape and dtype asked for and matches scipy's (N, ...) values."""
    assert got.dtype == dtype
    assert got.shape == (*shape, *want.shape[1:])
    np.testing.assert_allclose(
        got.double().reshape(want.shape).numpy(), want, atol=TOL[dtype], rtol=0
    )


# Against scipy ----------------------------------------------------------------------------


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("shape", SHAPES)
def test_quat_to_matrix(shape: tuple[int, ...], dtype: torch.dtype) -> None:
    rot = _random(shape, 0)
    quat = _tensor(_wxyz(rot.as_quat()), shape, dtype)
    _check(quat_to_matrix(quat), rot.as_matrix(), shape, dtype)
    # Quaternions are normalised first, and q and -q are the same rotation.
    _check(quat_to_matrix(-2.5 * quat), rot.as_matrix(), shape, dtype)


def test_quat_convention() -> None:
    # 90 degrees about z, (w, x, y, z): the local x axis points along world y (world = R local).
    half = math.sqrt(0.5)
    rot = quat_to_matrix(torch.tensor([half, 0.0, 0.0, half], dtype=torch.float64))
    np.testing.assert_allclose(rot.numpy() @ [1, 0, 0], [0, 1, 0], atol=1e-15)


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("shape", SHAPES)
def test_matrix_to_quat(shape: tuple[int, ...], dtype: torch.dtype) -> None:
    rot = _random(shape, 1)
    quat = matrix_to_quat(_tensor(rot.as_matrix(), shape, dtype))
    _check(quat, _wxyz(rot.as_quat(canonical=True)), shape, dtype)
    assert (quat[..., 0] >= 0).all()


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("shape", SHAPES)
def test_axis_angle_to_matrix(shape: tuple[int, ...], dtype: torch.dtype) -> None:
    # Angles up to 3 pi: beyond pi the same rotations come back with the axis reversed.
    rng = np.random.default_rng(2)
    n = max(math.prod(shape), 1)
    axis = rng.normal(size=(n, 3))
    vec = axis / np.linalg.norm(axis, axis=1, keepdims=True) * rng.uniform(0, 3 * np.pi, (n, 1))
    got = axis_angle_to_matrix(_tensor(vec, shape, dtype))
    _check(got, Rotation.from_rotvec(vec).as_matrix(), shape, dtype)


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("shape", SHAPES)
def test_matrix_to_axis_angle(shape: tuple[int, ...], dtype: torch.dtype) -> None:
    rot = _random(shape, 3)
    vec = matrix_to_axis_angle(_tensor(rot.as_matrix(), shape, dtype))
    _check(vec, rot.as_rotvec(), shape, dtype)
    assert (vec.norm(dim=-1) <= math.pi + TOL[dtype]).all()


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("shape", SHAPES)
def test_axis_angle_to_quat(shape: tuple[int, ...], dtype: torch.dtype) -> None:
    # Not sign-canonicalised: (cos(t/2), sin(t/2) axis), so w < 0 beyond pi, as scipy's.
    rng = np.random.default_rng(4)
    n = max(math.prod(shape), 1)
    axis = rng.normal(size=(n, 3))
    vec = axis / np.linalg.norm(axis, axis=1, keepdims=True) * rng.uniform(0, 2 * np.pi, (n, 1))
    got = axis_angle_to_quat(_tensor(vec, shape, dtype))
    _check(got, _wxyz(Rotation.from_rotvec(vec).as_quat(canonical=False)), shape, dtype)


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("shape", SHAPES)
def test_euler_xyz_to_matrix(shape: tuple[int, ...], dtype: torch.dtype) -> None:
    n = max(math.prod(shape), 1)
    angles = np.random.default_rng(5).uniform(-2 * np.pi, 2 * np.pi, (n, 3))
    got = euler_xyz_to_matrix(_tensor(angles, shape, dtype))
    _check(got, Rotation.from_euler("xyz", angles).as_matrix(), shape, dtype)


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("shape", SHAPES)
def test_matrix_to_euler_xyz(shape: tuple[int, ...], dtype: torch.dtype) -> None:
    rot = _random(shape, 6)
    angles = matrix_to_euler_xyz(_tensor(rot.as_matrix(), shape, dtype))
    _check(angles, rot.as_euler("xyz"), shape, dtype)


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("shape", SHAPES)
def test_rotation_6d(shape: tuple[int, ...], dtype: torch.dtype) -> None:
    rot = _random(shape, 7)
    mat = rot.as_matrix()
    got = rotation_6d(_tensor(mat, shape, dtype))
    _check(got, np.concatenate([mat[:, :, 0], mat[:, :, 1]], axis=1), shape, dtype)


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("shape", SHAPES)
def test_quat_multiply(shape: tuple[int, ...], dtype: torch.dtype) -> None:
    a, b = _random(shape, 8), _random(shape, 9)
    qa = _tensor(_wxyz(a.as_quat()), shape, dtype)
    qb = _tensor(_wxyz(b.as_quat()), shape, dtype)
    # scipy's a * b applies b first, then a: the matrix product A @ B.
    _check(quat_multiply(qa, qb), _wxyz((a * b).as_quat(canonical=False)), shape, dtype)
    _check(quat_to_matrix(quat_multiply(qa, qb)), (a * b).as_matrix(), shape, dtype)


def test_quat_multiply_broadcasts() -> None:
    qa = torch.as_tensor(_wxyz(Rotation.random(5, random_state=10).as_quat()))
    qb = torch.as_tensor(_wxyz(Rotation.random(random_state=11).as_quat()))
    got = quat_multiply(qa, qb)
    assert got.shape == (5, 4)
    np.testing.assert_allclose(got.numpy(), quat_multiply(qa, qb.expand(5, 4)).numpy())


# Round trips ------------------------------------------------------------------------------


@pytest.mark.parametrize("dtype", DTYPES)
def test_matrix_quat_round_trip(dtype: torch.dtype) -> None:
    # Random rotations plus each of Shepperd's four branches (identity, half turns about x, y, z).
    mats = np.concatenate(
        [Rotation.random(200, random_state=12).as_matrix(), np.eye(3)[None]]
        + [Rotation.from_rotvec(np.pi * np.eye(3)[i]).as_matrix()[None] for i in range(3)]
    )
    rot = torch.as_tensor(mats).to(dtype)
    quat = matrix_to_quat(rot)
    assert quat.dtype == dtype
    np.testing.assert_allclose(quat.norm(dim=-1).double().numpy(), 1.0, atol=TOL[dtype])
    np.testing.assert_allclose(
        quat_to_matrix(quat).double().numpy(), mats, atol=TOL[dtype], rtol=0
    )
    # quat -> matrix -> quat gives the quaternion back up to its sign.
    q = torch.as_tensor(_wxyz(Rotation.random(200, random_state=13).as_quat())).to(dtype)
    back = matrix_to_quat(quat_to_matrix(q))
    sign = torch.where(q[:, :1] < 0, -1.0, 1.0).to(dtype)
    np.testing.assert_allclose(
        back.double().numpy(), (sign * q).double().numpy(), atol=TOL[dtype], rtol=0
    )


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize(
    "angle", [0.0, 1e-12, 1e-9, 1e-7, 1e-4, 0.5, 2.0, np.pi - 1e-3, np.pi - 1e-6, np.pi]
)
def test_axis_angle_round_trip(angle: float, dtype: torch.dtype) -> None:
    axes = Rotation.random(20, random_state=14).as_rotvec()
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    vec = axes * angle
    rot = axis_angle_to_matrix(torch.as_tensor(vec).to(dtype))
    want = Rotation.from_rotvec(vec).as_matrix()
    np.testing.assert_allclose(rot.double().numpy(), want, atol=TOL[dtype], rtol=0)
    back = matrix_to_axis_angle(rot)
    assert back.dtype == dtype
    # The matrix always comes back; the vector too except where pi makes its sign ambiguous.
    np.testing.assert_allclose(
        axis_angle_to_matrix(back).double().numpy(), want, atol=TOL[dtype], rtol=0
    )
    if dtype == torch.float64 and angle < np.pi:
        np.testing.assert_allclose(back.numpy(), vec, atol=TOL[dtype], rtol=0)
    if dtype == torch.float32 and angle < np.pi - 1e-4:
        np.testing.assert_allclose(back.double().numpy(), vec, atol=TOL[dtype], rtol=0)
    quat = axis_angle_to_quat(torch.as_tensor(vec).to(dtype))
    np.testing.assert_allclose(quat_to_matrix(quat).double().numpy(), want, atol=TOL[dtype])


@pytest.mark.parametrize("dtype", DTYPES)
def test_euler_round_trip(dtype: torch.dtype) -> None:
    rot = Rotation.random(200, random_state=15).as_matrix()
    angles = matrix_to_euler_xyz(torch.as_tensor(rot).to(dtype))
    back = euler_xyz_to_matrix(angles)
    np.testing.assert_allclose(back.double().numpy(), rot, atol=TOL[dtype], rtol=0)
    angles = torch.as_tensor(Rotation.from_matrix(rot).as_euler("xyz")).to(dtype)
    np.testing.assert_allclose(
        matrix_to_euler_xyz(euler_xyz_to_matrix(angles)).double().numpy(),
        angles.double().numpy(),
        atol=TOL[dtype],
        rtol=0,
    )


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("offset", [0.0, 1e-12, 1e-9, 1e-6, 1e-4, 1e-2])
@pytest.mark.parametrize("lock", [np.pi / 2, -np.pi / 2])
def test_euler_near_gimbal_lock(lock: float, offset: float, dtype: torch.dtype) -> None:
    # Next to b = +-pi/2 only c -+ a is well determined; the angles found must still give the
    # matrix back, and b itself is well conditioned.
    rng = np.random.default_rng(16)
    n = 50
    b = lock - np.sign(lock) * offset
    angles = np.stack([rng.uniform(-3, 3, n), np.full(n, b), rng.uniform(-3, 3, n)], axis=1)
    rot = Rotation.from_euler("xyz", angles).as_matrix()
    got = matrix_to_euler_xyz(torch.as_tensor(rot).to(dtype))
    np.testing.assert_allclose(
        euler_xyz_to_matrix(got).double().numpy(), rot, atol=TOL[dtype], rtol=0
    )
    np.testing.assert_allclose(got[:, 1].double().numpy(), b, atol=TOL[dtype], rtol=0)
    if offset >= {torch.float64: 1e-4, torch.float32: 1e-2}[dtype]:
        # Far enough from the lock for every angle to be determined to the tolerance.
        np.testing.assert_allclose(got.double().numpy(), angles, atol=TOL[dtype] * 10, rtol=0)


# random_quats -----------------------------------------------------------------------------


def _angle_ks_pvalue(quat: torch.Tensor) -> float:
    """Kolmogorov-Smirnov p-value of the rotation angles of ``quat`` (N, 4) against uniform
    rotations, whose angle t in [0, pi] has the distribution function (t - sin t) / pi."""
    w = quat[:, 0].abs().clamp(max=1.0).double().numpy()
    return stats.kstest(2 * np.arccos(w), lambda t: (t - np.sin(t)) / np.pi).pvalue


def test_random_quats_uniform() -> None:
    n = 20_000
    gen = torch.Generator().manual_seed(0)
    quat = random_quats(n, generator=gen, dtype=torch.float64)
    assert quat.shape == (n, 4) and quat.dtype == torch.float64
    np.testing.assert_allclose(quat.norm(dim=-1).numpy(), 1.0, atol=1e-12)
    # Uniform on the 3-sphere: the products with any fixed quaternion are uniform too, with mean
    # 0 (each component has standard deviation 1 / sqrt(4 n) = 0.0035 in the mean).
    fixed = torch.as_tensor(_wxyz(Rotation.random(3, random_state=17).as_quat()))
    for q in fixed:
        assert quat_multiply(q, quat).mean(0).abs().max() < 0.02
    # Second moment E[q q^T] = I / 4 (equivalently the mean rotation matrix is 0).
    assert (quat.T @ quat / n - torch.eye(4, dtype=torch.float64) / 4).abs().max() < 0.02
    assert quat_to_matrix(quat).mean(0).abs().max() < 0.03
    # The rotation angles follow the Haar distribution ...
    assert _angle_ks_pvalue(quat) > 1e-3
    # ... a test that a plausible wrong sampler fails: normalised uniform-in-cube 4-vectors.
    cube = torch.rand(n, 4, generator=gen, dtype=torch.float64) * 2 - 1
    assert _angle_ks_pvalue(cube / cube.norm(dim=-1, keepdim=True)) < 1e-6


def test_random_quats_seeded() -> None:
    def draw(seed: int, **kwargs) -> torch.Tensor:
        return random_quats(7, generator=torch.Generator().manual_seed(seed), **kwargs)

    assert torch.equal(draw(3), draw(3))
    assert not torch.equal(draw(3), draw(4))
    assert draw(3).dtype == torch.float32
    assert draw(3, dtype=torch.float64).dtype == torch.float64
    assert random_quats((2, 3), generator=torch.Generator().manual_seed(3)).shape == (2, 3, 4)
    assert random_quats(5).shape == (5, 4)
