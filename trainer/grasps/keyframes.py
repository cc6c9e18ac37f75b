"""The keyframe grasp (family ``searched``): an open-loop grasp described by a short parameter
vector per env, so that a sampling search (``search.py``) can look for a grasp where no
hand-written family lifts an object, and the grasp it finds runs like any other family.

The parameters (``PARAMS``, one row of ``theta`` (E, D) per env) are in the target's *grasp
frame*, the frame of the top grasp (``top.grasp_frame``): origin at the top of the target's
bounding box above its centre, axes ``across`` (horizontal, the palm's x at the top grasp),
``along`` (horizontal, the fingers' direction there: across the target's narrowest width) and
world up. So a parameter vector means the same grasp for every initial pose of the target.

* ``x, y, z`` (m): the palm keypoint's goal at the grasp, in the grasp frame.
* ``yaw, pitch, roll`` (rad): the palm's orientation, the top grasp's palm-down orientation
  turned by ``roll`` about the fingers, ``pitch`` about the palm's x, then ``yaw`` about the
  vertical.
* ``open0..4``, ``closed0..4``: the 5 hand actions (action units, [-1, 1]: -1 the joint's open
  end, 1 its closed end) on the way down and at the end of the close.
* ``drag_x, drag_y, drag_z`` (m): how far the palm moves (grasp frame) while the hand closes:
  a sweep that rolls or slides the target into the hand.

Phases (actions at 30 Hz): approach to ``hover`` above the grasp goal, descend, close (the
hand's targets ramp from open to closed while the palm drags), settle, lift ``lift`` at half
speed, hold 1 s.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import torch

from geomgrasp.rotations import axis_angle_to_matrix
from trainer.errors import TrainerError
from trainer.grasps.geometry import ramp, steer
from trainer.grasps.top import TopGrasp, grasp_frame
from trainer.robots import sih
from trainer.tasks import GraspTask

PARAMS = (
    "x", "y", "z", "yaw", "pitch", "roll",
    "open0", "open1", "open2", "open3", "open4",
    "closed0", "closed1", "closed2", "closed3", "closed4",
    "drag_x", "drag_y", "drag_z",
)
"""The names of a keyframe grasp's parameters, in the order of ``theta``'s last axis."""
DIM = len(PARAMS)
_I = {name: i for i, name in enumerate(PARAMS)}


def index(name: str) -> int:
    """The position of parameter ``name`` in ``PARAMS``."""
    return _I[name]


def top_grasp_theta(top: TopGrasp | None = None) -> torch.Tensor:
    """(D,) the parameters that reproduce ``top`` (default: the top family's base variant):
    the search's starting point."""
    top = top or TopGrasp()
    kp = sih.PALM_KEYPOINT
    theta = torch.zeros(DIM)
    # The top grasp puts the target's centre at (lateral, top + clearance, depth) in the palm
    # frame, whose columns in the grasp frame are (across, -up, along).
    theta[_I["x"]] = kp[0] - top.lateral
    theta[_I["y"]] = kp[2] - top.grasp_depth
    theta[_I["z"]] = top.palm_clearance - kp[1]
    thumb = lambda rad: 2 * rad / sih.THUMB_FLEX_RANGE[1] - 1  # noqa: E731
    theta[_I["open0"]: _I["open0"] + 5] = torch.tensor([1.0, thumb(top.thumb_open), -1, -1, -1])
    theta[_I["closed0"]: _I["closed0"] + 5] = torch.tensor([1.0, thumb(top.thumb_closed), 1, 1, 1])
    return theta


@dataclass(frozen=True, eq=False)  # eq=False: tensor fields have no truth value to compare
class KeyframeGrasp:
    """A keyframe grasp per env: ``theta`` (E, D) or (D,) (the same for every env), or, when
    ``by_object`` is given, the row of each env's target object (object name -> (D,) values).
    ``extra_rows``: rows looked up for the env when the grasp is planned,
    which take the place of ``by_object``'s (the ``searched`` family: the grasps searched in
    the env's data directory with its hand and physics, ``searched.data_rows``)."""

    theta: torch.Tensor | None = None
    by_object: tuple[tuple[str, tuple[float, ...]], ...] = ()
    extra_rows: Callable[[GraspTask], dict[str, tuple[float, ...]]] | None = None
    approach_steps: int = 40
    descend_steps: int = 35
    close_steps: int = 30
    settle_steps: int = 5
    lift_steps: int = 60
    hold_steps: int = 30
    hover: float = 0.10
    lift: float = 0.3
    lift_rate: float = 0.5

    @property
    def total_steps(self) -> int:
        return (self.approach_steps + self.descend_steps + self.close_steps
                + self.settle_steps + self.lift_steps + self.hold_steps)

    @property
    def close_window(self) -> tuple[int, int]:
        start = self.approach_steps + self.descend_steps
        return start, start + self.close_steps

    @property
    def pushed_at(self) -> int:
        """The last step of the descent: a drag moves the target by design during the close."""
        return self.close_window[0] - 1

    def covering(self, names: Sequence[str]) -> KeyframeGrasp:
        """The same grasp with a row for every object of ``names``: those without one take the
        first object's. For a multi-object task whose other objects another family serves (the
        grasp starts' recorder): their envs run some keyframe grasp, and their trials are
        discarded."""
        if self.theta is not None or not self.by_object:
            return self
        table = dict(self.by_object)
        fallback = self.by_object[0][1]
        rows = tuple((n, table.get(n, fallback)) for n in names)
        return replace(self, by_object=rows)

    def env_theta(self, env: GraspTask) -> torch.Tensor:
        """(E, D) each env's parameters; an env whose target has no row is a one-line error."""
        if self.theta is not None:
            return self.theta.to(env.device).expand(env.num_envs, DIM)
        table = dict(self.by_object)
        if self.extra_rows is not None:
            table.update(self.extra_rows(env))
        names = env.objects.names
        missing = sorted({names[k] for k in env.target_objects().unique().tolist()} - set(table))
        if missing:
            raise TrainerError(
                f"no searched grasp for {', '.join(missing)}: search one with "
                f"`trainer grasp-search --objects {','.join(missing)}`, or choose of "
                f"{', '.join(sorted(table)) or 'none'}"
            )
        per_object = torch.tensor([table.get(n, (float("nan"),) * DIM) for n in names])
        return per_object.to(env.device)[env.target_objects()]

    def plan(self, env: GraspTask) -> dict:
        """Per env, from the target's pose after the reset: the keypoint goal at the grasp
        (E, 3), the drag (E, 3) (world), the palm orientation (E, 3, 3) and the hand's open and
        closed actions (E, 5) each."""
        theta = self.env_theta(env)
        center, half_height, palm_rot = grasp_frame(env)
        across, along = palm_rot[..., 0], palm_rot[..., 2]
        up = torch.zeros_like(across)
        up[:, 2] = 1.0
        frame = torch.stack([across, along, up], -1)  # (E, 3, 3) columns: grasp-frame axes
        origin = center.clone()
        origin[:, 2] += half_height
        goal = origin + (frame @ theta[:, 0:3, None])[..., 0]
        drag = (frame @ theta[:, _I["drag_x"]:, None])[..., 0]
        zeros = torch.zeros_like(theta[:, 0])
        yaw = axis_angle_to_matrix(torch.stack([zeros, zeros, theta[:, _I["yaw"]]], -1))
        local = axis_angle_to_matrix(torch.stack([theta[:, _I["pitch"]], zeros,
                                                  theta[:, _I["roll"]]], -1))
        rot = yaw @ palm_rot @ local
        hand_open = theta[:, _I["open0"]: _I["open0"] + 5].clamp(-1, 1)
        hand_closed = theta[:, _I["closed0"]: _I["closed0"] + 5].clamp(-1, 1)
        return {"goal": goal, "drag": drag, "rot": rot, "open": hand_open, "closed": hand_closed}

    def action(self, env: GraspTask, step: int, plan: dict) -> torch.Tensor:
        """The action (E, 11) for every env at episode step ``step``."""
        if step == 0:
            plan.update(self.plan(env))
        t1 = self.approach_steps
        t2 = t1 + self.descend_steps
        t3 = t2 + self.close_steps
        t4 = t3 + self.settle_steps
        frac = ramp(step, t2, self.close_steps)  # the close's progress
        goal = plan["goal"] + frac * plan["drag"]
        if step < t1:
            goal = goal + torch.tensor([0.0, 0.0, self.hover], device=goal.device)
        elif step < t2:
            rest = 1.0 - (step - t1 + 1) / self.descend_steps
            goal = goal + torch.tensor([0.0, 0.0, self.hover * rest], device=goal.device)
        elif step >= t4:
            goal = goal + torch.tensor([0.0, 0.0, self.lift], device=goal.device)
        hand = plan["open"] + frac * (plan["closed"] - plan["open"])
        rate = self.lift_rate if step >= t4 else 1.0
        return torch.cat([steer(env, goal, plan["rot"], rate), hand], dim=-1)
