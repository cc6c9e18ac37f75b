"""The reward's named terms and the observation's keys, each declared once: the task sums and
logs the terms from ``reward_terms``, and its specs (``trainer.tasks.spec``) come from the same
tables.

Reward. r = sum over the terms of their weighted values, in the table's order; each term is
logged as ``reward_<name>`` (E, 1). The paper's reward and its two ablations are configurations
of one table (``[reward]``: weights c1, c2, c3; ``kind`` picks the contact term's variant):

| term    | weight | value (E,)                                          |
|---------|--------|-----------------------------------------------------|
| lift    | c1     | c1 / (abs(h_bar - lift) + eps_h)                     |
| success | c2     | c2 * 1(success)                                     |
| contact | c3     | sdf: c3 / (sum of fingertip distances >= 0 + eps_sdf) |
|         |        | com: c3 / (sum of fingertip-COM distances + eps_sdf)  |
|         |        | none: 0                                             |
|         |        | sdf-thumb: c3 / (thumb's + nearest finger's distance >= 0 + eps_sdf) |

A term is paid per step (its value, the paper's) or, marked ``difference`` (``[reward]
contact_shaping = "difference"`` for the contact term; not the paper's), as its change since the
previous step: a potential-based shaping with discount 1 (``paid_terms``; the task keeps each
such term's previous value in its state as ``<name>_prev``).

A term's function receives its weight rather than returning a value to be multiplied by it:
the paper's inverse-distance terms divide the weight (``c1 / d``), and ``c1 * (1 / d)`` would
round differently and change the runs.

To add a term: write its function here, add it to ``reward_terms`` (and its weight to
``trainer.config.RewardConfig``); the reward, its ``reward_<name>`` output and its spec follow.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import NamedTuple

import torch

from trainer.config import EnvConfig, RewardConfig
from trainer.representations import representation_shape


class StepQuantities(NamedTuple):
    """What the reward terms may use at one step, for E envs (about the episode's target)."""

    lift: torch.Tensor
    """(E,) m, the target's height above its height at the episode's start."""
    h_bar: torch.Tensor
    """(E,) m, the lift target of each env's target object."""
    success: torch.Tensor
    """(E,) bool, the target lifted by h_bar while held (``trainer.tasks.outputs.termination``)."""
    tips: torch.Tensor
    """(E, 5, 3) m, the fingertip pads in the world."""
    tip_distance: torch.Tensor
    """(E, 5) m, their signed distances to the target's surface (zeros without an SDF)."""
    obj_pos: torch.Tensor
    """(E, 3) m, the target's centre of mass in the world."""


TermFunction = Callable[[float, StepQuantities, RewardConfig], torch.Tensor]
"""(weight, quantities, reward config) -> the weighted term (E,)."""


def lift_closeness(weight: float, q: StepQuantities, r: RewardConfig) -> torch.Tensor:
    """Grows as the lift nears h_bar: weight / (|h_bar - lift| + eps_h)."""
    return weight / ((q.h_bar - q.lift).abs() + r.eps_h)


def success_bonus(weight: float, q: StepQuantities, r: RewardConfig) -> torch.Tensor:
    """weight at a success step, else 0."""
    return weight * q.success.float()


def fingertip_surface_closeness(
    weight: float, q: StepQuantities, r: RewardConfig
) -> torch.Tensor:
    """weight / (sum of the fingertips' distances to the target's surface + eps_sdf); a
    fingertip pressed into the surface is in contact: its distance counts as 0, not < 0."""
    return weight / (q.tip_distance.clamp_min(0.0).sum(-1) + r.eps_sdf)


def fingertip_com_closeness(weight: float, q: StepQuantities, r: RewardConfig) -> torch.Tensor:
    """weight / (sum of the fingertips' distances to the target's centre of mass + eps_sdf)
    (the paper's ablation without the SDF)."""
    return weight / ((q.tips - q.obj_pos[:, None, :]).norm(dim=-1).sum(-1) + r.eps_sdf)


def thumb_finger_surface_closeness(
    weight: float, q: StepQuantities, r: RewardConfig
) -> torch.Tensor:
    """weight / (the thumb pad's distance to the target's surface + the nearest finger pad's +
    eps_sdf), distances >= 0 as in ``fingertip_surface_closeness`` (pads in ``FINGERTIPS``
    order: the thumb first). Not the paper's: the closeness of the SIH's smallest grasp, a
    thumb against one finger, which the five-pad sum pays less than resting the fingers on a
    flat object's top face."""
    d = q.tip_distance.clamp_min(0.0)
    return weight / (d[:, 0] + d[:, 1:].amin(-1) + r.eps_sdf)


def zero(weight: float, q: StepQuantities, r: RewardConfig) -> torch.Tensor:
    """No term (the paper's ablation without a contact term): 0 whatever the weight."""
    return torch.zeros_like(q.lift)


CONTACT_VARIANTS: dict[str, TermFunction] = {
    "sdf": fingertip_surface_closeness,
    "com": fingertip_com_closeness,
    "none": zero,
    "sdf-thumb": thumb_finger_surface_closeness,
}
"""``reward.kind`` -> the contact term (``trainer.config.REWARDS`` lists the same names)."""


class RewardTerm(NamedTuple):
    """One weighted term of the reward."""

    weight: float
    function: TermFunction
    difference: bool = False
    """Paid as its change since the previous step instead of its value (``paid_terms``)."""


def reward_terms(r: RewardConfig) -> dict[str, RewardTerm]:
    """The reward's terms by name, in the order they are summed (lift + success + contact,
    the order every recorded run used)."""
    return {
        "lift": RewardTerm(r.c1, lift_closeness),
        "success": RewardTerm(r.c2, success_bonus),
        "contact": RewardTerm(r.c3, CONTACT_VARIANTS[r.kind],
                              difference=r.contact_shaping == "difference"),
    }


def previous_key(name: str) -> str:
    """The task-state key (E,) holding difference term ``name``'s value at the previous step
    (NaN right after a reset)."""
    return f"{name}_prev"


def paid_terms(
    terms: Mapping[str, RewardTerm], values: Mapping[str, torch.Tensor],
    previous: Mapping[str, torch.Tensor],
) -> tuple[dict[str, torch.Tensor], dict[str, torch.Tensor]]:
    """What each term pays this step, from its value now (``values``, ``evaluate_terms``): its
    value, or for a ``difference`` term its change since ``previous[previous_key(name)]`` (E,)
    (NaN: the episode just started; it pays 0). Returns (paid, the new previous values)."""
    paid, now = dict(values), {}
    for name, term in terms.items():
        if term.difference:
            value, prev = values[name], previous[previous_key(name)]
            paid[name] = value - torch.where(prev.isnan(), value, prev)
            now[previous_key(name)] = value
    return paid, now


def evaluate_terms(
    terms: Mapping[str, RewardTerm], q: StepQuantities, r: RewardConfig
) -> dict[str, torch.Tensor]:
    """Every term's weighted value (E,), by name, in the table's order."""
    return {name: term.function(term.weight, q, r) for name, term in terms.items()}


def total_reward(values: Mapping[str, torch.Tensor]) -> torch.Tensor:
    """(E,) the sum of the terms, added left to right in their order ((a + b) + c), with
    NaN and infinities (a blown-up simulation) set to 0."""
    total: torch.Tensor | None = None
    for value in values.values():
        total = value if total is None else total + value
    assert total is not None, "the reward has no terms"
    return torch.nan_to_num(total, nan=0.0, posinf=0.0, neginf=0.0)


def reward_output_key(name: str) -> str:
    """The output (E, 1) that logs term ``name``."""
    return f"reward_{name}"


# --- observations -------------------------------------------------------------------------------
PROPRIO_DIM = 20
"""Palm keypoint position (3), palm orientation (6-d), hand joints (11)."""
FINGERTIPS_DIM = 15
"""``observe_fingertips``: the 5 fingertip pad positions (3 each), after the 20."""
HAND_TARGETS_DIM = 5
"""``observe_hand_targets``: the 5 servo targets, last."""


def proprio_size(cfg: EnvConfig) -> int:
    """Values in ``proprio``: ``PROPRIO_DIM``, plus ``FINGERTIPS_DIM`` and ``HAND_TARGETS_DIM``
    where observed."""
    return (PROPRIO_DIM + (FINGERTIPS_DIM if cfg.observe_fingertips else 0)
            + (HAND_TARGETS_DIM if cfg.observe_hand_targets else 0))
CONTEXT_DIM = 10
"""One other object's box: centre (3), quaternion (4), full extents (3)."""


def context_size(cfg: EnvConfig) -> int:
    """Other objects in the context (0 without context)."""
    return cfg.bin.num_objects - 1 if cfg.context == "bbox" else 0


@dataclass(frozen=True)
class ObservationTerm:
    """One observation key: its per-env shape and dtype (a bool key is a mask)."""

    name: str
    shape: Callable[[EnvConfig], tuple[int, ...]]
    dtype: torch.dtype = torch.float32
    present: Callable[[EnvConfig], bool] = lambda cfg: True


OBSERVATION_TERMS: tuple[ObservationTerm, ...] = (
    ObservationTerm("proprio", lambda cfg: (proprio_size(cfg),)),
    # The target's representation (trainer.representations), (D,) or (N, 3).
    ObservationTerm("object", lambda cfg: representation_shape(cfg.representation)),
    # The other objects' boxes and which of them are still on the table (bin task, context).
    ObservationTerm(
        "context", lambda cfg: (context_size(cfg), CONTEXT_DIM),
        present=lambda cfg: context_size(cfg) > 0,
    ),
    ObservationTerm(
        "context_mask", lambda cfg: (context_size(cfg),), torch.bool,
        present=lambda cfg: context_size(cfg) > 0,
    ),
)
"""What the policy sees, in the order of the observation spec. ``GraspTask._get_obs`` computes
proprio and object, a task's ``_extra_obs`` the rest."""


def observation_terms(cfg: EnvConfig) -> tuple[ObservationTerm, ...]:
    """The observation keys of the task ``cfg`` describes."""
    return tuple(term for term in OBSERVATION_TERMS if term.present(cfg))
