"""The hold probe: how firmly a grasp holds its target once lifted (issue 33's slip and pull
targets), measured on one env's state copied out of the backend (``SimBackend.snapshot``).

From the state at the end of a scripted grasp, with the hand's controls held:

1. *settle* for ``SETTLE_S`` seconds, then *hold* for ``HOLD_S``: the slip speed is how fast
   the target moves relative to the palm frame (mm/s); the grip force is the summed normal force
   of the hand-target contacts, and the support capacity the largest upward load those contacts
   can carry with their normal forces as measured: per contact, its normal force's upward share
   (negative for a palm pressing down on the target: that is a load) plus its friction
   coefficient times the normal force times the share of the vertical in its tangent plane
   (friction pointed straight up), summed (N); both averaged over the hold;
2. *pull*: a downward force on the target grows by ``PULL_RATE`` N/s until the target has moved
   ``SLIP_MM`` relative to the palm (or ``MAX_PULL`` is reached). The pull ratio is the load
   held at that moment (the target's weight plus the pull) over the support capacity measured
   while holding: 1.0 means the grip resisted everything friction times its force allows
   (the squeeze may rise under load, so a ratio above 1 is possible). Soft contacts creep under
   a tangential load below the friction limit, so a ratio well below 1 names creep. The
   contacts' capacity is measured again at the moment the pull ends (``slip_capacity_n``):
   where the squeeze falls under the pull (a force-limited servo yielding), the load over that
   (``slip_pull_ratio``) tells a grip that lost force from contacts that slid below their limit;
   and each contact's use of its friction cone then (``slip_cone_min`` / ``slip_cone_max``: 1 is
   at its limit, sliding) tells whether the contacts gave way together or one pad first.

One env at a time on a plain ``MjData`` (a probe, not a hot path: a few trials per object).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np

from trainer.assets.collision import BIT_HAND

SETTLE_S = 0.2
HOLD_S = 1.0
PULL_RATE = 5.0
"""N/s: how fast the downward pull grows."""
SLIP_MM = 5.0
"""mm: the target's move relative to the palm that ends the pull (it slipped)."""
MAX_PULL = 50.0
"""N: the pull stops here even if the target did not slip."""
DROP_MM = 20.0
"""mm: a target that moved this far relative to the palm while settling and holding, or that
no hand geom touches at the hold's end, was not held (it was falling when the script ended)."""


@dataclass(frozen=True)
class Hold:
    """One held target's measurements (``measure_hold``)."""

    slip_mm_s: float
    """Mean speed of the target relative to the palm frame during the hold (mm/s)."""
    grip_n: float
    """Summed normal force of the hand-target contacts, mean over the hold (N)."""
    capacity_n: float
    """The upward load the contacts can carry at their measured normal forces N, mean over the
    hold (N): the sum of N (n_z + mu sqrt(1 - n_z^2)), n the contact's normal pushing on the
    target, mu its friction coefficient."""
    weight_n: float
    """The target's weight (N)."""
    pull_n: float
    """The downward pull at which the target slipped ``SLIP_MM`` (N); ``MAX_PULL`` if never."""
    slip_grip_n: float
    """The grip's summed normal force when the pull ended (N)."""
    slip_capacity_n: float
    """The contacts' capacity (as ``capacity_n``) when the pull ended (N)."""
    slip_cone_min: float
    """When the pull ended, the least use of its friction cone among the hand-target contacts
    that push (``cone_use``; NaN without one)."""
    slip_cone_max: float
    """... and the most (1: that contact is at its friction limit, sliding)."""
    held: bool
    """Whether the hand held the target through the settle and hold (``DROP_MM``); the other
    fields of a target that was not held measure a fall, not a grip."""

    @property
    def pull_ratio(self) -> float:
        """(weight + pull) / friction capacity; NaN without contact."""
        if self.capacity_n <= 0:
            return math.nan
        return (self.weight_n + self.pull_n) / self.capacity_n

    @property
    def slip_pull_ratio(self) -> float:
        """(weight + pull) / the capacity when the pull ended; NaN without contact then."""
        if self.slip_capacity_n <= 0:
            return math.nan
        return (self.weight_n + self.pull_n) / self.slip_capacity_n


def _palm_frame(data: mujoco.MjData, palm: int, body: int) -> np.ndarray:
    """(3,) the body's position in the palm frame (m)."""
    return data.xmat[palm].reshape(3, 3).T @ (data.xpos[body] - data.xpos[palm])


def _grip_contacts(data: mujoco.MjData, hand: np.ndarray, on_target: np.ndarray) -> np.ndarray:
    """Indices of the contacts between ``hand`` and ``on_target`` geoms ((ngeom,) bool masks)."""
    g1, g2 = data.contact.geom1[: data.ncon], data.contact.geom2[: data.ncon]
    return np.flatnonzero((hand[g1] & on_target[g2]) | (hand[g2] & on_target[g1]))


def _grip(model: mujoco.MjModel, data: mujoco.MjData, hand: np.ndarray, on_target: np.ndarray,
          force: np.ndarray) -> tuple[float, float]:
    """(summed normal force, support capacity) of the contacts between ``hand`` and
    ``on_target`` geoms ((ngeom,) bool masks) (N): see ``Hold.capacity_n``."""
    normal = capacity = 0.0
    for c in _grip_contacts(data, hand, on_target):
        mujoco.mj_contactForce(model, data, int(c), force)
        normal += force[0]
        # frame row 0 is the normal, from geom1 toward geom2: the force pushes geom2 along it.
        n_z = data.contact.frame[c, 2] * (1.0 if on_target[data.contact.geom2[c]] else -1.0)
        friction = data.contact.friction[c, 0] * math.sqrt(max(0.0, 1.0 - n_z**2))
        capacity += force[0] * (n_z + friction)
    return normal, capacity


def cone_use(model: mujoco.MjModel, data: mujoco.MjData, hand: np.ndarray,
             on_target: np.ndarray, force: np.ndarray) -> list[float]:
    """Per hand-target contact with a normal force, how much of its (elliptic) friction cone
    its force uses: sqrt(sum_k (f_k / mu_k)^2) / N over its frictional components (sliding,
    torsional, rolling as its condim has them); 1 at the cone's surface."""
    out = []
    for c in _grip_contacts(data, hand, on_target):
        mujoco.mj_contactForce(model, data, int(c), force)
        dim = int(data.contact.dim[c])
        if force[0] <= 1e-9 or dim < 3:
            continue
        mu = data.contact.friction[c, : dim - 1]
        out.append(float(np.linalg.norm(force[1:dim] / mu) / force[0]))
    return out


def measure_hold(model: mujoco.MjModel, data: mujoco.MjData, target: int) -> Hold:
    """Settle, hold and pull the target body ``target`` from the state in ``data`` (modified),
    the controls and mocap targets as they are (the hand holding its grasp)."""
    palm = model.body("palm").id
    dt = model.opt.timestep
    force = np.zeros(6)
    hand = (model.geom_contype & BIT_HAND) != 0
    on_target = model.geom_bodyid == target
    mujoco.mj_forward(model, data)
    first = _palm_frame(data, palm, target)
    for _ in range(round(SETTLE_S / dt)):
        mujoco.mj_step(model, data)
    start = _palm_frame(data, palm, target)
    steps = round(HOLD_S / dt)
    normal = capacity = 0.0
    for _ in range(steps):
        mujoco.mj_step(model, data)
        n, c = _grip(model, data, hand, on_target, force)
        normal += n / steps
        capacity += c / steps
    held = _palm_frame(data, palm, target)
    slip = float(np.linalg.norm(held - start)) * 1000.0 / HOLD_S
    touching = _grip(model, data, hand, on_target, force)[0] > 0
    kept = touching and float(np.linalg.norm(held - first)) * 1000.0 < DROP_MM
    weight = float(model.body_subtreemass[target] * np.linalg.norm(model.opt.gravity))
    pull = 0.0
    while pull < MAX_PULL:
        pull += PULL_RATE * dt
        data.xfrc_applied[target, 2] = -pull
        mujoco.mj_step(model, data)
        if np.linalg.norm(_palm_frame(data, palm, target) - held) * 1000.0 > SLIP_MM:
            break
    slip_grip, slip_capacity = _grip(model, data, hand, on_target, force)
    use = cone_use(model, data, hand, on_target, force) or [math.nan]
    data.xfrc_applied[target] = 0.0
    return Hold(slip, float(normal), float(capacity), weight, min(pull, MAX_PULL),
                float(slip_grip), float(slip_capacity), min(use), max(use), kept)
