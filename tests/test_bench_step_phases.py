"""bench/step_phases.py: a trained run's policy drives its env, every configuration is timed
phase by phase at those same states, and the contacts are counted by part and geom-type pair."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from geomprep.config import Config
from tests.tiny_runs import tiny_run

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "bench" / "step_phases.py"


def bench(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(SCRIPT), *args],
                          capture_output=True, text=True, cwd=ROOT, timeout=600)


def _section(lines: list[str], title: str) -> dict[str, list[str]]:
    """The rows of the table under ``title``: first column -> the configurations' values."""
    start = next(i for i, line in enumerate(lines) if line.startswith(title)) + 2
    rows = {}
    for line in lines[start:]:
        if not line.strip():
            break
        *key, a, b = line.split()
        rows[" ".join(key)] = [a, b]
    return rows


def test_phases_and_contacts_at_the_same_states(builtin_data: Config, tmp_path: Path) -> None:
    run = tiny_run(builtin_data, tmp_path / "run", "builtin_box", compile=False)
    done = bench("--policy", str(run.path), "--envs", "3", "--advance", "3", "--steps", "2",
                 "--rounds", "2", "--variant", "physics.table_plane=true")
    assert done.returncode == 0, done.stderr[-2000:]
    lines = done.stdout.splitlines()
    assert lines[0].startswith(f"{run.path}: lift, repr bbox, 3 envs, cpu on cpu")
    times = _section(lines, "time by phase")
    assert float(times["step"][0]) > 0 and float(times["narrowphase"][0]) > 0
    assert float(times["step"][0]) >= float(times["solver+noslip"][0])
    ratio = next(line for line in lines if "step / the run's own" in line).split()[-2:]
    assert float(ratio[0]) == 1.0 and float(ratio[1]) > 0  # the baseline against itself
    parts = _section(lines, "contacts per env by part pair")
    # the box rests on the table in every env, in both configurations (the same states)
    assert float(parts["object-static"][0]) >= 1 and float(parts["object-static"][1]) >= 1
    types = _section(lines, "contacts per env by geom-type pair")
    # ... on the table's box, or on the plane of its top that replaces it for the objects
    assert float(types["box-mesh"][0]) >= 1 and float(types["box-mesh"][1]) == 0
    assert float(types["mesh-plane"][1]) >= 1 and float(types["mesh-plane"][0]) == 0


def test_unknown_run_is_one_line(tmp_path: Path) -> None:
    done = bench("--policy", str(tmp_path / "nowhere"))
    assert done.returncode != 0 and "Traceback" not in done.stderr
    assert done.stderr.strip().splitlines()[-1].startswith("step_phases: ")
