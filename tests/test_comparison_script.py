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
    assert result.returncode == 2 and "unknown variant 'wide' (known: shared)" in result.stderr
    # Its config is the comparison's: the arms' common budget.
    config = (ROOT / "results" / "cpu-comparison-2026-11-29" / "comparison.toml").read_text()
    assert "total_steps = 4600000" in config
