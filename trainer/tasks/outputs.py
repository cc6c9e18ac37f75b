"""What a task computes from the simulated state at every step, as one pure tensor function
(``StepOutputs``; ``torch.compile`` fuses it when ``cfg.compile``): the observations, the reward
terms' values (``trainer.tasks.terms``), success and termination, the target's lift.

Shapes: E envs, K object slots, O objects; positions in m, quaternions (w, x, y, z).
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Mapping

import torch

from geomgrasp.rotations import quat_to_matrix, rotation_6d
from trainer.config import EnvConfig, RewardConfig
from trainer.errors import TrainerWarning
from trainer.kinematics import SiteKinematics
from trainer.objects import ObjectSet
from trainer.representations import object_representation
from trainer.tasks.terms import RewardTerm, StepQuantities, evaluate_terms

ESCAPE_DISTANCE = 2.0
"""An object higher than this above the table top, or farther than this from its centre (m), is
out of the UR5e's reach (0.85 m from its base): only a blown-up contact puts it there."""
LAUNCH_SPEED = 10.0
"""An object moving faster than this (m/s) was launched by a blown-up contact: the arm moves the
hand at ~1 m/s and an object falling off the table reaches ~1 m/s before it is reset."""

ExtraObservations = Callable[[torch.Tensor, torch.Tensor], dict[str, torch.Tensor]]
"""A task's own observations from every slot's pose (E, K, 7) and the target slot (E,)."""


def compiled_or_eager(function):  # noqa: ANN001, ANN201
    """``torch.compile(function)``, or ``function`` itself (with one warning) if compiling fails,
    e.g. on a machine without a C++ compiler or Python headers: slower, never broken."""
    # Every env instance (each representation, env count, robot) is one more specialization of
    # the same code, and past torch's default limit of 8 it would silently fall back to eager.
    torch._dynamo.config.recompile_limit = max(torch._dynamo.config.recompile_limit, 64)
    current = torch.compile(function, dynamic=False)

    def call(*args):  # noqa: ANN002, ANN202
        nonlocal current
        try:
            return current(*args)
        except torch._dynamo.exc.BackendCompilerFailed as err:
            warnings.warn(
                f"torch.compile failed ({str(err).splitlines()[0][:200]}); the env runs eagerly "
                "(install g++ and the Python headers, or pass --no-compile)",
                TrainerWarning,
                stacklevel=2,
            )
            current = function
            return function(*args)

    return call


def lowest_point(
    points: torch.Tensor, obj_pos: torch.Tensor, obj_quat: torch.Tensor
) -> torch.Tensor:
    """(n,) m: the height of the lowest of each object's surface samples ``points`` (n, P, 3)
    (body frame), the object at obj_pos (n, 3) with quaternion obj_quat (n, 4)."""
    vertical = quat_to_matrix(obj_quat)[:, 2, :]  # (n, 3) the world z axis in the object frame
    heights = torch.einsum("npk,nk->np", points, vertical)
    return heights.amin(-1) + obj_pos[:, 2]


def termination(
    cfg: EnvConfig, lift: torch.Tensor, h_bar: torch.Tensor, tip_distance: torch.Tensor,
    obj_pos: torch.Tensor, step_count: torch.Tensor,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(success, terminated, truncated), each (E,) bool: success is the target lifted by
    h_bar while held, ``reward.hold_tips`` fingertip pads within ``reward.hold_distance`` of
    its surface (tip_distance (E, 5), m): a toss through h_bar is not a lift (below a
    training target of ``reward.hold_from`` it is). A blown-up simulation also truncates;
    the task adds that from the backend's ``unstable``."""
    r = cfg.reward
    held = (tip_distance < r.hold_distance).sum(-1) >= r.hold_tips
    held = held | (h_bar < r.hold_from)
    success = (lift >= h_bar) & held
    fell = obj_pos[:, 2] < cfg.fall_height
    return success, success | fell, step_count >= cfg.max_steps


def thrown(pos: torch.Tensor, speed: torch.Tensor) -> torch.Tensor:
    """(E,) bool: some object (positions ``pos`` (E, K, 3), speeds ``speed`` (E, K)) was
    launched by a blown-up contact: it is out of the robot's reach (``ESCAPE_DISTANCE``) or
    faster than ``LAUNCH_SPEED``. The backend's ``unstable`` misses this: rises of hundreds of
    metres were seen with impratio 10, every speed finite and below its MAX_SPEED, and the
    object counted as lifted on its way up."""
    far = (pos[..., 2] > ESCAPE_DISTANCE) | (pos[..., :2].norm(dim=-1) > ESCAPE_DISTANCE)
    return (far | (speed > LAUNCH_SPEED)).any(1)


class StepOutputs:
    """The per-step outputs of a task's envs: the robot's sites (``kinematics``), the objects
    (``objects``) in slots at qpos addresses ``slot_qpos`` (K, 7), filled per env as
    ``assignment`` (E, K) object ids, the hand's joints at ``hand_qpos`` (11,), the reward's
    ``terms`` and the task's ``extra_obs``.

    ``observed``: the objects as the target's representation tells the policy of them,
    ``objects`` unless a caller sets other shapes (scripts/observed_size.py: what a trained
    policy reads from the size it is shown); the physics, the lift, the reward, the success and
    a task's ``extra_obs`` (the bin's context boxes) always use ``objects``."""

    def __init__(
        self, cfg: EnvConfig, objects: ObjectSet, kinematics: SiteKinematics,
        slot_qpos: torch.Tensor, assignment: torch.Tensor, hand_qpos: torch.Tensor,
        terms: Mapping[str, RewardTerm], extra_obs: ExtraObservations,
    ) -> None:
        self.cfg, self.objects, self.kinematics = cfg, objects, kinematics
        self.observed: ObjectSet = objects
        self.slot_qpos, self.assignment, self.hand_qpos = slot_qpos, assignment, hand_qpos
        self.terms, self.extra_obs = terms, extra_obs

    def __call__(
        self,
        qpos: torch.Tensor,
        start_height: torch.Tensor,
        start_low: torch.Tensor,
        step_count: torch.Tensor,
        target_slot: torch.Tensor,
        h_bars: torch.Tensor,
    ) -> tuple[dict, dict, tuple, torch.Tensor]:
        """(observations, the reward terms' values and ``lift_height``, (success, terminated,
        truncated), palm position (E, 3)) from qpos (E, nq). start_height, start_low (E,): the
        target's centre and lowest surface point at the episode's start (start_low read only
        with ``reward.lift_clearance``), m; step_count (E,); target_slot (E,); h_bars: the lift
        target per object id (O,), m."""
        poses = self.kinematics.forward(qpos)
        slots = qpos[:, self.slot_qpos]  # (E, K, 7)
        target = slots.gather(1, target_slot[:, None, None].expand(-1, 1, 7))[:, 0]
        target_id = self.assignment.gather(1, target_slot[:, None])[:, 0]
        h_bar = h_bars[target_id]  # (E,)
        obj_pos, obj_quat = target[:, :3], target[:, 3:]
        tips = poses.site_pos[:, 1:]
        palm_pos, palm_rot = poses.site_pos[:, 0], poses.site_rot[:, 0]
        obs = self.observations(qpos, palm_pos, palm_rot, target_id, obj_pos, obj_quat, tips,
                                slots, target_slot)
        # A blown-up env (flagged unstable, truncated, reset next) must not feed NaN to the
        # networks or to the value targets.
        obs = {
            k: v if v.dtype == torch.bool else torch.nan_to_num(v, nan=0.0, posinf=0.0, neginf=0.0)
            for k, v in obs.items()
        }
        lift = self.lift(obj_pos, obj_quat, target_id, start_height, start_low)
        if self.cfg.representation == "sdf" and self.observed is self.objects:
            tip_distance = obs["object"]  # the same query: the fingertips' signed distances
        elif self.objects.sdf is not None:
            tip_distance = self.objects.sdf.query(tips, obj_pos, obj_quat, target_id)
        else:  # no SDF is needed: the com reward and no hold condition (hold_tips = 0)
            tip_distance = torch.zeros_like(tips[..., 0])
        flags = termination(self.cfg, lift, h_bar, tip_distance, obj_pos, step_count)
        quantities = StepQuantities(lift, h_bar, flags[0], tips, tip_distance, obj_pos)
        terms = evaluate_terms(self.terms, quantities, self.cfg.reward)
        terms["lift_height"] = lift
        return obs, terms, flags, palm_pos

    def observations(
        self, qpos: torch.Tensor, palm_pos: torch.Tensor, palm_rot: torch.Tensor,
        target_id: torch.Tensor, obj_pos: torch.Tensor, obj_quat: torch.Tensor,
        tips: torch.Tensor, slots: torch.Tensor, target_slot: torch.Tensor,
    ) -> dict[str, torch.Tensor]:
        """The robot's proprioception and the target's representation, then what the task adds
        (``extra_obs``). palm_rot (E, 3, 3); tips (E, 5, 3) the fingertip pads."""
        parts = [palm_pos, rotation_6d(palm_rot), qpos[:, self.hand_qpos]]
        if self.cfg.observe_fingertips:
            parts.append(tips.reshape(tips.shape[0], -1))
        proprio = torch.cat(parts, dim=-1)
        obj = object_representation(
            self.cfg.representation, self.observed, target_id, obj_pos, obj_quat, tips
        )
        return {"proprio": proprio, "object": obj, **self.extra_obs(slots, target_slot)}

    def lift(
        self, obj_pos: torch.Tensor, obj_quat: torch.Tensor, target_id: torch.Tensor,
        start_height: torch.Tensor, start_low: torch.Tensor,
    ) -> torch.Tensor:
        """(E,) m: the target's lift, the rise of its centre once it is clear of where it rested
        (obj_pos (E, 3), obj_quat (E, 4), target_id (E,); start_height, start_low (E,))."""
        lift = obj_pos[:, 2] - start_height
        r: RewardConfig = self.cfg.reward
        if r.lift_clearance > 0:
            # Until the target is clear of where it rested, its lift is its lowest point's rise:
            # a tipped object's centre rises, its lowest point does not.
            low = lowest_point(self.objects.points[target_id], obj_pos, obj_quat)
            low_rise = low - start_low
            lift = torch.where(low_rise >= r.lift_clearance, lift, low_rise)
        return lift
