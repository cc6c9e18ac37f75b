"""Offscreen rendering of environments into videos (``trainer demo``, ``trainer play``).

MuJoCo picks its OpenGL backend when it is first imported, from ``MUJOCO_GL``; the command line
sets ``MUJOCO_GL=egl`` before importing anything (EGL renders without a display; ``osmesa`` is
the software fallback). Videos: ``.mp4`` (H.264 through the ffmpeg binary of imageio-ffmpeg) or
``.gif`` (Pillow).

By default each tile is filmed by a ``TrackingCamera`` that keeps the hand and the object in
frame; ``EnvRecorder.capture_hold`` keeps the simulation rolling after the episode so that the
video does not stop on the very frame the object is lifted.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import mujoco
import numpy as np

from geomprep.store import atomic_path
from trainer.camera import CameraView, TrackingCamera
from trainer.env import GraspEnv
from trainer.errors import TrainerError

VIDEO_SUFFIXES = (".mp4", ".gif")
TAIL_SECONDS = 1.0
"""Simulated time (s) a video keeps rolling after its episodes end."""


class EnvRecorder:
    """Renders chosen environments of a ``GraspEnv`` side by side, one frame per ``capture``.

    env_ids: which environments (one tile each, left to right); width, height: pixels per tile;
    camera: None (default) for a tracking camera per tile that keeps the hand and the object in
    view (``trainer.camera``), or the name of a fixed camera of the scene (``front``).
    """

    def __init__(
        self,
        env: GraspEnv,
        env_ids: Sequence[int],
        width: int = 480,
        height: int = 360,
        camera: str | None = None,
    ) -> None:
        self.env = env
        self.env_ids = [int(i) for i in env_ids]
        backend = env.backend
        self.models = [backend.models[backend.env_model[i]] for i in self.env_ids]
        self.datas = [mujoco.MjData(m) for m in self.models]
        try:
            self._renderers = [mujoco.Renderer(m, height, width) for m in self.models]
        except Exception as error:  # noqa: BLE001 (any GL failure gets the same fix)
            raise TrainerError(
                f"offscreen rendering failed ({error}); set MUJOCO_GL=egl (or osmesa) before "
                "starting Python, and install libegl1 (or libosmesa6)"
            ) from error
        self.camera = camera
        dt = 1.0 / env.cfg.physics.control_hz
        self.trackers = [
            TrackingCamera(float(m.vis.global_.fovy), width / height, dt) for m in self.models
        ]
        self._framed = [framed_geoms(m) for m in self.models]
        self.frames: list[np.ndarray] = []

    def capture(self) -> np.ndarray:
        """Render the current state of every chosen env; returns and keeps the (H, W·n, 3)
        uint8 frame."""
        qpos = self.env.backend.qpos.detach().cpu().double().numpy()
        mocap_pos, mocap_quat = self.env.mocap_targets()
        tiles = []
        for k, i in enumerate(self.env_ids):
            model, data, renderer = self.models[k], self.datas[k], self._renderers[k]
            data.qpos[:] = qpos[i]
            if model.nmocap:
                data.mocap_pos[:] = mocap_pos[i].detach().cpu().numpy()
                data.mocap_quat[:] = mocap_quat[i].detach().cpu().numpy()
            mujoco.mj_forward(model, data)
            renderer.update_scene(data, self.camera_for(k))
            tiles.append(renderer.render())
        frame = np.concatenate(tiles, axis=1)
        self.frames.append(frame)
        return frame

    def camera_for(self, k: int) -> mujoco.MjvCamera | str:
        """The camera of tile ``k`` for the state now in its MjData: the fixed scene camera, or
        the tracking camera moved on by one frame."""
        if self.camera:
            return self.camera
        geoms = self._framed[k]
        data = self.datas[k]
        view = self.trackers[k].update(data.geom_xpos[geoms], self.models[k].geom_rbound[geoms])
        return mjv_camera(view)

    def capture_hold(self, seconds: float = TAIL_SECONDS) -> None:
        """Keep the simulation rolling for ``seconds`` after the episodes, holding the last
        commands (the hand keeps its grip, the arm its pose), one frame per control period.

        Steps the backend directly: the episodes are over, so nothing (observations, step
        counts, rewards) is updated on the env; use it last, before ``save``."""
        env = self.env
        for _ in range(round(seconds * env.cfg.physics.control_hz)):
            env.backend.step(env.ctrl, *env.mocap_targets())
            self.capture()

    def save(self, path: str | Path, fps: float) -> Path:
        """Write the captured frames as a video (atomically)."""
        return write_video(path, self.frames, fps)

    def close(self) -> None:
        for renderer in self._renderers:
            renderer.close()


def mjv_camera(view: CameraView) -> mujoco.MjvCamera:
    """MuJoCo's free camera for ``view``."""
    cam = mujoco.MjvCamera()
    cam.type = mujoco.mjtCamera.mjCAMERA_FREE
    cam.lookat[:] = view.lookat
    cam.distance = view.distance
    cam.azimuth = view.azimuth
    cam.elevation = view.elevation
    return cam


def hand_geoms(model: mujoco.MjModel) -> np.ndarray:
    """Geom ids (K,) of the hand: the ``palm`` body and every body below it."""
    palm = model.body("palm").id
    hand = np.zeros(model.nbody, dtype=bool)
    for body in range(model.nbody):
        # Parents come before children in MuJoCo's body order, so one pass marks the subtree.
        hand[body] = body == palm or (body > 0 and hand[model.body_parentid[body]])
    return np.flatnonzero(hand[model.geom_bodyid])


def object_geoms(model: mujoco.MjModel) -> np.ndarray:
    """Geom ids (K,) of the object (the last body, as in ``GraspEnv``)."""
    return np.flatnonzero(model.geom_bodyid == model.nbody - 1)


def framed_geoms(model: mujoco.MjModel) -> np.ndarray:
    """Geom ids (K,) the tracking camera keeps in view: the hand's and the object's."""
    return np.concatenate([hand_geoms(model), object_geoms(model)])


def write_video(path: str | Path, frames: Sequence[np.ndarray], fps: float) -> Path:
    """Frames (H, W, 3) uint8 → ``path`` (.mp4 or .gif), written to a temp file then renamed."""
    path = Path(path)
    if path.suffix.lower() not in VIDEO_SUFFIXES:
        raise TrainerError(f"{path}: unknown video format; use a name ending in .mp4 or .gif")
    if not frames:
        raise TrainerError(f"{path}: no frames were captured")
    path.parent.mkdir(parents=True, exist_ok=True)
    height, width = frames[0].shape[:2]
    with atomic_path(path) as tmp:
        if path.suffix.lower() == ".gif":
            from PIL import Image

            images = [Image.fromarray(f) for f in frames]
            images[0].save(
                tmp, format="GIF", save_all=True, append_images=images[1:],
                duration=int(round(1000 / fps)), loop=0,
            )
        else:
            import imageio_ffmpeg

            # H.264 wants even sizes; pad by one pixel rather than resample.
            pad = ((0, height % 2), (0, width % 2), (0, 0))
            writer = imageio_ffmpeg.write_frames(
                str(tmp), (width + width % 2, height + height % 2), fps=fps, codec="libx264",
                pix_fmt_out="yuv420p", output_params=["-f", "mp4"], macro_block_size=1,
            )
            writer.send(None)
            for frame in frames:
                writer.send(np.ascontiguousarray(np.pad(frame, pad)))
            writer.close()
    return path
