"""Offscreen rendering of environments into videos (``trainer demo``, ``trainer play``).

MuJoCo picks its OpenGL backend when it is first imported, from ``MUJOCO_GL``; the command line
sets ``MUJOCO_GL=egl`` before importing anything (EGL renders without a display; ``osmesa`` is
the software fallback). Videos: ``.mp4`` (H.264 through the ffmpeg binary of imageio-ffmpeg) or
``.gif`` (Pillow).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import mujoco
import numpy as np

from geomprep.store import atomic_path
from trainer.env import GraspEnv
from trainer.errors import TrainerError

VIDEO_SUFFIXES = (".mp4", ".gif")


class EnvRecorder:
    """Renders chosen environments of a ``GraspEnv`` side by side, one frame per ``capture``.

    env_ids: which environments (one tile each, left to right); width, height: pixels per tile;
    camera: a camera of the scene (``front``), or None for a free camera looking at the object.
    """

    def __init__(
        self,
        env: GraspEnv,
        env_ids: Sequence[int],
        width: int = 480,
        height: int = 360,
        camera: str | None = "front",
    ) -> None:
        self.env = env
        self.env_ids = [int(i) for i in env_ids]
        backend = env.backend
        self._models = [backend.models[backend.env_model[i]] for i in self.env_ids]
        self._datas = [mujoco.MjData(m) for m in self._models]
        try:
            self._renderers = [mujoco.Renderer(m, height, width) for m in self._models]
        except Exception as error:  # noqa: BLE001 (any GL failure gets the same fix)
            raise TrainerError(
                f"offscreen rendering failed ({error}); set MUJOCO_GL=egl (or osmesa) before "
                "starting Python, and install libegl1 (or libosmesa6)"
            ) from error
        self.camera = camera
        self.frames: list[np.ndarray] = []

    def capture(self) -> np.ndarray:
        """Render the current state of every chosen env; returns and keeps the (H, W·n, 3)
        uint8 frame."""
        qpos = self.env.backend.qpos.detach().cpu().double().numpy()
        mocap_pos, mocap_quat = self.env.mocap_targets()
        tiles = []
        for k, i in enumerate(self.env_ids):
            model, data, renderer = self._models[k], self._datas[k], self._renderers[k]
            data.qpos[:] = qpos[i]
            if model.nmocap:
                data.mocap_pos[:] = mocap_pos[i].detach().cpu().numpy()
                data.mocap_quat[:] = mocap_quat[i].detach().cpu().numpy()
            mujoco.mj_forward(model, data)
            renderer.update_scene(data, self.camera if self.camera else -1)
            tiles.append(renderer.render())
        frame = np.concatenate(tiles, axis=1)
        self.frames.append(frame)
        return frame

    def save(self, path: str | Path, fps: float) -> Path:
        """Write the captured frames as a video (atomically)."""
        return write_video(path, self.frames, fps)

    def close(self) -> None:
        for renderer in self._renderers:
            renderer.close()


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
