"""Compare finished training runs: markdown tables and plots like the paper's Table II and Fig. 4.

A run directory is read as the trainer writes it::

    RUN_DIR/config.json            env.task, env.bin.num_objects, env.context,
                                   env.representation, env.reward.kind, env.robot.kind, run.seed
    RUN_DIR/metrics.csv            one row per PPO iteration: env_steps, wall_time_s,
                                   object_success_rate (the mean over objects; success_rate, over
                                   all ended episodes, in runs logged before it existed)
    RUN_DIR/launches.csv           optional: the code and machine of each start and resume
    RUN_DIR/eval/per_object.csv    optional (``trainer eval``): object, episodes, successes;
                                   ``eval`` or another folder of ``trainer eval --out`` (the
                                   report's ``eval_dir``), with the success criterion in table.md

Runs are grouped by (task, representation, reward kind, robot kind), where the task is ``lift`` or
``binN`` (N objects per bin) and the representation gains ``+ctx`` when the policy also sees the
other objects (``context``): a bin run and a lift run are different groups even with the same
representation. Run directories written before the tasks existed (no ``env.task``) are lift
runs. Runs of one such group whose configs differ in anything else (physics, PPO settings, the
budget; not in the seed or in ``NOT_THE_EXPERIMENT``, and only in fields every one of them
records, or that ``config.ABSENT_MEANS`` fills in) are split further, and the representation names
the difference, e.g. ``bbox [noslip_iterations=5]``; so is a group whose runs differ from most
of the report's runs in such a field, even alone (``pc128 [pointnet_hidden=[16, 32, 64]]`` among
arms of the default encoder). The runs of a group are then taken to
differ by seed, and every table cell is a mean ± std (ddof = 0) over them. Units: env steps are
counted over all parallel environments, wall time is seconds in the data and minutes in tables
and plots, success rates are fractions in [0, 1].

Groups are the arms of the paper's comparison: ordered as its Table I (``PAPER_ORDER``), then
the reward ablations (the paper's are bbox runs with reward kind ``com`` and ``none``), then any
other group in the order the runs came. Labels: ``sq`` (lift), ``bbox (reward com)``, ``bbox (no
shaping)``, ``bin5-bbox``, ``bin5-bbox+ctx``, and ``(robot floating)`` for another robot than the
paper's. The paper's numbers (``PAPER_TABLE_I``, ``PAPER_TABLE_II``) stand beside the arms that
are its own: a lift run, no context, the SDF reward, the UR5e.

The package follows the report's data flow: ``runs`` (a run directory loaded), ``groups`` (runs
into arms), ``paper`` (the paper's numbers), ``ranking`` and ``tables`` (what report.md says),
``plots`` (its PNGs) and ``write`` (``trainer report``). The names below are its public API.
"""

from __future__ import annotations

from trainer.report.groups import (
    GROUP_FIELDS,
    REWARD_NOTES,
    arm_order,
    group_labels,
    group_runs,
    overall_success,
    per_object_rates,
    resolve_group,
    seed_rates,
)
from trainer.report.paper import (
    PAPER_ALL_OBJECTS,
    PAPER_ORDER,
    PAPER_TABLE_I,
    PAPER_TABLE_II,
    paper_overall,
)
from trainer.report.plots import (
    mean_curve,
    plot_curriculum,
    plot_curves,
    plot_gain,
    pyplot,
    save_png,
    success_gain,
)
from trainer.report.ranking import (
    Ranking,
    SeedSpread,
    paper_ranking,
    ranking_text,
    seed_and_arm_spread,
    settled,
    spearman,
)
from trainer.report.runs import (
    NOT_THE_EXPERIMENT,
    GroupKey,
    Run,
    allowing_differences,
    eval_success,
    final_success,
    load_run,
    read_per_object,
    relative_to,
    steps_to_reach,
    training_success,
)
from trainer.report.tables import (
    THRESHOLDS,
    WORST,
    comparable_endings,
    machines_text,
    per_object_table,
    seeds_table,
    summary_table,
    upside_down_table,
    worst_objects_table,
)
from trainer.report.write import report_command, write_report

__all__ = [
    "GROUP_FIELDS", "NOT_THE_EXPERIMENT", "PAPER_ALL_OBJECTS", "PAPER_ORDER", "PAPER_TABLE_I",
    "PAPER_TABLE_II", "REWARD_NOTES", "THRESHOLDS", "WORST", "GroupKey", "Ranking", "Run",
    "SeedSpread", "allowing_differences", "arm_order", "comparable_endings", "eval_success",
    "final_success", "group_labels", "group_runs", "load_run", "machines_text", "mean_curve",
    "overall_success", "paper_overall", "paper_ranking", "per_object_rates", "per_object_table",
    "plot_curriculum", "plot_curves", "plot_gain", "pyplot", "ranking_text", "read_per_object",
    "relative_to", "report_command", "resolve_group", "save_png", "seed_and_arm_spread",
    "seed_rates", "seeds_table", "settled", "spearman", "steps_to_reach", "success_gain",
    "summary_table", "training_success", "upside_down_table", "worst_objects_table",
    "write_report",
]
