"""trainer.report on synthetic run directories whose thresholds and means are worked out by hand.

Rows are iterations i = 1, 2, ...; env_steps = 100 000 i, wall_time_s = (seconds per iteration) i.
"""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from tests.tiny_runs import trainer_main
from trainer import report
from trainer.errors import TrainerError

NAN = math.nan

# (representation, seed, seconds per iteration, success rates, per-object eval or None)
RUNS = [
    # 0.9 first at i=5 (500k, 150 s); 0.95 at i=7 (700k, 210 s)
    (
        "sq",
        0,
        30,
        [NAN, 0.2, 0.5, 0.8, 0.91, 0.93, 0.96, 0.97, 0.97, 0.98],
        {"cube": (10, 10), "mug": (10, 8), "plate": (10, 5)},
    ),
    # 0.9 reached with equality at i=6 (600k, 204 s); 0.95 likewise at i=8 (800k, 272 s)
    (
        "sq",
        1,
        34,
        [NAN, NAN, 0.4, 0.7, 0.85, 0.9, 0.94, 0.95, 0.96, 0.96],
        {"cube": (10, 9), "mug": (10, 6), "plate": (10, 3)},
    ),
    # 0.9 at i=6 (600k, 216 s), after a NaN row; never 0.95
    (
        "sq",
        2,
        36,
        [0.1, 0.3, 0.6, 0.88, NAN, 0.92, 0.93, 0.94, 0.93, 0.94],
        {"cube": (10, 10), "mug": (10, 7), "plate": (10, 4)},
    ),
    # 0.9 at i=9 (900k, 270 s); never 0.95
    (
        "com",
        0,
        30,
        [0.1, 0.2, 0.3, 0.5, 0.6, 0.7, 0.8, 0.85, 0.92, 0.89],
        {"cube": (10, 10), "mug": (10, 2), "plate": (5, 1), "bowl": (4, 3)},
    ),
    # not evaluated; never 0.9; the last 10 % (2 of 20 rows) average 0.6
    ("com", 1, 30, [0.0] * 17 + [0.1, 0.5, 0.7], None),
]


def _write_run(
    root: Path,
    representation: str,
    seed: int,
    seconds: float,
    rates: list[float],
    per_object: dict[str, tuple[int, int]] | None,
    task: dict | None = None,
    name: str | None = None,
) -> Path:
    """A run directory; ``task``: env fields of the task (``{"task": "bin", ...}``), none for a
    config from before the tasks (no ``env.task``: a lift run)."""
    path = root / (name or f"{representation}_s{seed}")
    path.mkdir(parents=True)
    config = {
        "env": {
            "representation": representation,
            "reward": {"kind": "sdf", "c3": 1.0},
            "robot": {"kind": "ur5e"},
            "objects": "builtin",
            "num_envs": 64,
            **(task or {}),
        },
        "ppo": {"lr": 3e-4},
        "run": {"seed": seed, "total_steps": 1_000_000},
    }
    (path / "config.json").write_text(json.dumps(config))
    lines = ["iteration,env_steps,wall_time_s,success_rate,episodes,loss"]
    for i, rate in enumerate(rates, start=1):
        # The trainer leaves the rate empty before the first episode ends.
        text = "" if math.isnan(rate) else repr(rate)
        lines.append(f"{i},{100_000 * i},{seconds * i},{text},{3 * i},0.5")
    (path / "metrics.csv").write_text("\n".join(lines) + "\n")
    if per_object is not None:
        (path / "eval").mkdir()
        rows = ["object,episodes,successes,success_rate"]
        rows += [f"{name},{e},{s},{s / e}" for name, (e, s) in per_object.items()]
        (path / "eval" / "per_object.csv").write_text("\n".join(rows) + "\n")
    return path


@pytest.fixture
def run_dirs(tmp_path: Path) -> list[Path]:
    return [_write_run(tmp_path / "runs", *spec) for spec in RUNS]


@pytest.fixture
def runs(run_dirs: list[Path]) -> list[report.Run]:
    return [report.load_run(d) for d in run_dirs]


def test_load_run(runs: list[report.Run]) -> None:
    run = runs[1]
    assert (run.representation, run.reward, run.robot, run.seed) == ("sq", "sdf", "ur5e", 1)
    # config.json written before the tasks (no env.task): a lift run.
    assert (run.task, run.bin_objects, run.context) == ("lift", None, "none")
    assert run.group == ("lift", "sq", "sdf", "ur5e") and run.label == "sq"
    assert run.env_steps[-1] == 1_000_000 and run.wall_time_s[-1] == 340
    assert np.isnan(run.success_rate[:2]).all() and run.success_rate[5] == 0.9
    assert run.per_object == {"cube": (10, 9), "mug": (10, 6), "plate": (10, 3)}
    assert runs[4].per_object is None


def test_load_run_prefers_the_mean_over_objects(tmp_path: Path) -> None:
    """Where the trainer logged ``object_success_rate`` (the mean over objects) the report uses
    it, not the rate over all ended episodes, which favours the objects that are lifted."""
    path = _write_run(tmp_path, "com", 0, 10.0, [0.5, 0.9], None)
    (path / "metrics.csv").write_text(
        "iteration,env_steps,wall_time_s,success_rate,object_success_rate\n"
        "1,100,10,0.5,0.25\n2,200,20,0.9,\n"
    )
    run = report.load_run(path)
    assert run.success_rate[0] == 0.25 and np.isnan(run.success_rate[1])


def test_steps_to_reach(runs: list[report.Run]) -> None:
    expected = {
        0.9: [(500_000, 150), (600_000, 204), (600_000, 216), (900_000, 270), None],
        0.95: [(700_000, 210), (800_000, 272), None, None, None],
    }
    for threshold, per_run in expected.items():
        for run, want in zip(runs, per_run, strict=True):
            got = report.steps_to_reach(run, threshold)
            if want is None:
                assert all(math.isnan(v) for v in got), (threshold, run.path)
            else:
                assert got == want, (threshold, run.path)


def test_final_success_prefers_eval(runs: list[report.Run]) -> None:
    assert report.training_success(runs[0]) == 0.98  # last 1 of 10 rows
    assert report.final_success(runs[0]) == pytest.approx(23 / 30)  # eval overall instead
    # Overall is successes / episodes, not the mean over objects (which would be 0.5375).
    assert report.eval_success(runs[3]) == pytest.approx(16 / 29)
    assert report.final_success(runs[4]) == pytest.approx(0.6)  # no eval: last 2 of 20 rows
    assert report.training_success(runs[4], last_fraction=0.15) == pytest.approx(1.3 / 3)


def test_summary_table(runs: list[report.Run]) -> None:
    """Table II's layout: arms in the paper's order (com before sq), seeds that reached each
    threshold, steps and minutes over those seeds beside the paper's Table II, env steps/s."""
    lines = report.summary_table(runs).splitlines()
    assert lines[0] == (
        "| arm | seeds | final success | env steps/s | reached 90 % | steps to 90 % (M) "
        "| minutes to 90 % | reached 95 % | steps to 95 % (M) | minutes to 95 % |"
    )
    # final: 16/29 = 0.5517 (eval) and 0.6 (training tail) -> 0.5759 ± 0.0241
    # steps/s: 1 M / 300 s and 2 M / 600 s -> 3333 ± 0
    # 90 %: one seed of two, 0.9 M and 4.5 min (paper: 149 M, 47 min); 95 %: none
    assert lines[2] == (
        "| com | 2 | 0.58 ± 0.02 | 3333 ± 0 | 1/2 | 0.90 (149) | 4.5 (47) "
        "| 0/2 | not reached (550) | not reached (116) |"
    )
    # final: eval overall 23/30, 18/30, 21/30 -> mean 0.6889, std 0.0685
    # steps/s: 1 M over 300, 340, 360 s -> 3017.4 ± 233.1
    # 90 %: 0.5, 0.6, 0.6 M -> 0.5667 ± 0.0471; 2.5, 3.4, 3.6 min -> 3.1667 ± 0.4784
    # 95 %: 0.7, 0.8 M -> 0.75 ± 0.05; 3.5, 4.5333 min -> 4.0167 ± 0.5167 (2 of 3 seeds)
    assert lines[3] == (
        "| sq | 3 | 0.69 ± 0.07 | 3017 ± 233 | 3/3 | 0.57 ± 0.05 (178) | 3.2 ± 0.5 (58) "
        "| 2/3 | 0.75 ± 0.05 (436) | 4.0 ± 0.5 (220) |"
    )
    assert len(lines) == 4
    assert [r.steps_per_second for r in runs[:2]] == pytest.approx([1e6 / 300, 1e6 / 340])


def test_summary_table_at_other_thresholds(runs: list[report.Run]) -> None:
    """--thresholds 0.5,0.7 (the CPU analog): the paper has no numbers there, none in brackets."""
    lines = report.summary_table(runs, thresholds=(0.5, 0.7)).splitlines()
    assert lines[0].endswith(
        "| reached 50 % | steps to 50 % (M) | minutes to 50 % | reached 70 % "
        "| steps to 70 % (M) | minutes to 70 % |"
    )
    # com: 0.5 at i=4 (seed 0, 2 min) and i=19 (seed 1, 9.5 min); 0.7 at i=6 and i=20.
    assert lines[2].endswith(
        "| 2/2 | 1.15 ± 0.75 | 5.8 ± 3.8 | 2/2 | 1.30 ± 0.70 | 6.5 ± 3.5 |"
    )


def test_per_object_table(runs: list[report.Run]) -> None:
    """Objects the paper's Table I lacks: "(—)" beside our mean ± std over the seeds."""
    lines = report.per_object_table(runs).splitlines()
    assert lines[0] == "| object | com | sq |"
    rows = {line.split(" | ")[0].strip("| *"): line for line in lines[2:]}
    assert list(rows) == [
        "bowl", "cube", "mug", "plate", "mean over objects", "all 78 YCB objects (paper)",
        "seeds evaluated",
    ]
    assert rows["bowl"] == "| bowl | 0.75 (—) | — (—) |"
    # sq: 1.0, 0.9, 1.0 -> 0.9667 ± 0.0471
    assert rows["cube"] == "| cube | 1.00 (—) | 0.97 ± 0.05 (—) |"
    # com (one evaluated seed): (1 + 0.2 + 0.2 + 0.75) / 4 = 0.5375; sq per seed:
    # (1 + 0.8 + 0.5) / 3, (0.9 + 0.6 + 0.3) / 3, (1 + 0.7 + 0.4) / 3 -> 0.6889 ± 0.0685;
    # the paper's beside: its all-78 value (these objects are not in its Table I)
    assert rows["mean over objects"] == (
        "| **mean over objects** | **0.54** (0.95) | **0.69 ± 0.07** (0.96) |"
    )
    assert rows["all 78 YCB objects (paper)"] == "| all 78 YCB objects (paper) | (0.95) | (0.96) |"
    assert rows["seeds evaluated"] == "| seeds evaluated | 1 | 3 |"


def _table_one_runs(root: Path) -> list[Path]:
    """bbox over two seeds, and the paper's two reward ablations, on two of its Table I objects
    and one of ours; seed 1 of bbox was not evaluated on the cube."""
    rates = [0.1, 0.5, 0.92]
    ablation = [
        ({"reward": {"kind": kind}}, kind) for kind in ("none", "com")
    ]
    dirs = [
        _write_run(root, "bbox", 0, 30, rates,
                   {"029_plate": (20, 16), "062_dice": (20, 10), "cube": (10, 5)}),
        _write_run(root, "bbox", 1, 30, rates, {"029_plate": (20, 14), "062_dice": (20, 12)}),
    ]
    for env, kind in ablation:
        dirs.append(_write_run(root, "bbox", 0, 30, rates,
                               {"029_plate": (10, 1), "062_dice": (10, 2)}, env, f"bbox-{kind}"))
    return dirs


def test_table_one_cells_paper_column_and_ablations(tmp_path: Path) -> None:
    runs = [report.load_run(d) for d in _table_one_runs(tmp_path)]
    labels = list(report.group_labels(runs).values())
    # The paper's arm first, then the ablations (reward com before no shaping).
    assert labels == ["bbox", "bbox (reward com)", "bbox (no shaping)"]
    assert [r.paper_arm for r in runs] == ["bbox", "bbox", None, None]
    lines = report.per_object_table(runs).splitlines()
    assert lines[0] == "| object | bbox | bbox (reward com) | bbox (no shaping) |"
    rows = {line.split(" | ")[0].strip("| *"): line for line in lines[2:]}
    # plate: 0.8 and 0.7 -> 0.75 ± 0.05, the paper's bbox 0.93; the ablations have no paper value
    assert rows["029_plate"] == "| 029_plate | 0.75 ± 0.05 (0.93) | 0.10 (—) | 0.10 (—) |"
    assert rows["062_dice"] == "| 062_dice | 0.55 ± 0.05 (0.95) | 0.20 (—) | 0.20 (—) |"
    # one of the two seeds has the cube: its value, marked; not in the paper's table
    assert rows["cube"] == "| cube | 0.50† (—) | — (—) | — (—) |"
    for cell in lines[2].split(" | ")[1:]:
        assert len(cell.strip("| ")) <= 20
    # bbox per seed: (0.8 + 0.5 + 0.5) / 3 = 0.6, (0.7 + 0.6) / 2 = 0.65 -> 0.625 ± 0.025 (in
    # binary a hair below both, shown 0.62 ± 0.02); beside it the paper's all-78 value, as the
    # cube is not in its Table I
    assert rows["mean over objects"] == (
        "| **mean over objects** | **0.62 ± 0.02** (0.97) | **0.15** (—) | **0.15** (—) |"
    )
    assert rows["seeds evaluated"] == "| seeds evaluated | 2 | 1 | 1 |"
    # Evaluated on the paper's objects only: its mean over the same objects, (0.93 + 0.95) / 2.
    assert report.paper_overall("bbox", ["029_plate", "062_dice"]) == (
        pytest.approx(0.94), "its mean over the same objects"
    )
    # Table II: no paper numbers for the ablations.
    table = report.summary_table(runs).splitlines()
    assert table[2].startswith("| bbox | 2 |") and "(165)" in table[2]
    assert table[3] == (
        "| bbox (reward com) | 1 | 0.15 | 3333 | 1/1 | 0.30 | 1.5 | 0/1 | not reached "
        "| not reached |"
    )
    assert table[4].startswith("| bbox (no shaping) | 1 |")


def test_spearman() -> None:
    assert report.spearman([0.1, 0.2, 0.3], [1, 2, 3]) == pytest.approx(1.0)
    assert report.spearman([0.1, 0.2, 0.3], [3, 2, 1]) == pytest.approx(-1.0)
    # ties take the average rank: ranks (1, 2.5, 2.5) against (1, 2, 3)
    assert report.spearman([1, 2, 2], [1, 2, 3]) == pytest.approx(np.sqrt(3) / 2)
    assert math.isnan(report.spearman([1.0], [2.0]))
    assert math.isnan(report.spearman([1, 1, 1], [1, 2, 3]))


def test_rank_correlation_on_a_known_ordering(tmp_path: Path) -> None:
    """Four arms on the plate and the dice. The paper's means over them: sq 0.945 > bbox 0.94 >
    com 0.695 > pc32 0.525; ours: bbox 0.9 > sq 0.8 > com 0.5 > pc32 0.1. One swapped pair:
    rho = 1 - 6 * 2 / (4 * 15) = 0.8."""
    ours = {"com": 0.5, "bbox": 0.9, "sq": 0.8, "pc32": 0.1}
    dirs = [
        _write_run(tmp_path, rep, 0, 30, [0.1],
                   {"029_plate": (10, round(10 * rate)), "062_dice": (10, round(10 * rate))})
        for rep, rate in ours.items()
    ]
    # Not one of the paper's arms: left out of the ranking.
    dirs.append(_write_run(tmp_path, "sq", 0, 30, [0.1], {"029_plate": (10, 10)},
                           {"reward": {"kind": "none"}}, "sq-none"))
    ranking = report.paper_ranking([report.load_run(d) for d in dirs])
    assert ranking.arms == ("com", "bbox", "sq", "pc32")
    assert ranking.ours == pytest.approx((0.5, 0.9, 0.8, 0.1))
    assert ranking.paper == pytest.approx((0.695, 0.94, 0.945, 0.525))
    assert ranking.rho == pytest.approx(0.8)
    text = report.ranking_text(ranking)
    assert "ρ = +0.80" in text and "its mean over the same objects" in text
    assert "Ours: bbox 0.900 > sq 0.800 > com 0.500 > pc32 0.100" in text
    assert "the paper's: sq 0.945 > bbox 0.940 > com 0.695 > pc32 0.525" in text
    assert "agree on 5 (" in text
    assert "disagree on 1 (ours bbox > sq; the paper's the reverse)" in text
    one = report.paper_ranking([report.load_run(dirs[0])])
    assert "needs at least two" in report.ranking_text(one)


def test_seeds_settle_only_separated_arms_with_two_seeds(tmp_path: Path) -> None:
    """An arm is settled above another only where every seed of it is above every seed of the
    other, each with two seeds; overlapping seeds and one-seed arms are not settled, and the
    ranking sentence says which of the pairs that disagree with the paper the seeds settle."""
    assert report.settled([0.8, 0.9], [0.6, 0.7])
    assert not report.settled([0.8, 0.9], [0.6, 0.85])  # overlap
    assert not report.settled([0.9], [0.1, 0.2])  # one seed
    assert not report.settled([0.8, 0.9], [0.8, 0.7])  # equal is not above

    def plate(rep: str, seed: int, held: int) -> Path:
        return _write_run(tmp_path, rep, seed, 30, [0.1], {"029_plate": (10, held)})

    dirs = [plate("pc32", 0, 9), plate("pc32", 1, 8),  # the paper's plate: pc32 0.50 last
            plate("bbox", 0, 6), plate("bbox", 1, 7),  # bbox 0.93
            plate("sq", 0, 5), plate("sq", 1, 9),  # sq 0.95: overlaps bbox and pc32
            plate("com", 0, 10)]  # com 0.74, one seed
    runs = [report.load_run(d) for d in dirs]
    lines = [line for line in report.seeds_table(runs).splitlines() if line.startswith("|")]
    assert lines[0].startswith("| arm | seeds | overall per seed | settled above |")
    rows = {line.split("|")[1].strip(): [c.strip() for c in line.strip("|").split("|")]
            for line in lines[2:]}
    assert [line.split("|")[1].strip() for line in lines[2:]] == ["com", "pc32", "sq", "bbox"]
    assert rows["pc32"][1:] == ["2", "0.900, 0.800", "bbox", "sq"]
    assert rows["bbox"][3:] == ["—", "sq"] and rows["sq"][3:] == ["—", "pc32, bbox"]
    assert rows["com"][1:] == ["1", "1.000", "—", "—"]
    # Within: pc32 (0.9, 0.8), bbox (0.6, 0.7), sq (0.5, 0.9): sums of squares 0.005 + 0.005 +
    # 0.08 over 3 degrees of freedom; between: the means 0.85, 0.65, 0.7 (com has one seed).
    within, between, alike, arms = report.seed_and_arm_spread(
        [[0.9, 0.8], [0.6, 0.7], [0.5, 0.9], [1]])
    assert within == pytest.approx(math.sqrt(0.09 / 3)) and arms == 3
    assert between == pytest.approx(float(np.std([0.85, 0.65, 0.7], ddof=1)))
    assert alike == pytest.approx(within / math.sqrt(2))
    assert report.seed_and_arm_spread([[0.9, 0.8], [1.0]]) is None
    assert f"seeds of one arm spread by {within:.3f}" in report.seeds_table(runs)
    assert f"would spread by about {within / math.sqrt(2):.3f}." in report.seeds_table(runs)
    text = report.ranking_text(report.paper_ranking(runs))
    assert "disagree on 4 (ours com > bbox, com > sq, pc32 > bbox, pc32 > sq;" in text
    assert "our seeds settle 1 (pc32 > bbox)" in text
    assert "## Which differences the seeds settle" in report.write_report(dirs, tmp_path / "r")[
        -1].read_text()


def test_group_labels_name_reward_and_robot_when_they_differ(runs: list[report.Run]) -> None:
    assert list(report.group_labels(runs).values()) == ["com", "sq"]
    other = report.Run(
        path=Path("x"),
        representation="sq",
        reward="none",
        robot="ur5e",
        seed=0,
        env_steps=np.ones(1),
        wall_time_s=np.ones(1),
        success_rate=np.ones(1),
        per_object=None,
    )
    floating = replace(other, reward="com", robot="floating")
    labels = report.group_labels([floating, *runs, other])
    assert list(labels.values()) == [
        "com", "sq", "sq (no shaping)", "sq (reward com; robot floating)"
    ]
    assert report.resolve_group([*runs, other], "com") == ("lift", "com", "sdf", "ur5e")
    assert report.resolve_group([*runs, other], "sq (no shaping)") == ("lift", "sq", "none", "ur5e")
    assert report.resolve_group([*runs, other], "sq") == ("lift", "sq", "sdf", "ur5e")


def test_bin_runs_are_their_own_groups(run_dirs: list[Path], tmp_path: Path) -> None:
    """Task, bin size and context split the groups: a bin run is never averaged with a lift
    run of the same representation; labels bin5-bbox, bin5-bbox+ctx."""
    root = tmp_path / "runs"
    bin5 = {"task": "bin", "bin": {"num_objects": 5}, "context": "none"}
    ctx = {"task": "bin", "bin": {"num_objects": 5}, "context": "bbox"}
    bin10 = {"task": "bin", "bin": {"num_objects": 10}}
    rates = [0.1, 0.5, 0.92]
    extra = [
        _write_run(root, "sq", 0, 30, rates, {"cube": (10, 4)}, bin5, "bin5-sq_s0"),
        _write_run(root, "bbox", 0, 30, rates, {"cube": (12, 6)}, bin5, "bin5-bbox_s0"),
        _write_run(root, "bbox", 1, 30, rates, None, bin5, "bin5-bbox_s1"),
        _write_run(root, "bbox", 0, 30, rates, {"cube": (10, 9)}, ctx, "bin5-bbox-ctx_s0"),
        _write_run(root, "bbox", 0, 30, rates, None, bin10, "bin10-bbox_s0"),
    ]
    runs = [report.load_run(d) for d in [*run_dirs, *extra]]
    assert (runs[-2].task, runs[-2].bin_objects, runs[-2].context) == ("bin", 5, "bbox")
    assert runs[-2].label == "bin5-bbox+ctx" and runs[-1].label == "bin10-bbox"
    groups = report.group_runs(runs)
    assert len(groups) == 6 and len(groups[("bin5", "bbox", "sdf", "ur5e")]) == 2
    assert list(report.group_labels(runs).values()) == [
        "com", "sq", "bin5-sq", "bin5-bbox", "bin5-bbox+ctx", "bin10-bbox"
    ]
    lines = report.summary_table(runs).splitlines()
    assert [line.split(" | ")[:2] for line in lines[4:]] == [
        ["| bin5-sq", "1"], ["| bin5-bbox", "2"], ["| bin5-bbox+ctx", "1"], ["| bin10-bbox", "1"],
    ]
    assert "(" not in lines[4]  # the paper's Table II has no bin numbers
    header = report.per_object_table(runs).splitlines()[0]
    assert header == "| object | com | sq | bin5-sq | bin5-bbox | bin5-bbox+ctx |"
    assert report.resolve_group(runs, "sq") == ("lift", "sq", "sdf", "ur5e")
    assert report.resolve_group(runs, "bin5-bbox+ctx") == ("bin5", "bbox+ctx", "sdf", "ur5e")
    with pytest.raises(TrainerError, match="several groups"):
        report.resolve_group(runs, "bbox")  # bin5-bbox and bin10-bbox
    gains = report.success_gain(runs, "bin5-bbox", "bin5-bbox+ctx")
    assert gains == [("cube", pytest.approx(0.9 - 0.5))]
    report.write_report([*run_dirs, *extra], tmp_path / "out")
    text = (tmp_path / "out" / "report.md").read_text()
    assert "in 6 arms" in text and "| bin5-bbox+ctx | 1 |" in text
    assert "): bin5-bbox+ctx (bin5/bbox+ctx/sdf/ur5e), seed 0" in text


def test_success_gain(runs: list[report.Run]) -> None:
    gains = report.success_gain(runs, "com", "sq")
    assert [name for name, _ in gains] == ["mug", "plate", "cube"]  # bowl: only com has it
    assert [g for _, g in gains] == pytest.approx([0.5, 0.2, -1 / 30])


def test_mean_curve_covers_only_the_common_range(runs: list[report.Run]) -> None:
    grid, mean, std = report.mean_curve(runs[:3])
    # sq seed 1 logs its first rate at i=3; all three end at i=10.
    assert grid[0] == 300_000 and grid[-1] == 1_000_000
    assert mean[-1] == pytest.approx(0.96) and std[-1] == pytest.approx(np.std([0.98, 0.96, 0.94]))
    # At i=3 seed 0 is at 0.5, seed 1 at 0.4, seed 2 at 0.6.
    assert mean[0] == pytest.approx(0.5)


def test_write_report(run_dirs: list[Path], tmp_path: Path) -> None:
    out = tmp_path / "report"
    written = report.write_report(run_dirs, out, compare=("com", "sq"))
    names = {p.name for p in written}
    assert names == {
        "report.md",
        "success_vs_steps.png",
        "success_vs_time.png",
        "gain_sq_over_com.png",
    }
    for path in written:
        assert path.parent == out and path.is_file()
        if path.suffix == ".png":
            with Image.open(path) as image:
                assert image.format == "PNG" and image.width > 0 and image.height > 0
    text = (out / "report.md").read_text()
    assert "| sq | 3 | 0.69 ± 0.07 | 3017 ± 233 |" in text
    assert "| **mean over objects** | **0.54** (0.95) | **0.69 ± 0.07** (0.96) |" in text
    assert "(gain_sq_over_com.png)" in text and "(success_vs_time.png)" in text
    assert "ρ = " in text  # com and sq are two of the paper's arms
    assert not list(out.glob(".*tmp*"))


def test_machines_say_whether_minutes_compare(run_dirs: list[Path], tmp_path: Path) -> None:
    """Each run's launches.csv in words per span of iterations (machine and code); the report
    says minutes and env steps/s compare across arms only where one machine (recorded) trained
    every run."""
    from trainer.training.run_dir import RunDir, record_launch

    def launch(first: int, cpu: str, nice: int = 0) -> dict[str, object]:
        return {"first_iteration": first, "started": "2026-11-30T04:00:00Z",
                "code": f"c{first}", "cpu": cpu,
                "cores": 2, "nice": nice, "device": "cpu", "processes": 1, "sim_threads": 1,
                "torch_threads": 1}

    for path in run_dirs:
        record_launch(RunDir(path), launch(1, "AMD EPYC"))
    out = tmp_path / "report"
    report.write_report(run_dirs, out)
    assert "One machine trained every run" in (out / "report.md").read_text()
    sq0 = RunDir(run_dirs[0])
    record_launch(sq0, launch(6, "Intel Xeon", nice=5))
    record_launch(sq0, launch(8, "Intel Xeon", nice=5))
    record_launch(sq0, launch(4, "Intel Xeon", nice=5))  # resumed from iteration 3: redone
    assert report.load_run(sq0.path).machines == (
        (1, "AMD EPYC, 2 cores", "c1"), (4, "Intel Xeon, 2 cores, nice 5", "c4"))
    RunDir(run_dirs[1]).launches.unlink()
    report.write_report(run_dirs, out)
    text = (out / "report.md").read_text()
    assert "compare only between runs on one machine" in text
    assert ("`../runs/sq_s0`: iterations 1-3: AMD EPYC, 2 cores (code c1); iterations 4-10: "
            "Intel Xeon, 2 cores, nice 5 (code c4)") in text
    assert "`../runs/sq_s1`: iterations 1-10: not recorded" in text


def test_machines_name_the_cpu_that_evaluated(run_dirs: list[Path], tmp_path: Path) -> None:
    """table.md's last line (trainer eval's machine and code): one line where one CPU model
    evaluated every run, each run's where they differ or one is not recorded."""
    from trainer.evaluation import evaluated_line

    evaluated = [p for p in run_dirs if (p / "eval" / "per_object.csv").is_file()]
    assert len(evaluated) >= 2
    for path in evaluated:
        (path / "eval" / "table.md").write_text(
            "| object | episodes | sq |\n\nEvaluated on AMD EPYC with code 0123abcd, "
            "2026-11-30 07:46 UTC.\n")
    run = report.load_run(evaluated[0])
    assert run.eval_machine == ("AMD EPYC", "0123abcd")
    out = tmp_path / "report"
    report.write_report(run_dirs, out)
    text = (out / "report.md").read_text()
    assert "One CPU model evaluated every run: AMD EPYC (code 0123abcd)." in text
    (evaluated[1] / "eval" / "table.md").write_text("| object | episodes | sq |\n")
    report.write_report(run_dirs, out)
    text = (out / "report.md").read_text()
    assert "evaluations were made on more than one CPU model or on one not recorded" in text
    assert f"`../runs/{evaluated[0].name}`: AMD EPYC (code 0123abcd)" in text
    assert f"`../runs/{evaluated[1].name}`: not recorded" in text
    # the line trainer eval writes reads back as its machine
    (evaluated[1] / "eval" / "table.md").write_text(evaluated_line() + "\n")
    assert report.load_run(evaluated[1]).eval_machine is not None


@pytest.mark.parametrize("relative_args", [False, True])
def test_report_names_runs_relative_to_its_directory(
    run_dirs: list[Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch, relative_args: bool
) -> None:
    """No absolute machine path in report.md; each run's link resolves from the report's
    directory to that run, whether the command got absolute or relative paths, and the command
    that made it names them relative to the directory it ran in."""
    out = tmp_path / "reports" / "latest"
    args, out_arg = run_dirs, out
    monkeypatch.chdir(tmp_path)
    if relative_args:
        args = [d.relative_to(tmp_path) for d in run_dirs]
        out_arg = out.relative_to(tmp_path)
    report.write_report(args, out_arg)
    text = (out / "report.md").read_text()
    assert str(tmp_path) not in text and str(tmp_path.resolve()) not in text
    listed = [line for line in text.splitlines() if line.startswith("- [`")]
    assert len(listed) == len(run_dirs)
    assert "Made by this command, run in `../..` (relative to this folder)" in text
    runs = " ".join(f"runs/{d.name}" for d in run_dirs)
    assert f"\n    trainer report {runs} --out reports/latest\n" in text
    for line, run_dir in zip(listed, run_dirs, strict=True):
        link = line.split("](", 1)[1].split(")", 1)[0]
        assert not Path(link).is_absolute() and link == f"../../runs/{run_dir.name}"
        assert (out / link).resolve() == run_dir.resolve()


def test_write_report_rejects_unknown_group_before_writing(
    run_dirs: list[Path], tmp_path: Path
) -> None:
    with pytest.raises(TrainerError, match="no group named 'pc32'"):
        report.write_report(run_dirs, tmp_path / "report", compare=("pc32", "sq"))
    assert not (tmp_path / "report").exists()


def test_missing_metrics_names_the_path(run_dirs: list[Path]) -> None:
    metrics = run_dirs[0] / "metrics.csv"
    metrics.unlink()
    with pytest.raises(TrainerError, match="metrics.csv") as err:
        report.load_run(run_dirs[0])
    assert str(metrics) in str(err.value) and "\n" not in str(err.value)


def test_malformed_inputs_name_the_path(run_dirs: list[Path]) -> None:
    config = run_dirs[0] / "config.json"
    config.write_text(json.dumps({"env": {"representation": "sq", "robot": {"kind": "ur5e"}}}))
    with pytest.raises(TrainerError, match="env.reward.kind") as err:
        report.load_run(run_dirs[0])
    assert str(config) in str(err.value)

    metrics = run_dirs[1] / "metrics.csv"
    metrics.write_text(metrics.read_text() + "11,1100000,374,oops,33,0.5\n")
    with pytest.raises(TrainerError, match="success_rate 'oops'") as err:
        report.load_run(run_dirs[1])
    assert f"{metrics}:12" in str(err.value)


def test_curriculum_runs_get_their_plot(run_dirs: list[Path], tmp_path: Path) -> None:
    # A run whose metrics carry the lift curriculum's columns, the target rising from 0.04 m.
    path = run_dirs[0]
    lines = ["iteration,env_steps,wall_time_s,success_rate,h_bar,target_success_rate"]
    for i in range(1, 9):
        lines.append(f"{i},{100_000 * i},{10 * i},0.0,{min(0.04 + 0.02 * i, 0.2)},{0.05 * i}")
    (path / "metrics.csv").write_text("\n".join(lines) + "\n")
    run = report.load_run(path)
    assert run.has_curriculum and run.h_bar is not None and run.target_success_rate is not None
    np.testing.assert_allclose(run.target_success_rate, 0.05 * np.arange(1, 9))
    assert not report.load_run(run_dirs[1]).has_curriculum  # no such columns
    written = report.write_report(run_dirs, tmp_path / "out")
    assert "curriculum.png" in {p.name for p in written}
    assert "![lift curriculum](curriculum.png)" in (tmp_path / "out" / "report.md").read_text()


def test_runs_that_differ_in_more_than_the_seed_are_not_averaged(tmp_path: Path) -> None:
    """Two bbox runs, one with the no-slip solver: two groups named by the difference, never
    one group of two "seeds"; seeds that differ only in the seed and the threads stay one group.
    A field only some runs record (added to the config later) does not split them."""
    root = tmp_path / "runs"
    rates = [0.1, 0.5]
    dirs = [_write_run(root, "bbox", s, 30, rates, None, name=f"bbox_s{s}") for s in (0, 1)]
    dirs.append(_write_run(root, "bbox", 0, 30, rates, None,
                           {"physics": {"noslip_iterations": 5}}, "bbox-noslip"))
    for path, physics in zip(dirs, ({"noslip_iterations": 0}, {"noslip_iterations": 0}, None),
                             strict=True):
        config = json.loads((path / "config.json").read_text())
        config["run"]["torch_threads"] = 1 + config["run"]["seed"]
        if physics:
            config["env"]["physics"] = {**physics, "sleep": False}
        (path / "config.json").write_text(json.dumps(config))
    runs = [report.load_run(d) for d in dirs]
    groups = report.group_runs(runs)
    assert {k[1]: len(v) for k, v in groups.items()} == {
        "bbox [noslip_iterations=0]": 2, "bbox [noslip_iterations=5]": 1,
    }
    assert "| bbox [noslip_iterations=5] | 1 |" in report.summary_table(runs)
    assert len(report.group_runs(runs[:2])) == 1


def test_objects_that_fail_upside_down_get_their_face_up_rates(
    run_dirs: list[Path], tmp_path: Path
) -> None:
    """by_start.csv of the evaluations: the plate, never lifted upside down, is listed with each
    arm's rate over all resets and over the face-up ones (mean over seeds); the cube, lifted
    either way, is not; runs without the file are left out of it."""
    rows = {"sq_s0": {"plate": (7, 5, 3, 0), "cube": (6, 6, 4, 4)},
            "sq_s1": {"plate": (7, 3, 3, 0), "cube": (6, 5, 4, 4)},
            "com_s0": {"plate": (4, 1, 1, 0), "cube": (5, 5, 5, 5)}}
    for path in run_dirs:
        if path.name in rows:
            lines = ["object,face_up_episodes,face_up_successes,upside_down_episodes,"
                     "upside_down_successes"]
            lines += [f"{k},{','.join(map(str, v))}" for k, v in rows[path.name].items()]
            (path / "eval" / "by_start.csv").write_text("\n".join(lines) + "\n")
    runs = [report.load_run(d) for d in run_dirs]
    table = report.upside_down_table(runs).splitlines()
    assert table[0] == "| object | com | sq |" and len(table) == 3
    assert table[2] == "| plate | 0.20 / 0.25 (80% face up) | 0.40 / 0.57 (70% face up) |"
    out = tmp_path / "report"
    report.write_report(run_dirs, out)
    assert "### Objects that fail upside down" in (out / "report.md").read_text()
    assert report.upside_down_table([replace(r, by_start=None) for r in runs]) == ""


def test_an_arm_that_ran_with_other_settings_than_most_is_named(
    run_dirs: list[Path], tmp_path: Path
) -> None:
    """One pc128 run with another learning rate than the five others: alone in its group, it is
    named by the difference; the others are not; the group key's own fields (here the
    representation) never are; a tie names both sides."""
    odd = _write_run(tmp_path / "runs", "pc128", 0, 30, [0.1, 0.5], None)
    config = json.loads((odd / "config.json").read_text())
    config["ppo"]["lr"] = 1e-3
    (odd / "config.json").write_text(json.dumps(config))
    runs = [report.load_run(d) for d in [*run_dirs, odd]]
    assert [k[1] for k in report.group_runs(runs)] == ["com", "sq", "pc128 [lr=0.001]"]
    pair = [report.load_run(run_dirs[0]), runs[-1]]
    assert [k[1] for k in report.group_runs(pair)] == ["sq [lr=0.0003]", "pc128 [lr=0.001]"]


def test_runs_from_before_the_held_criterion_are_not_averaged_with_later_ones(
    tmp_path: Path,
) -> None:
    """A config without ``reward.hold_tips`` was written when any rise by h_bar was a success:
    it is reported as hold_tips=0, apart from a run trained with today's default of 2."""
    root = tmp_path / "runs"
    dirs = [_write_run(root, "bbox", s, 30, [0.1, 0.5], None, name=f"bbox_s{s}") for s in (0, 1)]
    config = json.loads((dirs[1] / "config.json").read_text())
    config["env"]["reward"] = {**config["env"].get("reward", {}), "hold_tips": 2}
    (dirs[1] / "config.json").write_text(json.dumps(config))
    groups = report.group_runs([report.load_run(d) for d in dirs])
    assert {k[1]: len(v) for k, v in groups.items()} == {
        "bbox [hold_tips=0]": 1, "bbox [hold_tips=2]": 1,
    }


def _move_eval(run_dir: Path, name: str, criterion: str | None = None) -> None:
    """Rename a run's eval/ to ``name`` (as ``trainer eval --out NAME`` writes it), with a
    table.md stating ``criterion`` as trainer eval does."""
    (run_dir / "eval").rename(run_dir / name)
    if criterion is not None:
        (run_dir / name / "table.md").write_text(f"Success per target object.\n\nSuccess: "
                                                 f"{criterion}\n\n| object |\n")


def test_report_options_eval_folder_thresholds_and_allowed_differences(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``--eval eval-it350`` reads that folder (and its criterion), ``--thresholds`` sets Table
    II's columns, ``--allow-differ run.max_minutes`` keeps two seeds with different budgets one
    arm; the command recorded at the top carries the options."""
    monkeypatch.chdir(tmp_path)
    held = "the target lifted by 0.2 m while held (2 or more fingertip pads within 0.02 m of it)."
    dirs = _table_one_runs(tmp_path / "runs")[:2]
    for path, minutes in zip(dirs, (150.0, 155.0), strict=True):
        _move_eval(path, "eval-it350", held)
        config = json.loads((path / "config.json").read_text())
        config["run"]["max_minutes"] = minutes
        (path / "config.json").write_text(json.dumps(config))
    runs = [report.load_run(d, "eval-it350") for d in dirs]
    assert runs[0].eval_criterion == held.removeprefix("Success: ")
    assert report.load_run(dirs[0]).per_object is None  # no eval/ any more

    # The budgets differ: two arms, unless allowed.
    report.write_report(dirs, "split", eval_dir="eval-it350")
    text = Path("split/report.md").read_text()
    assert "bbox [max_minutes=150.0] (1), bbox [max_minutes=155.0] (1)" in text
    assert "`--allow-differ FIELD,...` makes them one arm" in text
    with pytest.raises(TrainerError, match="run.max_minuts: no run's config.json"):
        report.write_report(dirs, "typo", allow_differ=["run.max_minuts"])

    report.write_report(dirs, "rep", eval_dir="eval-it350", thresholds=(0.5, 0.7),
                        allow_differ=["run.max_minutes"])
    text = Path("rep/report.md").read_text()
    assert (
        "\n    trainer report runs/bbox_s0 runs/bbox_s1 --out rep --eval eval-it350 --thresholds "
        "0.5,0.7 --allow-differ run.max_minutes\n"
    ) in text
    assert "2 runs in 1 arm: bbox (2)." in text
    assert "| 029_plate | 0.75 ± 0.05 (0.93) |" in text
    assert f"Success in these evaluations: {held}" in text
    # final success, successes / episodes: 31/50 and 26/40 -> 0.635 ± 0.015; rates 0.1, 0.5,
    # 0.92 at 100 k steps and 30 s each: 0.5 at 0.2 M (1 min), 0.7 at 0.3 M (1.5 min)
    assert (
        "| bbox | 2 | 0.64 ± 0.02 | 3333 ± 0 | 2/2 | 0.20 ± 0.00 | 1.0 ± 0.0 | 2/2 | 0.30 ± 0.00 "
        "| 1.5 ± 0.0 |"
    ) in text

    # The default folder is absent: say which folders there are instead of Table I.
    report.write_report(dirs, "none", allow_differ=["run.max_minutes"])
    text = Path("none/report.md").read_text()
    assert "No run has `eval/per_object.csv` (evaluation folders in the runs: `eval-it350`)" in text
    assert "## Ranking" not in text and "| bbox | 2 |" in text

    for bad, message in (((), "give success rates"), ((0.5, 1.5), "give success rates"),
                         ((0.5, 0.5), "each at most once")):
        with pytest.raises(TrainerError, match=message):
            report.write_report(dirs, "bad", thresholds=bad)
    with pytest.raises(TrainerError, match="name of a folder inside the run directories"):
        report.write_report(dirs, "bad", eval_dir="../elsewhere")
    assert not Path("bad").exists()


def test_report_command_line(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys) -> None:  # noqa: ANN001


    monkeypatch.chdir(tmp_path)
    dirs = _table_one_runs(tmp_path / "runs")
    _move_eval(dirs[0], "eval-x")

    def invoke(*argv: str) -> tuple[int, str]:
        code, out, err = trainer_main(["report", *argv], monkeypatch, capsys)
        return code, out + err

    code, out = invoke("runs/bbox_s0", "--eval", "eval-x", "--thresholds", "0.5,0.7")
    assert code == 0, out
    text = Path("report/report.md").read_text()
    assert "--eval eval-x --thresholds 0.5,0.7" in text and "| 029_plate | 0.80 (0.93) |" in text
    code, out = invoke("runs/bbox_s0", "--thresholds", "0.5,high")
    assert code != 0 and "--thresholds '0.5,high': give comma-separated success rates" in out


def test_worst_objects_pool_the_seeds_endings(run_dirs: list[Path], tmp_path: Path) -> None:
    """With ``endings.csv`` in the evaluations, the report lists each arm's worst objects
    (success pooled over its seeds, lowest first) with their episodes by ending; arms without
    it are left out, and a damaged file leaves its run's endings out instead of stopping."""
    endings = {  # sq seeds 0 and 1: success, never lifted, dropped (as trainer eval writes)
        "sq_s0": {"cube": (10, 0, 0), "mug": (8, 1, 1), "plate": (5, 3, 2)},
        "sq_s1": {"cube": (9, 1, 0), "mug": (6, 4, 0), "plate": (3, 7, 0)},
    }
    for name, rows in endings.items():
        lines = ["object,episodes,success,never_lifted,dropped"]
        lines += [f"{obj},{sum(row)},{row[0]},{row[1]},{row[2]}" for obj, row in rows.items()]
        (tmp_path / "runs" / name / "eval" / "endings.csv").write_text("\n".join(lines) + "\n")
    (tmp_path / "runs" / "sq_s2" / "eval" / "endings.csv").write_text("object,episodes\nx,y\n")
    runs = [report.load_run(d) for d in run_dirs]
    assert runs[0].endings == {"cube": {"success": 10, "never lifted": 0, "dropped": 0},
                               "mug": {"success": 8, "never lifted": 1, "dropped": 1},
                               "plate": {"success": 5, "never lifted": 3, "dropped": 2}}
    assert runs[2].endings is None  # damaged: left out
    table = report.worst_objects_table(runs, count=2)
    assert table.splitlines()[:5] == [
        "**sq** (2 seeds, 3 objects):", "",
        "| object | episodes | success | never lifted | dropped |",
        "|---|---:|---:|---:|---:|",
        "| plate | 20 | 8 | 10 | 2 |",
    ]
    assert table.splitlines()[5] == "| mug | 20 | 14 | 5 | 1 |" and "com" not in table
    # a seed evaluated since never reached is recorded, beside one from before: its never
    # reached are counted as never lifted, as the older one counted them
    split = {obj: {"success": s, "never reached": 2, "never lifted": n - 2, "dropped": d}
             for obj, (s, n, d) in endings["sq_s1"].items() if n >= 2}
    runs[1] = dataclasses.replace(runs[1], endings=split)
    assert report.worst_objects_table(runs, count=2).splitlines()[2:6] == [
        "| object | episodes | success | never lifted | dropped |", "|---|---:|---:|---:|---:|",
        "| plate | 20 | 8 | 10 | 2 |", "| mug | 20 | 14 | 5 | 1 |"]
    for k, name in enumerate(("sq_s0", "sq_s1")):  # both seeds with it: the column is kept
        split = {obj: {"success": s, "never reached": 1, "never lifted": n - 1, "dropped": d}
                 for obj, (s, n, d) in endings[name].items() if n >= 1}
        runs[k] = dataclasses.replace(runs[k], endings=split)
    assert report.worst_objects_table(runs, count=1).splitlines()[2:5] == [
        "| object | episodes | success | never reached | never lifted | dropped |",
        "|---|---:|---:|---:|---:|---:|", "| plate | 20 | 8 | 2 | 8 | 2 |"]
    out = tmp_path / "report"
    report.write_report(run_dirs, out, worst_count=2)
    text = (out / "report.md").read_text()
    assert "## The 2 worst objects of each arm" in text and "| plate | 20 | 8 | 10 | 2 |" in text
    assert "--worst 2" in text  # the command that made it
