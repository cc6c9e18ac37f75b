"""The report's PNGs: learning curves with seed bands, the lift curriculum, the per-object gain
of one arm over another (the paper's Fig. 4). matplotlib is imported on the first plot."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any, Literal

import numpy as np

from geomgrasp.files import atomic_path
from trainer.errors import TrainerError
from trainer.report.groups import (
    REWARD_NOTES,
    arm_order,
    group_labels,
    group_runs,
    per_object_rates,
    resolve_group,
)
from trainer.report.runs import Run

CURVE_POINTS = 200
"""Points of the common env-step (or minute) grid the seeds' curves are interpolated onto."""


def pyplot() -> Any:
    # Imported on first plot so that importing the module (e.g. from the CLI) stays cheap, and
    # Agg so that plotting works on a headless training machine.
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_png(fig: Any, out_png: Path) -> Path:
    out_png = Path(out_png)
    try:
        with atomic_path(out_png) as tmp:
            # The temporary name has no .png suffix to infer the format from.
            fig.savefig(tmp, format="png", dpi=120, bbox_inches="tight")
    finally:
        pyplot().close(fig)
    return out_png


def mean_curve(
    members: Sequence[Run],
    x: Literal["env_steps", "wall_time_s"] = "env_steps",
    points: int = CURVE_POINTS,
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """(x grid, mean, std over seeds) of the success curves of one group, or None if no seed
    has a success rate yet.

    Each seed's curve (NaN rows dropped) is linearly interpolated onto a common grid spanning the
    x range every seed covers, so nothing is extrapolated; x is in the units of the column.
    """
    curves = []
    for run in members:
        xs = getattr(run, x)
        valid = np.isfinite(run.success_rate) & np.isfinite(xs)
        if valid.any():
            curves.append((xs[valid], run.success_rate[valid]))
    if not curves:
        return None
    lo = max(float(xs[0]) for xs, _ in curves)
    hi = min(float(xs[-1]) for xs, _ in curves)
    grid = np.linspace(lo, hi, points) if hi > lo else np.array([hi])
    values = np.stack([np.interp(grid, xs, ys) for xs, ys in curves])
    return grid, values.mean(axis=0), values.std(axis=0, ddof=0)


def _style(run: Run, others: int) -> dict[str, str]:
    """Line colour and style of a group: each of the paper's representations has its own colour
    in every plot (C0..C6 in ``PAPER_ORDER``), its ablations dashed, other groups (the
    ``others``-th of them) C7 on, dotted."""
    tier, index = arm_order(run)
    if tier > len(REWARD_NOTES) + 1:
        return {"color": f"C{(7 + others) % 10}", "linestyle": ":"}
    return {"color": f"C{index}", "linestyle": "-" if tier == 0 else "--"}


def plot_curves(
    runs: Sequence[Run],
    out_png: str | Path,
    x: Literal["env_steps", "wall_time_s"] = "env_steps",
    thresholds: Sequence[float] = (),
) -> Path:
    """Success rate vs env steps (M) or vs wall time (min): per group, the mean over seeds with a
    ± std band (see ``mean_curve``; with two seeds the band is their min-max), and a grey dashed
    line at each of ``thresholds``. Writes ``out_png`` atomically and returns it."""
    if x not in ("env_steps", "wall_time_s"):
        raise TrainerError(f"x must be env_steps or wall_time_s, got {x!r}")
    scale, xlabel = (1e6, "env steps (M)") if x == "env_steps" else (60.0, "wall time (min)")
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7, 4.5))
    labels = group_labels(runs)
    for threshold in thresholds:
        ax.axhline(threshold, color="0.5", linewidth=0.8, linestyle="--")
    others = 0
    for key, members in group_runs(runs).items():
        style = _style(members[0], others)
        others += style["linestyle"] == ":"
        curve = mean_curve(members, x)
        if curve is None:
            continue
        grid, mean, std = curve
        ax.plot(
            grid / scale,
            mean,
            marker="o" if grid.size == 1 else None,
            label=f"{labels[key]} ({len(members)} seed{'' if len(members) == 1 else 's'})",
            **style,
        )
        # A rate cannot leave [0, 1] even where mean ± std does.
        band = np.clip(mean - std, 0.0, 1.0), np.clip(mean + std, 0.0, 1.0)
        ax.fill_between(grid / scale, *band, color=style["color"], alpha=0.2)
    ax.set_xlabel(xlabel)
    ax.set_ylabel("success rate")
    ax.set_ylim(0.0, 1.02)
    ax.grid(alpha=0.3)
    if ax.get_legend_handles_labels()[0]:
        ax.legend(loc="best", fontsize="small")
    return save_png(fig, Path(out_png))


def plot_curriculum(runs: Sequence[Run], out_png: str | Path) -> Path:
    """For the runs with a lift curriculum: the training lift target (m) and the success rate at
    it vs env steps (M), one colour per run. Writes ``out_png`` atomically and returns it."""
    plt = pyplot()
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(7, 6), sharex=True)
    labels = group_labels(runs)
    for key, members in group_runs(runs).items():
        for run in members:
            if not run.has_curriculum:
                continue
            assert run.h_bar is not None and run.target_success_rate is not None
            label = f"{labels[key]} s{run.seed}"
            line = top.plot(run.env_steps / 1e6, run.h_bar, label=label)[0]
            bottom.plot(run.env_steps / 1e6, run.target_success_rate, color=line.get_color())
    top.set_ylabel("lift target h_bar (m)")
    top.grid(alpha=0.3)
    top.legend(loc="lower right")
    bottom.set_ylabel("success rate at the target")
    bottom.set_ylim(0.0, 1.02)
    bottom.set_xlabel("env steps (M)")
    bottom.grid(alpha=0.3)
    return save_png(fig, Path(out_png))


def success_gain(runs: Sequence[Run], base: str, other: str) -> list[tuple[str, float]]:
    """Per object evaluated in both groups: mean success of ``other`` minus that of ``base``
    (fractions), largest gain first. Groups are named as in ``resolve_group``."""
    groups = group_runs(runs)
    base_rates = per_object_rates(groups[resolve_group(runs, base)])
    other_rates = per_object_rates(groups[resolve_group(runs, other)])
    for name, rates in ((base, base_rates), (other, other_rates)):
        if not rates:
            raise TrainerError(f"group {name!r} has no eval/per_object.csv; run trainer eval on it")
    common = sorted(base_rates.keys() & other_rates.keys())
    if not common:
        raise TrainerError(f"groups {base!r} and {other!r} were evaluated on no common object")
    gains = [(name, other_rates[name] - base_rates[name]) for name in common]
    return sorted(gains, key=lambda item: (-item[1], item[0]))


def plot_gain(runs: Sequence[Run], base: str, other: str, out_png: str | Path) -> Path:
    """Bar chart of ``success_gain`` (like the paper's Fig. 4), objects sorted by gain.
    Writes ``out_png`` atomically and returns it."""
    gains = success_gain(runs, base, other)
    names = [name for name, _ in gains]
    values = np.array([gain for _, gain in gains])
    plt = pyplot()
    # Wide enough that rotated object names do not overlap with the full YCB set.
    fig, ax = plt.subplots(figsize=(max(6.0, 0.25 * len(names) + 2.0), 4.5))
    colors = np.where(values >= 0, "tab:green", "tab:red")
    ax.bar(np.arange(len(names)), values, color=colors)
    ax.axhline(0.0, color="k", linewidth=0.8)
    ax.set_xticks(np.arange(len(names)), names, rotation=90, fontsize=7)
    ax.set_xlim(-0.6, len(names) - 0.4)
    ax.set_ylabel(f"success gain ({other} − {base})")
    ax.set_title(f"per-object success gain of {other} over {base} (mean {values.mean():+.2f})")
    ax.grid(axis="y", alpha=0.3)
    return save_png(fig, Path(out_png))
