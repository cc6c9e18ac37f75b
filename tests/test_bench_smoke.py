"""Every bench of bench/ in its smallest configuration (seconds, built-in objects or one YCB
mesh): it runs, and its output has its figures and the line that compares them with the
baseline measured in the same run. (bench/reward_balance.py and bench/env_throughput.py
--policy run in their own tests too.)"""

from __future__ import annotations

import re
from pathlib import Path

import pytest
import torch

from geomprep.config import Config
from tests.conftest import require_ycb
from tests.tiny_runs import ROOT, script

NUMBER = r"[0-9]+(\.[0-9]+)?"


def run_bench(name: str, argv: list[str], capsys: pytest.CaptureFixture[str]) -> list[str]:
    """``bench/NAME.py ARGV`` in this process: its printed lines (torch's threads restored)."""
    threads = torch.get_num_threads()
    try:
        script("bench", name).main(argv)
    finally:
        torch.set_num_threads(threads)
    return capsys.readouterr().out.splitlines()


def test_build_all(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    lines = run_bench("build_all", ["--objects", "builtin_dice", "--jobs", "1",
                                    "--data-dir", str(tmp_path / "data")], capsys)
    stages = {line.split()[0]: line.split()[1:] for line in lines if line.split()}
    assert float(stages["sdf"][0]) > 0 and float(stages["mesh"][0]) >= 0
    assert "failed: none" in lines
    assert any(re.fullmatch(rf"cold build: {NUMBER} s wall .*", line) for line in lines)
    assert re.fullmatch(r"ratio cold / cached rerun: [0-9]+x", lines[-1])


def test_sdf(capsys: pytest.CaptureFixture[str]) -> None:
    ycb = require_ycb()
    lines = run_bench("sdf", ["--objects", "062_dice", "--resolution", "32",
                              "--ycb-dir", str(ycb)], capsys)
    assert lines[0].split() == ["object", "open3d", "s", "ours", "s", "ratio", "max", "err",
                                "mm", "MB"]
    row, mean = lines[1].split(), lines[2].split()
    assert row[0] == "062_dice" and all(float(v) >= 0 for v in row[1:])
    assert float(row[4]) < 2.0  # mm off open3d's distance, at 32^3
    assert mean[0] == "mean" and float(mean[3]) > 0  # the ratio to the baseline


def test_sdf_lookup(capsys: pytest.CaptureFixture[str]) -> None:
    lines = run_bench("sdf_lookup", ["--envs", "64", "--objects", "2", "--resolution", "32",
                                     "--repeats", "3", "--no-compile", "--devices", "cpu",
                                     "--spread", "near"], capsys)
    timed = [line for line in lines if "SDFLookup.query" in line]
    assert len(timed) >= 2 and all(re.search(rf": +{NUMBER} ms", line) for line in timed)
    baselines = [line for line in lines if "baseline" in line]
    assert len(baselines) == 2
    assert all(re.search(rf"ratio {NUMBER}x; max diff", line) for line in baselines)


def test_sq(capsys: pytest.CaptureFixture[str]) -> None:
    ycb = require_ycb()
    lines = run_bench("sq", ["--objects", "025_mug", "--ycb-dir", str(ycb)], capsys)
    row = next(line for line in lines if line.startswith("025_mug"))
    assert len(re.findall(NUMBER, row)) >= 12  # seconds, 4 distances, IoU for both fits
    assert any(line.startswith("ems+surface  seconds per object") for line in lines)
    # The mug is concave: the surface term's p95 against EMS alone's (the baseline).
    assert re.match(rf"concave 025_mug +sq->mesh p95 +{NUMBER} -> +{NUMBER} mm", lines[-1])


def test_ppo_throughput(builtin_data: Config, monkeypatch: pytest.MonkeyPatch,
                        capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.syspath_prepend(str(ROOT / "bench"))  # it imports env_throughput beside it
    lines = run_bench("ppo_throughput", ["--envs", "4", "--repr", "com", "--iterations", "1",
                                         "--no-compile", "--objects", "builtin_box",
                                         "--data-dir", str(builtin_data.data_dir)], capsys)
    assert lines[0].split()[-1] == "ratio"
    task, envs, rep, train_rate, env_rate, ratio = lines[1].split()
    assert (task, envs, rep) == ("lift", "4", "com")
    assert float(train_rate) > 0 and float(env_rate) > 0
    assert float(ratio) == pytest.approx(float(train_rate) / float(env_rate), abs=0.01)


@pytest.mark.slow
def test_ppo_throughput_processes(builtin_data: Config, monkeypatch: pytest.MonkeyPatch,
                                  capsys: pytest.CaptureFixture[str]) -> None:
    # One process of two simulation threads against two processes of one (torchrun).
    monkeypatch.syspath_prepend(str(ROOT / "bench"))
    lines = run_bench("ppo_throughput", ["--processes", "2", "--envs", "4", "--repr", "com",
                                         "--iterations", "1", "--no-compile", "--objects",
                                         "builtin_box", "--data-dir",
                                         str(builtin_data.data_dir)], capsys)
    assert lines[0].split()[-1] == "ratio"
    task, envs, rep, one, two, ratio = lines[1].split()
    assert (task, envs, rep) == ("lift", "4", "com")
    assert float(one) > 0 and float(two) > 0
    assert float(ratio) == pytest.approx(float(two) / float(one), abs=0.01)
    assert lines[-1].startswith("ratio: training env steps/s of 2 processes")


def test_pointnet_update(capsys: pytest.CaptureFixture[str]) -> None:
    lines = run_bench("pointnet_update", ["--repr", "pc32", "--envs", "4", "--repeats", "1",
                                          "--set", "ppo.pointnet_hidden=[8,16]"], capsys)
    assert lines[0].split()[-1] == "plain"
    rows = [line.split() for line in lines[1:4]]
    assert [" ".join(r[1:-4]) for r in rows] == ["plain", "fast", "fast + shared"]
    for row in rows:
        assert row[0] == "pc32" and all(float(v) > 0 for v in row[-4:-1])
    assert rows[0][-1] == "1.00x"  # the baseline against itself
    assert lines[-1].startswith("s/iteration: 5 epochs x minibatches of")


def test_env_throughput(builtin_data: Config, capsys: pytest.CaptureFixture[str]) -> None:
    lines = run_bench("env_throughput", [
        "--tasks", "lift,bin", "--envs", "4", "--reprs", "com",
        "--objects", "builtin_dice,builtin_sphere", "--bin-objects", "2",
        "--data-dir", str(builtin_data.data_dir), "--steps", "2", "--rounds", "1",
        "--no-memory", "--no-compile"], capsys)
    rows = [line.split() for line in lines[1:3]]
    assert [row[0] for row in rows] == ["lift", "bin"]
    for row in rows:
        env_rate, phys_rate, ratio = (float(v) for v in row[4:7])
        assert env_rate > 0 and phys_rate > 0 and ratio == pytest.approx(
            env_rate / phys_rate, abs=0.01)
    assert re.match(rf"bin \(2 objects\) / lift env steps/s, 4 envs, repr com: {NUMBER} ",
                    lines[3])


def test_graspability(builtin_data: Config, tmp_path: Path,
                      capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "rows.csv"
    lines = run_bench("graspability", ["--objects", "builtin_cylinder", "--trials", "1",
                                       "--data-dir", str(builtin_data.data_dir),
                                       "--out", str(out)], capsys)
    assert re.fullmatch(r"### baseline: top base, seed 0 \([01]/1 lifted, [0-9]+ s\)", lines[1])
    row = next(line for line in lines if line.startswith("| builtin_cylinder |"))
    assert len(re.findall(NUMBER, row)) == 6
    assert re.fullmatch(r"baseline: [01]/1 lifted, (1\.00x|n/a \(baseline lifted 0\)) the "
                        r"baseline", lines[-3])
    assert out.read_text().startswith("object,family,trials,lifted,dropped,no_grip,pushed,")
