"""trainer.camera: the tracking camera keeps every sphere in the image and moves smoothly."""

from __future__ import annotations

import math

import numpy as np

from trainer.camera import CameraView, TrackingCamera, forward_vector

FOVY, ASPECT, DT = 45.0, 4 / 3, 1 / 30


def image_coords(view: CameraView, points: np.ndarray) -> np.ndarray:
    """Pinhole projection (N, 2) of world points (N, 3), in units of the half image height
    (so the image is |x| <= aspect, |y| <= 1); the camera's up is the world's z."""
    fwd = forward_vector(view.azimuth, view.elevation)
    right = np.cross(fwd, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, fwd)
    rel = points - view.position()
    depth = rel @ fwd
    assert (depth > 0).all(), "a point is behind the camera"
    half = math.tan(math.radians(FOVY) / 2)
    return np.stack([rel @ right, rel @ up], axis=1) / depth[:, None] / half


def sphere_points(centers: np.ndarray, radii: np.ndarray, n: int = 200) -> np.ndarray:
    dirs = np.random.default_rng(0).normal(size=(n, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    return (centers[:, None, :] + radii[:, None, None] * dirs[None]).reshape(-1, 3)


def assert_in_image(view: CameraView, centers: np.ndarray, radii: np.ndarray) -> None:
    xy = image_coords(view, sphere_points(centers, radii))
    assert (np.abs(xy[:, 0]) <= ASPECT).all() and (np.abs(xy[:, 1]) <= 1.0).all()


def grasp_trajectory(frames: int = 120) -> list[tuple[np.ndarray, np.ndarray]]:
    """Hand (r 8 cm) descends onto an object (r 4 cm) at the origin, then lifts it 0.3 m; then
    the object drops back to the table at once (a sudden change, e.g. a slip)."""
    out = []
    for i in range(frames):
        s = i / (frames - 1)
        hand_z = 0.35 - 0.25 * min(2 * s, 1.0) + 0.3 * max(2 * s - 1, 0.0)
        obj_z = 0.04 + 0.3 * max(2 * s - 1, 0.0)
        if i >= frames - 10:
            obj_z = 0.04
        out.append((np.array([[0.05, -0.02, hand_z], [0.0, 0.0, obj_z]]), np.array([0.08, 0.04])))
    return out


def test_every_sphere_stays_in_the_image() -> None:
    camera = TrackingCamera(FOVY, ASPECT, DT)
    for centers, radii in grasp_trajectory():
        view = camera.update(centers, radii)
        assert_in_image(view, centers, radii)
        # Framed, not filmed from afar: the spheres fill a good part of the image.
        assert view.distance < 1.0


def test_smoothing_removes_jitter() -> None:
    """Millimetre noise on the tracked positions barely moves the camera."""
    rng = np.random.default_rng(1)
    camera = TrackingCamera(FOVY, ASPECT, DT)
    base = np.array([[0.05, -0.02, 0.15], [0.0, 0.0, 0.04]])
    radii = np.array([0.08, 0.04])
    lookats, distances, targets = [], [], []
    for _ in range(200):
        centers = base + rng.normal(scale=0.002, size=base.shape)
        view = camera.update(centers, radii)
        lookats.append(view.lookat)
        distances.append(view.distance)
        targets.append(centers.mean(axis=0))
        assert_in_image(view, centers, radii)
    camera_steps = np.linalg.norm(np.diff(lookats[50:], axis=0), axis=1)
    target_steps = np.linalg.norm(np.diff(targets[50:], axis=0), axis=1)
    assert camera_steps.mean() < 0.3 * target_steps.mean()
    assert np.ptp(distances[50:]) < 0.1 * np.mean(distances[50:])


def test_zooms_in_gradually_and_out_at_once() -> None:
    camera = TrackingCamera(FOVY, ASPECT, DT)
    far = np.array([[0.0, 0.0, 0.5], [0.0, 0.0, 0.0]]), np.array([0.08, 0.04])
    near = np.array([[0.0, 0.0, 0.12], [0.0, 0.0, 0.0]]), np.array([0.08, 0.04])
    wide = camera.update(*far).distance
    steps = [camera.update(*near).distance for _ in range(60)]
    assert steps[0] > 0.8 * wide  # no jump inward
    assert all(b <= a for a, b in zip(steps, steps[1:], strict=False))
    assert steps[-1] < 0.6 * wide
    assert camera.update(*far).distance >= wide  # out at once: the hand stays in view
