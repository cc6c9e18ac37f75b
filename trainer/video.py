"""Offscreen rendering of environments into videos (``trainer demo``, ``trainer play``).

MuJoCo picks its OpenGL backend when it is first imported, from ``MUJOCO_GL``; the command line
sets ``MUJOCO_GL=egl`` before importing anything (EGL renders without a display; ``osmesa`` is
the software fallback). Videos: ``.mp4`` (H.264 through the ffmpeg binary of imageio-ffmpeg) or
``.gif`` (Pillow).

By default each tile is filmed by a ``TrackingCamera`` that keeps the hand and the env's target
object in frame (in a scene with a bin: the hand, the whole bin and every object still on the
table, so that the clutter is visible); ``EnvRecorder.capture_hold`` keeps the simulation rolling
after the episode so that the video does not stop on the very frame the object is lifted.
``StateTape`` records the states of every env without rendering, so that ``trainer play --tries``
can run many episodes and film only the chosen ones afterwards (``EnvRecorder.film``).

Objects are found by their slot body (``trainer.assets.scene.slot_name``), the bin by its geoms'
names (``bin_floor``, ``bin_wall_x+``, ...), the hand as the subtree of the ``palm`` body: never
by body order.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import mujoco
import numpy as np
import torch

from geomgrasp.files import atomic_path
from trainer.assets.scene import hand_geoms, slot_geoms, slot_name
from trainer.camera import CameraView, TrackingCamera
from trainer.errors import TrainerError
from trainer.tasks import GraspTask

VIDEO_SUFFIXES = (".mp4", ".gif")
TAIL_SECONDS = 1.0
"""Simulated time (s) a video keeps rolling after its episodes end."""


class EnvRecorder:
    """Renders chosen environments of a task (``trainer.tasks.make_env``) side by side, one frame
    per ``capture``.

    env_ids: which environments (one tile each, left to right); width, height: pixels per tile;
    camera: None (default) for a tracking camera per tile (``trainer.camera``) that keeps in view
    the hand and the env's current target object, re-read at every frame since each episode may
    have another target; in a scene with a bin, the hand, the bin and every object still on the
    table. Or the name of a fixed camera of the scene (``front``).
    """

    def __init__(
        self,
        env: GraspTask,
        env_ids: Sequence[int],
        width: int = 480,
        height: int = 360,
        camera: str | None = None,
    ) -> None:
        self.env = env
        self.env_ids = [int(i) for i in env_ids]
        self.models = [env.backend.model_for_env(i) for i in self.env_ids]
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
        self.with_bin = "bin" in env.scene.fixtures
        slots = range(env.scene.num_slots)
        self._hand = [hand_geoms(m) for m in self.models]
        self._bin = [bin_geoms(m) if self.with_bin else np.zeros(0, int) for m in self.models]
        self._slot_geoms = [[slot_geoms(m, s) for s in slots] for m in self.models]
        self._slot_bodies = [[m.body(slot_name(s)).id for s in slots] for m in self.models]
        self._targets = self._read_targets()
        self.frames: list[np.ndarray] = []

    def _read_targets(self) -> list[int]:
        target_slot = self.env.state["target_slot"].detach().cpu()
        return [int(target_slot[i]) for i in self.env_ids]

    def capture(self) -> np.ndarray:
        """Render the current state of every chosen env; returns and keeps the (H, W·n, 3)
        uint8 frame."""
        return self._render(StateTape.snapshot(self.env))

    def film(self, tape: StateTape) -> None:
        """Render every state ``tape`` recorded, one frame each, for the chosen envs (which
        index the tape's envs: the same env as the tape's)."""
        for state in tape.states:
            self._render(state)

    def _render(self, state: EnvState) -> np.ndarray:
        qpos, mocap_pos, mocap_quat, target_slot = state
        self._targets = [int(target_slot[i]) for i in self.env_ids]
        tiles = []
        for k, i in enumerate(self.env_ids):
            model, data, renderer = self.models[k], self.datas[k], self._renderers[k]
            data.qpos[:] = qpos[i]
            if model.nmocap:
                data.mocap_pos[:] = mocap_pos[i]
                data.mocap_quat[:] = mocap_quat[i]
            mujoco.mj_forward(model, data)
            renderer.update_scene(data, self.camera_for(k))
            tiles.append(renderer.render())
        frame = np.concatenate(tiles, axis=1)
        self.frames.append(frame)
        return frame

    def framed_parts(self, k: int) -> dict[str, np.ndarray]:
        """Geom ids the tracking camera of tile ``k`` keeps in view, by part, for the state now
        in its MjData (as of the last ``capture``): ``hand``, ``target`` (the env's target
        object) and, with a bin, ``bin`` and ``clutter`` (the other objects still above
        ``fall_height``: one that fell off the table is let go rather than zoomed out to)."""
        target = self._targets[k]
        parts = {"hand": self._hand[k], "target": self._slot_geoms[k][target]}
        if self.with_bin:
            height = self.datas[k].xpos[self._slot_bodies[k], 2]
            on_table = [
                s for s, z in enumerate(height) if s != target and z > self.env.cfg.fall_height
            ]
            parts["bin"] = self._bin[k]
            parts["clutter"] = np.concatenate(
                [np.zeros(0, int)] + [self._slot_geoms[k][s] for s in on_table]
            )
        return parts

    def camera_for(self, k: int) -> mujoco.MjvCamera | str:
        """The camera of tile ``k`` for the state now in its MjData: the fixed scene camera, or
        the tracking camera moved on by one frame."""
        if self.camera:
            return self.camera
        parts = self.framed_parts(k)
        model, data = self.models[k], self.datas[k]
        geoms = np.concatenate([g for part, g in parts.items() if part != "bin"])
        centers, radii = data.geom_xpos[geoms], model.geom_rbound[geoms]
        if "bin" in parts:
            # The bin's boxes by their corners: their bounding spheres reach far past the thin
            # walls and floor and would film the bin from ~1.4 times as far.
            corners = box_corners(model, data, parts["bin"])
            centers = np.concatenate([centers, corners])
            radii = np.concatenate([radii, np.zeros(len(corners))])
        view = self.trackers[k].update(centers, radii)
        return mjv_camera(view)

    def capture_hold(self, seconds: float = TAIL_SECONDS) -> None:
        """Keep the simulation rolling for ``seconds`` after the episodes, holding the last
        commands (the hand keeps its grip, the arm its pose), one frame per control period.

        Uses ``env.hold()``: the episodes are over, so nothing (observations, step counts,
        rewards, targets) is updated on the env; use it last, before ``save``."""
        env = self.env
        for _ in range(round(seconds * env.cfg.physics.control_hz)):
            env.hold()
            self.capture()

    def save(self, path: str | Path, fps: float) -> Path:
        """Write the captured frames as a video (atomically)."""
        return write_video(path, self.frames, fps)

    def close(self) -> None:
        for renderer in self._renderers:
            renderer.close()


EnvState = tuple[np.ndarray, np.ndarray | None, np.ndarray | None, np.ndarray]
"""What a frame is rendered from, for every env of a task: qpos (E, nq) float64, the mocap
target's position (E, 1, 3) and quaternion (E, 1, 4) (Nones without a mocap hand), and the
target slot (E,) int."""


class StateTape:
    """Records the state of every env of a task at each ``capture``, to film chosen envs later
    (``EnvRecorder.film``): ``trainer play --tries`` runs many episodes, then films the ones
    that succeeded. A few kB per env and step (qpos and the targets), nothing rendered."""

    def __init__(self, env: GraspTask) -> None:
        self.env = env
        self.states: list[EnvState] = []

    @staticmethod
    def snapshot(env: GraspTask) -> EnvState:
        """The state of every env of ``env`` now: copies on the CPU (the backend's arrays are
        views that the next step overwrites)."""

        def copy(x: torch.Tensor) -> np.ndarray:
            return x.detach().to("cpu", torch.float64, copy=True).numpy()

        mocap_pos, mocap_quat = env.mocap_targets()
        return (
            copy(env.backend.qpos),
            None if mocap_pos is None else copy(mocap_pos),
            None if mocap_quat is None else copy(mocap_quat),
            env.state["target_slot"].detach().cpu().numpy().copy(),
        )

    def capture(self) -> None:
        self.states.append(self.snapshot(self.env))

    def on_step(self, env: GraspTask, step: int, td: object) -> None:
        """``capture`` as the step hook of an episode run (``trainer.session``)."""
        self.capture()

    def end_at(self, steps: int, seconds: float = TAIL_SECONDS) -> None:
        """Make the tape ``steps`` control periods plus ``seconds`` long: the states past that
        are dropped (the filmed episodes ended ``steps`` in, the others ran on), and a tape too
        short rolls the simulation on holding the last commands (``GraspTask.hold``)."""
        want = steps + round(seconds * self.env.cfg.physics.control_hz)
        del self.states[want:]
        while len(self.states) < want:
            self.env.hold()
            self.capture()


def mjv_camera(view: CameraView) -> mujoco.MjvCamera:
    """MuJoCo's free camera for ``view``."""
    cam = mujoco.MjvCamera()
    cam.type = mujoco.mjtCamera.mjCAMERA_FREE
    cam.lookat[:] = view.lookat
    cam.distance = view.distance
    cam.azimuth = view.azimuth
    cam.elevation = view.elevation
    return cam


def bin_geoms(model: mujoco.MjModel) -> np.ndarray:
    """Geom ids of the bin fixture (``bin_floor``, ``bin_wall_*``); empty without a bin."""
    names = (model.geom(g).name for g in range(model.ngeom))
    return np.array([g for g, name in enumerate(names) if name.startswith("bin_")], dtype=int)


def box_corners(model: mujoco.MjModel, data: mujoco.MjData, geoms: np.ndarray) -> np.ndarray:
    """World positions (8·n, 3) of the corners of the box geoms ``geoms`` (n,) in ``data``."""
    signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    local = signs[None, :, :] * model.geom_size[geoms][:, None, :]  # (n, 8, 3)
    rot = data.geom_xmat[geoms].reshape(-1, 3, 3)
    world = data.geom_xpos[geoms][:, None, :] + local @ rot.transpose(0, 2, 1)
    return world.reshape(-1, 3)


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
