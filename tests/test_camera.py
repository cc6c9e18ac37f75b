"""trainer.camera: the tracking camera keeps every sphere in the image and moves smoothly; and
what ``trainer.video`` frames in a task scene (hand, slots, bin), found by name, not body order."""

from __future__ import annotations

import math

import numpy as np

from geomprep.config import Config
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


def test_scene_parts_found_by_name_and_the_bin_framed_by_its_corners(builtin_data: Config) -> None:
    """In a bin scene the hand, each slot's object and the bin are disjoint sets of geoms
    (slot k: exactly the geoms named ``slot{k}/...``, whatever the body order); the bin's box
    corners are its extreme points, a camera fed them and the hand sees all of them, and frames
    the bin from closer than the boxes' bounding spheres would allow."""
    import mujoco

    from trainer.assets.scene import Scene, build_scene
    from trainer.config import load_env_config
    from trainer.video import bin_geoms, box_corners, hand_geoms, slot_geoms

    cfg = load_env_config(task="bin", data_dir=builtin_data.data_dir)
    processed = builtin_data.data_dir / "processed"
    xmls = [processed / n / f"{n}.xml" for n in ("builtin_mug", "builtin_box", "builtin_sphere")]
    model = build_scene(cfg, Scene(("table", "bin"), len(xmls)), xmls).compile()
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    names = [model.geom(g).name for g in range(model.ngeom)]
    hand, box = hand_geoms(model), bin_geoms(model)
    slots = [slot_geoms(model, k) for k in range(len(xmls))]
    for k, geoms in enumerate(slots):
        assert sorted(geoms) == [g for g, n in enumerate(names) if n.startswith(f"slot{k}/")]
    assert sorted(names[g] for g in box) == sorted(
        ["bin_floor", "bin_wall_x+", "bin_wall_x-", "bin_wall_y+", "bin_wall_y-"]
    )
    parts = [hand, box, *slots]
    assert sum(len(p) for p in parts) == len(np.unique(np.concatenate(parts)))
    assert len(hand) > 0 and not np.isin(hand, np.concatenate([box, *slots])).any()

    corners = box_corners(model, data, box)
    hx, hy = cfg.bin.inner_half_size
    t = cfg.bin.wall_thickness
    assert np.allclose(corners.max(axis=0), [hx + t, hy + t, cfg.bin.wall_height])
    assert np.allclose(corners.min(axis=0), [-hx - t, -hy - t, 0.001 - t])  # floor: 1 mm up

    camera = TrackingCamera(FOVY, ASPECT, DT)
    centers = np.concatenate([data.geom_xpos[hand], corners])
    radii = np.concatenate([model.geom_rbound[hand], np.zeros(len(corners))])
    assert_in_image(camera.update(centers, radii), centers, radii)
    # The bin alone: its corners 0.71x the distance its boxes' bounding spheres need.
    zeros = np.zeros(len(corners))
    by_corners = TrackingCamera(FOVY, ASPECT, DT).update(corners, zeros)
    by_spheres = TrackingCamera(FOVY, ASPECT, DT).update(
        data.geom_xpos[box], model.geom_rbound[box]
    )
    assert by_corners.distance < 0.8 * by_spheres.distance
