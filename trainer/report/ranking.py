"""Our ordering of the representations against the paper's (Spearman's rank correlation), and
what the seeds settle: which arm is above which, and the seeds' spread against the arms'."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from trainer.errors import TrainerError
from trainer.report.groups import group_runs, overall_success, seed_rates
from trainer.report.paper import PAPER_ORDER, paper_overall
from trainer.report.runs import Run


def spearman(xs: Sequence[float], ys: Sequence[float]) -> float:
    """Spearman's rank correlation: the Pearson correlation of the ranks, ties given their
    average rank; NaN for fewer than two pairs or when one side is all ties."""
    if len(xs) != len(ys):
        raise TrainerError(f"spearman needs pairs, got {len(xs)} and {len(ys)} values")
    if len(xs) < 2:
        return math.nan
    from scipy.stats import rankdata

    rx, ry = rankdata(xs), rankdata(ys)
    if np.ptp(rx) == 0 or np.ptp(ry) == 0:
        return math.nan
    return float(np.corrcoef(rx, ry)[0, 1])


@dataclass(frozen=True)
class Ranking:
    """Our ordering of the paper's representations by overall success against the paper's:
    ``arms`` in the paper's order, ``ours`` (Table I's mean over objects, mean over seeds) and
    ``paper`` (``paper_overall`` on the same objects), Spearman's ``rho`` between them, and
    ``basis`` saying which paper value was used."""

    arms: tuple[str, ...]
    ours: tuple[float, ...]
    paper: tuple[float, ...]
    rho: float
    basis: str
    left_out: tuple[str, ...] = ()
    """Representations in several groups (e.g. split by a setting), not ranked."""
    seeds: tuple[tuple[float, ...], ...] = ()
    """Per arm (``arms``' order), the overall success of each evaluated seed (``settled``);
    ``ours`` is their mean."""


def paper_ranking(runs: Sequence[Run]) -> Ranking:
    """The ``Ranking`` over the paper's arms that were evaluated (one group each)."""
    by_arm: dict[str, list[list[Run]]] = {}
    for members in group_runs(runs).values():
        arm = members[0].paper_arm
        if arm is not None and overall_success(members):
            by_arm.setdefault(arm, []).append(members)
    arms = tuple(a for a in PAPER_ORDER if len(by_arm.get(a, ())) == 1)
    ours, paper, bases, seeds = [], [], set(), []
    for arm in arms:
        members = by_arm[arm][0]
        seeds.append(tuple(overall_success(members)))
        ours.append(float(np.mean(seeds[-1])))
        value, basis = paper_overall(arm, set().union(*seed_rates(members)))
        paper.append(value)
        bases.add(basis)
    return Ranking(
        arms=arms, ours=tuple(ours), paper=tuple(paper), rho=spearman(ours, paper),
        basis=" / ".join(sorted(bases)),
        left_out=tuple(a for a in PAPER_ORDER if len(by_arm.get(a, ())) > 1),
        seeds=tuple(seeds),
    )


def _ordering(arms: Sequence[str], values: Sequence[float]) -> str:
    """``bbox 0.810 > sq 0.600 = com 0.600``, best first."""
    order = sorted(range(len(arms)), key=lambda i: -values[i])
    text = f"{arms[order[0]]} {values[order[0]]:.3f}"
    for prev, i in zip(order, order[1:], strict=False):
        relation = "=" if math.isclose(values[i], values[prev]) else ">"
        text += f" {relation} {arms[i]} {values[i]:.3f}"
    return text


def ranking_text(ranking: Ranking) -> str:
    """Sentences on the ranking: rho, both orderings, and the pairs they agree and disagree on."""
    left = (
        f" Left out, being in several groups: {', '.join(ranking.left_out)}."
        if ranking.left_out else ""
    )
    if len(ranking.arms) < 2:
        have = ", ".join(ranking.arms) or "none"
        return (
            "The rank correlation with the paper needs at least two of its representations "
            f"(lift, SDF reward) evaluated; here {have}.{left}"
        )
    rho = "undefined (all tied on one side)" if math.isnan(ranking.rho) else f"{ranking.rho:+.2f}"
    agree, disagree, tied, settled_disagree = [], [], [], []
    for i in range(len(ranking.arms)):
        for j in range(i + 1, len(ranking.arms)):
            a, b = ranking.arms[i], ranking.arms[j]
            ours = ranking.ours[i] - ranking.ours[j]
            paper = ranking.paper[i] - ranking.paper[j]
            ours_tie = math.isclose(ranking.ours[i], ranking.ours[j])
            paper_tie = math.isclose(ranking.paper[i], ranking.paper[j])
            if ours_tie or paper_tie:
                side = "both" if ours_tie and paper_tie else "ours" if ours_tie else "the paper"
                tied.append(f"{a} = {b} ({side})")
            elif (ours > 0) == (paper > 0):
                agree.append(f"{a} > {b}" if ours > 0 else f"{b} > {a}")
            else:
                disagree.append(f"{a} > {b}" if ours > 0 else f"{b} > {a}")
                high, low = (i, j) if ours > 0 else (j, i)
                if settled(ranking.seeds[high], ranking.seeds[low]):
                    settled_disagree.append(disagree[-1])
    pairs = len(ranking.arms) * (len(ranking.arms) - 1) // 2
    text = (
        f"Spearman's rank correlation of our ordering of the {len(ranking.arms)} representations "
        f"by overall success (Table I's mean over objects) with the paper's ({ranking.basis}): "
        f"ρ = {rho}. Ours: {_ordering(ranking.arms, ranking.ours)}; the "
        f"paper's: {_ordering(ranking.arms, ranking.paper)}. "
    )
    text += f"Of the {pairs} pairs, the orderings agree on {len(agree)}"
    text += f" ({', '.join(agree)})" if agree else ""
    text += f" and disagree on {len(disagree)}"
    text += f" (ours {', '.join(disagree)}; the paper's the reverse)" if disagree else ""
    text += f"; tied: {', '.join(tied)}." if tied else "."
    if disagree:
        text += (
            f" Of the pairs that disagree, our seeds settle {len(settled_disagree)}"
            + (f" ({', '.join(settled_disagree)})" if settled_disagree else "")
            + " (every seed of the one above every seed of the other, two seeds or more "
            "each); the others are inside the seed spread or rest on one seed."
        )
    return text + left


def settled(higher: Sequence[float], lower: Sequence[float]) -> bool:
    """Whether the seeds settle that one arm is above another: both evaluated with two seeds or
    more, and every seed of ``higher`` above every seed of ``lower`` (overall success)."""
    return len(higher) >= 2 and len(lower) >= 2 and min(higher) > max(lower)


class SeedSpread(NamedTuple):
    """How much the seeds of one arm differ, against how much the arms do (overall success)."""

    within: float
    """Pooled standard deviation of the seeds within an arm (ddof 1)."""
    between: float
    """Standard deviation of the arms' means (ddof 1)."""
    alike: float
    """What ``between`` would be were the arms alike: ``within`` / sqrt(seeds per arm, their
    harmonic mean)."""
    arms: int


def seed_and_arm_spread(arms: Sequence[Sequence[float]]) -> SeedSpread | None:
    """The ``SeedSpread`` over the arms (each its seeds' overall success) with two seeds or
    more; None for fewer than two such arms."""
    kept = [np.asarray(a, dtype=np.float64) for a in arms if len(a) >= 2]
    if len(kept) < 2:
        return None
    dof = sum(a.size - 1 for a in kept)
    within = math.sqrt(sum(float(((a - a.mean()) ** 2).sum()) for a in kept) / dof)
    between = float(np.std([a.mean() for a in kept], ddof=1))
    alike = within * math.sqrt(sum(1 / a.size for a in kept) / len(kept))
    return SeedSpread(within, between, alike, len(kept))
