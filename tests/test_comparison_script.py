"""scripts/comparison_runs.sh: the comparison's chunks (results/cpu-comparison-2026-11-29/)."""

from __future__ import annotations

import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "scripts" / "comparison_runs.sh"


def test_the_chunk_script_parses_and_says_how_to_call_it() -> None:
    assert subprocess.run(["bash", "-n", str(SCRIPT)], capture_output=True).returncode == 0
    result = subprocess.run([str(SCRIPT)], capture_output=True, text=True)
    assert result.returncode == 2
    assert "usage: scripts/comparison_runs.sh MINUTES ARM" in result.stderr
    # An unknown network variant stops before anything runs, naming the known ones.
    result = subprocess.run([str(SCRIPT), "1", "pc32-sdf-s0-wide"], capture_output=True,
                            text=True)
    assert result.returncode == 2
    assert "unknown variant 'wide' (known: shared, authors)" in result.stderr
    # Its config is the comparison's: the arms' common budget.
    config = (ROOT / "results" / "cpu-comparison-2026-11-29" / "comparison.toml").read_text()
    assert "total_steps = 4600000" in config


def test_a_variant_arm_passes_its_network_to_trainer_run(tmp_path: Path) -> None:
    """pc128-sdf-s3-authors runs the comparison's config with that arm's representation, reward
    and seed, and the authors' encoder: shared, per-point 16-32-64."""
    fake = tmp_path / "bin" / "trainer"
    fake.parent.mkdir()
    fake.write_text('#!/usr/bin/env bash\necho "trainer $*"\n')  # writes no checkpoint
    fake.chmod(0o755)
    env = {"PATH": f"{fake.parent}:/usr/bin:/bin", "RUNS_DIR": str(tmp_path / "runs")}
    result = subprocess.run([str(SCRIPT), "5", "pc128-sdf-s3-authors"], capture_output=True,
                            text=True, env=env, cwd=ROOT)
    call = next(line for line in result.stdout.splitlines() if line.startswith("trainer run"))
    assert "--config results/cpu-comparison-2026-11-29/comparison.toml" in call
    assert "--repr pc128 --reward sdf --seed 3" in call and "--minutes 5" in call
    assert "--set ppo.shared_encoder=true --set ppo.pointnet_hidden=[16,32,64]" in call
    assert "cmp-pc128-sdf-s3-authors: no checkpoint written" in result.stderr
    assert not (ROOT / "results" / "cpu-comparison-2026-11-29" / "runs"
                / "cmp-pc128-sdf-s3-authors").exists()


def _budget_run(folder: Path, evaluated: bool = True) -> None:
    """A run folder at the comparison's budget as chunked_run.sh keeps it."""
    (folder / "checkpoints").mkdir(parents=True)
    (folder / "checkpoints" / "last.pt").write_bytes(b"checkpoint")
    (folder / "config.json").write_text(
        '{"run": {"total_steps": 4600000}, "env": {"task": "lift"}}')
    (folder / "metrics.csv").write_text("iteration,env_steps,wall_time_s\n562,4603904,6000.0\n")
    (folder / "curriculum.csv").write_text("iteration\n")
    if evaluated:
        (folder / "eval").mkdir()
        (folder / "eval" / "per_object.csv").write_text("object,success\n")


def test_extend_to_continues_a_copy_of_the_arm_and_keeps_the_budget_run(tmp_path: Path) -> None:
    """EXTEND_TO=STEPS copies cmp-ARM (and its local history) to ext-ARM without the budget's
    evaluation and curriculum, and resumes the copy to STEPS; cmp-ARM is left as it was."""
    here = tmp_path / "comparison"
    budget = here / "runs" / "cmp-sq-sdf-s0"
    _budget_run(budget)
    _budget_run(tmp_path / "runs" / "cmp-sq-sdf-s0")
    (here / "comparison.toml").write_text("")
    fake = tmp_path / "bin" / "trainer"
    fake.parent.mkdir()
    fake.write_text('#!/usr/bin/env bash\necho "trainer $*"\n')
    fake.chmod(0o755)
    env = {"PATH": f"{fake.parent}:/usr/bin:/bin", "RUNS_DIR": str(tmp_path / "runs"),
           "COMPARISON_DIR": str(here), "EXTEND_TO": "6900000"}
    result = subprocess.run([str(SCRIPT), "5", "sq-sdf-s0"], capture_output=True, text=True,
                            env=env, cwd=ROOT)
    call = next(line for line in result.stdout.splitlines() if line.startswith("trainer run"))
    assert f"--resume {tmp_path / 'runs' / 'ext-sq-sdf-s0'}" in call
    assert "--steps 6900000" in call and "--minutes 5" in call
    copy = here / "runs" / "ext-sq-sdf-s0"
    assert (copy / "checkpoints" / "last.pt").read_bytes() == b"checkpoint"
    assert not (copy / "curriculum.csv").exists()
    assert not (tmp_path / "runs" / "ext-sq-sdf-s0" / "eval").exists()
    assert (budget / "eval" / "per_object.csv").exists()  # the budget's run untouched
    assert (budget / "curriculum.csv").exists()


def test_extend_to_refuses_an_arm_not_evaluated_at_the_budget(tmp_path: Path) -> None:
    here = tmp_path / "comparison"
    _budget_run(here / "runs" / "cmp-sq-sdf-s1", evaluated=False)
    env = {"PATH": "/usr/bin:/bin", "RUNS_DIR": str(tmp_path / "runs"),
           "COMPARISON_DIR": str(here), "EXTEND_TO": "6900000"}
    result = subprocess.run([str(SCRIPT), "5", "sq-sdf-s1"], capture_output=True, text=True,
                            env=env, cwd=ROOT)
    assert result.returncode == 2
    assert "is not a run evaluated at the budget: run the arm first" in result.stderr
    assert not (here / "runs" / "ext-sq-sdf-s1").exists()
    bad = subprocess.run([str(SCRIPT), "5", "sq-sdf-s1"], capture_output=True, text=True,
                         env={**env, "EXTEND_TO": "7M"}, cwd=ROOT)
    assert bad.returncode == 2 and "a number of env steps" in bad.stderr
