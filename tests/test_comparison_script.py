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
