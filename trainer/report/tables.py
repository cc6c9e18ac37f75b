"""The report's markdown tables: Table I's layout (``per_object_table``), Table II's
(``summary_table``), the seeds (``seeds_table``), the objects that fail upside down, the worst
objects with how their episodes ended, and the machines that trained and evaluated the runs."""

from __future__ import annotations

import math
import re
from collections import Counter
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from trainer.errors import TrainerError
from trainer.report.groups import group_labels, group_runs, overall_success, seed_rates
from trainer.report.paper import PAPER_ALL_OBJECTS, PAPER_TABLE_I, PAPER_TABLE_II, paper_overall
from trainer.report.ranking import seed_and_arm_spread, settled
from trainer.report.runs import Run, final_success, relative_to, steps_to_reach

THRESHOLDS = (0.9, 0.95)
"""Table II's success rates (the paper's); ``trainer report --thresholds`` picks others."""
DASH = "—"
"""What a table cell holds where there is no value."""
WORST = 10
"""Objects listed per arm in the report's worst-objects table (the paper's all-78 layout names
its worst ten)."""


def machines_text(runs: Sequence[Run], out_dir: Path) -> list[str]:
    """Per run, the machines (and code) that trained which of its iterations (``launches.csv``),
    and whether the arms' minutes and env steps/s compare: only where one machine trained them
    all."""
    lines, seen = [], set()
    for r in runs:
        last = len(r.env_steps)
        spans = []
        if not r.machines or r.machines[0][0] > 1:
            end = r.machines[0][0] - 1 if r.machines else last
            spans.append(f"iterations 1-{end}: not recorded")
            seen.add(None)
        for k, (first, words, code) in enumerate(r.machines):
            end = r.machines[k + 1][0] - 1 if k + 1 < len(r.machines) else last
            if first <= end:
                spans.append(f"iterations {first}-{end}: {words} (code {code})")
            seen.add(re.sub(r", nice -?[0-9]+", "", words))  # (the same machine, niced or not)
        lines.append(f"- `{relative_to(r.path, out_dir)}`: " + "; ".join(spans))
    if seen == {next(iter(seen))} and None not in seen:
        verdict = "One machine trained every run: minutes and env steps/s compare across arms."
    else:
        verdict = ("**Minutes and env steps/s compare only between runs on one machine**, and "
                   "these runs were trained on more than one or on machines not recorded "
                   "(`launches.csv` exists since 2026-11-30): compare the arms by env steps.")
    return [verdict, "", *lines, "", *_evaluation_machines(runs, out_dir)]


def _evaluation_machines(runs: Sequence[Run], out_dir: Path) -> list[str]:
    """Which CPU models evaluated the runs (table.md's last line): one line where one did them
    all, else each run's, since the same checkpoint and seed end some episodes differently on
    another CPU model."""
    evaluated = [r for r in runs if r.per_object is not None]
    if not evaluated:
        return []
    cpus = {r.eval_machine[0] if r.eval_machine else None for r in evaluated}
    if len(cpus) == 1 and None not in cpus:
        codes = sorted({r.eval_machine[1] for r in evaluated if r.eval_machine})
        return [f"One CPU model evaluated every run: {next(iter(cpus))} (code "
                f"{', '.join(codes)}).", ""]
    return [
        "**The evaluations were made on more than one CPU model or on one not recorded** "
        "(table.md's last line, since 2026-11-30): the same checkpoint and seed end some "
        "contact-rich episodes differently on another CPU model (up to 5 of 50 per object, "
        "0.016 overall: results/cpu-comparison-2026-11-29/), as another evaluation seed would.",
        "",
        *(f"- `{relative_to(r.path, out_dir)}`: "
          + (f"{r.eval_machine[0]} (code {r.eval_machine[1]})" if r.eval_machine
             else "not recorded") for r in evaluated),
        "",
    ]


def upside_down_table(runs: Sequence[Run]) -> str:
    """The objects that fail when they start upside down (the plate: a dome no grasp of this
    hand lifts): those whose upside-down episodes, pooled over every evaluated run, succeed at
    less than half the rate of their face-up ones. One row per such object, one column per arm
    with the record: its success over all resets and over the face-up ones (mean over seeds),
    and the face-up share of the episodes. Empty where no object qualifies."""
    recorded = [r for r in runs if r.by_start]
    pooled: dict[str, list[int]] = {}
    for r in recorded:
        for name, counts in r.by_start.items():  # type: ignore[union-attr]
            pooled[name] = [a + b for a, b in zip(pooled.get(name, [0] * 4), counts, strict=True)]
    failing = sorted(
        name for name, (up, up_held, down, down_held) in pooled.items()
        if up and down and up_held and down_held / down < 0.5 * up_held / up
    )
    if not failing:
        return ""
    labels = group_labels(runs)
    groups = {k: [r for r in m if r.by_start] for k, m in group_runs(runs).items()}
    groups = {k: m for k, m in groups.items() if m}
    lines = ["| object | " + " | ".join(labels[k] for k in groups) + " |",
             "|---|" + "---:|" * len(groups)]
    for name in failing:
        cells = [name]
        for members in groups.values():
            rows = [r.by_start[name] for r in members if name in r.by_start]  # type: ignore[index]
            if not rows:
                cells.append(DASH)
                continue
            every = np.mean([(b + d) / max(1, a + c) for a, b, c, d in rows])
            up = [b / a for a, b, _, _ in rows if a]
            share = sum(a for a, _, _, _ in rows) / max(1, sum(a + c for a, _, c, _ in rows))
            face_up = f"{np.mean(up):.2f}" if up else DASH
            cells.append(f"{every:.2f} / {face_up} ({share:.0%} face up)")
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def mean_std(values: Sequence[float], fmt: str = ".2f") -> str:
    """``mean ± std`` (ddof 0) over the finite values, the mean alone for one, "—" for none."""
    finite = np.array([v for v in values if math.isfinite(v)], dtype=np.float64)
    if finite.size == 0:
        return DASH
    if finite.size == 1:
        return format(finite[0], fmt)
    return f"{format(finite.mean(), fmt)} ± {format(finite.std(ddof=0), fmt)}"


def _percent(threshold: float) -> str:
    return f"{threshold * 100:g} %"


def _paper_note(value: float | None, fmt: str) -> str:
    return f" ({DASH if value is None else format(value, fmt)})"


def summary_table(
    runs: Sequence[Run], thresholds: Sequence[float] = THRESHOLDS, last_fraction: float = 0.1
) -> str:
    """Markdown table in the layout of the paper's Table II, one line per group (arm, in the
    paper's order): seeds, final success (``final_success``), env steps per second of training
    wall time, and per threshold how many seeds reached it, and the env steps (M) and minutes to
    it, mean ± std over the seeds that did ("not reached" where none did). In brackets beside
    steps and minutes the paper's Table II mean, for its arms at its thresholds (90 %, 95 %)."""
    header = ["arm", "seeds", "final success", "env steps/s"]
    for threshold in thresholds:
        p = _percent(threshold)
        header += [f"reached {p}", f"steps to {p} (M)", f"minutes to {p}"]
    lines = ["| " + " | ".join(header) + " |", "|---|" + "---:|" * (len(header) - 1)]
    labels = group_labels(runs)
    for key, members in group_runs(runs).items():
        arm = members[0].paper_arm
        cells = [labels[key], str(len(members))]
        cells.append(mean_std([final_success(r, last_fraction) for r in members]))
        cells.append(mean_std([r.steps_per_second for r in members], ".0f"))
        for threshold in thresholds:
            reached = [steps_to_reach(r, threshold) for r in members]
            hits = sum(math.isfinite(steps) for steps, _ in reached)
            paper = PAPER_TABLE_II.get(arm or "", {}).get(round(threshold, 6))
            steps = mean_std([s / 1e6 for s, _ in reached]) if hits else "not reached"
            minutes = mean_std([t / 60 for _, t in reached], ".1f") if hits else "not reached"
            if paper is not None:
                steps += _paper_note(paper[0][0], "g")
                minutes += _paper_note(paper[1][0], "g")
            cells += [f"{hits}/{len(members)}", steps, minutes]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def per_object_table(runs: Sequence[Run]) -> str:
    """Markdown table in the layout of the paper's Table I: one row per object, one column per
    group with eval data (arms in the paper's order), each cell the mean ± std over that group's
    evaluated seeds of the object's success rate, then in brackets the paper's Table I value
    ("—" where it has none). "†" marks a cell some evaluated seeds lack the object in. Then
    the overall row (per seed the mean over its objects, mean ± std over seeds, beside the
    paper's ``paper_overall``), the paper's all-78-objects row, and the seeds evaluated."""
    labels = group_labels(runs)
    groups = {
        key: members
        for key, members in group_runs(runs).items()
        if any(r.per_object is not None for r in members)
    }
    if not groups:
        raise TrainerError(
            "no run has an evaluation (per_object.csv); run trainer eval on the runs first"
        )
    seeds = {key: seed_rates(members) for key, members in groups.items()}
    arms = {key: members[0].paper_arm for key, members in groups.items()}
    objects = sorted(set().union(*(rates for per_seed in seeds.values() for rates in per_seed)))
    lines = [
        "| object | " + " | ".join(labels[key] for key in groups) + " |",
        "|---|" + "---:|" * len(groups),
    ]
    for name in objects:
        cells = []
        for key, per_seed in seeds.items():
            values = [rates[name] for rates in per_seed if name in rates]
            paper = PAPER_TABLE_I.get(name, {}).get(arms[key] or "")
            mark = "†" if values and len(values) < len(per_seed) else ""
            cells.append(mean_std(values) + mark + _paper_note(paper[0] if paper else None, ".2f"))
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    overall = []
    for key, members in groups.items():
        arm = arms[key]
        columns = set().union(*seeds[key])
        paper = paper_overall(arm, columns)[0] if arm else None
        overall.append(f"**{mean_std(overall_success(members))}**" + _paper_note(paper, ".2f"))
    lines.append("| **mean over objects** | " + " | ".join(overall) + " |")
    every = [
        _paper_note(PAPER_ALL_OBJECTS[a][0] if a else None, ".2f").strip() for a in arms.values()
    ]
    lines.append("| all 78 YCB objects (paper) | " + " | ".join(every) + " |")
    lines.append("| seeds evaluated | " + " | ".join(str(len(s)) for s in seeds.values()) + " |")
    return "\n".join(lines) + "\n"


def seeds_table(runs: Sequence[Run]) -> str:
    """Per evaluated arm, best mean first: its overall success per seed, the arms the seeds
    settle it above (``settled``), and those whose seeds overlap with its own (a difference
    inside the seed spread; an arm with one seed is in neither column); then the seeds' spread
    against the arms' (``seed_and_arm_spread``)."""
    labels = group_labels(runs)
    overall = {labels[k]: overall_success(m) for k, m in group_runs(runs).items()}
    overall = {label: rates for label, rates in overall.items() if rates}
    order = sorted(overall, key=lambda label: -float(np.mean(overall[label])))
    lines = ["| arm | seeds | overall per seed | settled above | seeds overlap with |",
             "|---|---:|---|---|---|"]
    for label in order:
        mine = overall[label]
        above = [o for o in order if o != label and settled(mine, overall[o])]
        overlap = [
            o for o in order
            if o != label and not settled(mine, overall[o]) and not settled(overall[o], mine)
            and len(mine) >= 2 and len(overall[o]) >= 2
        ]
        per_seed = ", ".join(f"{rate:.3f}" for rate in mine)
        lines.append(f"| {label} | {len(mine)} | {per_seed} | {', '.join(above) or DASH} | "
                     f"{', '.join(overlap) or DASH} |")
    spread = seed_and_arm_spread(list(overall.values()))
    if spread is not None:
        lines += ["", f"Over the {spread.arms} arms with two seeds or more: the seeds of one arm "
                  f"spread by {spread.within:.3f} (pooled std, ddof 1), the arms' means by "
                  f"{spread.between:.3f} (std of the means, ddof 1); were the arms alike, "
                  f"their means would spread by about {spread.alike:.3f}."]
    return "\n".join(lines) + "\n"


def comparable_endings(endings: Sequence[Mapping[str, int]]) -> list[Counter[str]]:
    """Episodes by ending (``trainer eval``'s names, spaces and all), one mapping per
    evaluation, counted alike: an evaluation from before 2026-11-30 counted never reached as
    never lifted, so where any lacks never reached, every one's is folded into never lifted."""
    fold = not all("never reached" in by for by in endings)
    out = []
    for by_ending in endings:
        by = Counter(by_ending)
        if fold and "never reached" in by:
            by["never lifted"] += by.pop("never reached")
        out.append(by)
    return out


def worst_objects_table(runs: Sequence[Run], count: int = WORST) -> str:
    """Per arm whose evaluations recorded how episodes ended: its ``count`` objects of lowest
    success (episodes pooled over the seeds), each with its episodes by ending, worst first.
    The empty string when no arm has them."""
    labels = group_labels(runs)
    blocks = []
    for key, members in group_runs(runs).items():
        ended = [r for r in members if r.endings is not None and r.per_object is not None]
        if not ended:
            continue
        names = [name for r in ended for name in r.endings]
        counted = comparable_endings([by for r in ended for by in r.endings.values()])
        totals: dict[str, Counter[str]] = {}
        for name, by in zip(names, counted, strict=True):
            totals.setdefault(name, Counter()).update(by)
        endings = list(dict.fromkeys(e for by in totals.values() for e in by))
        episodes = {name: sum(by.values()) for name, by in totals.items()}
        rate = {name: by.get("success", 0) / max(1, episodes[name])
                for name, by in totals.items()}
        worst = sorted(totals, key=lambda name: (rate[name], name))[:count]
        seeds = f"{len(ended)} seed{'s' * (len(ended) != 1)}"
        blocks += [f"**{labels[key]}** ({seeds}, {len(totals)} objects):", "",
                   "| object | episodes | " + " | ".join(endings) + " |",
                   "|---|---:|" + "---:|" * len(endings)]
        blocks += [f"| {name} | {episodes[name]} | "
                   + " | ".join(str(totals[name].get(e, 0)) for e in endings) + " |"
                   for name in worst]
        blocks.append("")
    return "\n".join(blocks)
