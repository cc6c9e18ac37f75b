"""scripts/chunked_run.sh: a long run in chunks kept in results/ (issues 62, 63). A chunk short
of the budget is saved and evaluated apart; the next call continues it from the saved copy and,
at the budget, evaluates it into eval/."""

from __future__ import annotations

import csv
import os
import shutil
import subprocess
import sys
from pathlib import Path

from geomprep.config import Config

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "scripts" / "chunked_run.sh"

TINY = """objects = "builtin_box"
num_envs = 4
max_steps = 12
compile = false
[ppo]
frames_per_env = 8
minibatches = 2
min_minibatch = 1
epochs = 1
hidden = [16, 16]
[run]
total_steps = 640
checkpoint_every = 1
"""


def _call(tmp: Path, data: Path, *args: str, env: dict[str, str] | None = None
          ) -> subprocess.CompletedProcess:
    env = {**os.environ, "DATA_DIR": str(data), "RUNS_DIR": str(tmp / "runs"),
           "CHUNK_EPISODES": "1", "FINAL_EPISODES": "1",
           "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}",
           **(env or {})}
    return subprocess.run([str(SCRIPT), *args], capture_output=True, text=True, env=env,
                          timeout=600, cwd=tmp)


def _rows(path: Path) -> list[dict]:
    return list(csv.DictReader(path.open()))


def test_chunks_continue_from_results_and_end_evaluated(builtin_data: Config,
                                                        tmp_path: Path) -> None:
    config = tmp_path / "tiny.toml"
    config.write_text(TINY)
    results = tmp_path / "results"
    # A budget of 10 minutes is not reached by a first chunk of ~0.1 second: a chunk evaluation.
    done = _call(tmp_path, builtin_data.data_dir, str(results), "tiny", str(config), "0.002",
                 "10")
    assert done.returncode == 0, done.stderr[-3000:]
    saved = results / "runs" / "tiny"
    assert (saved / "checkpoints" / "last.pt").is_file() and (saved / "config.json").is_file()
    first = _rows(saved / "metrics.csv")
    assert 1 <= len(first) < 20
    chunk_evals = list(saved.glob("eval-*M"))
    assert len(chunk_evals) == 1 and (chunk_evals[0] / "per_object.csv").is_file()
    assert not (saved / "eval").exists()
    # The local copy is gone (a new session): the next chunk continues from the saved one,
    # reaches total_steps and is evaluated into eval/.
    shutil.rmtree(tmp_path / "runs")
    done = _call(tmp_path, builtin_data.data_dir, str(results), "tiny", str(config), "5", "10")
    assert done.returncode == 0, done.stderr[-3000:]
    rows = _rows(saved / "metrics.csv")
    assert rows[: len(first)] == first and int(rows[-1]["env_steps"]) >= 640
    assert (saved / "eval" / "per_object.csv").is_file()
    # the machines of both launches are kept with it, each from the iteration it trained first
    launches = _rows(saved / "launches.csv")
    assert [int(r["first_iteration"]) for r in launches] == [1, len(first) + 1]

    # STEPS extends the budget: not in place (its eval/ is of the old budget), in a copy.
    extend = {"STEPS": "1280"}
    done = _call(tmp_path, builtin_data.data_dir, str(results), "tiny", str(config), "5", "10",
                 env=extend)
    assert done.returncode == 2 and "extend a copy without eval/" in done.stderr
    shutil.copytree(saved, results / "runs" / "tiny-ext", ignore=shutil.ignore_patterns("eval"))
    done = _call(tmp_path, builtin_data.data_dir, str(results), "tiny-ext", str(config), "5",
                 "10", env=extend)
    assert done.returncode == 0, done.stderr[-3000:]
    longer = _rows(results / "runs" / "tiny-ext" / "metrics.csv")
    assert longer[: len(rows)] == rows and 1280 <= int(longer[-1]["env_steps"]) < 1280 + 64
    assert (results / "runs" / "tiny-ext" / "eval" / "per_object.csv").is_file()


def test_bad_arguments_are_one_line(tmp_path: Path) -> None:
    assert subprocess.run(["bash", "-n", str(SCRIPT)], capture_output=True).returncode == 0
    done = subprocess.run([str(SCRIPT)], capture_output=True, text=True)
    assert done.returncode == 2 and done.stderr.startswith("usage: scripts/chunked_run.sh")
    done = subprocess.run([str(SCRIPT), str(tmp_path), "x", str(tmp_path / "none.toml"), "1",
                           "2"], capture_output=True, text=True)
    assert done.returncode == 2 and "none.toml: no such config" in done.stderr
    done = subprocess.run([str(SCRIPT), str(tmp_path), "x", "c.toml", "ten", "2"],
                          capture_output=True, text=True)
    assert done.returncode == 2 and "ten: MINUTES and BUDGET_MINUTES are numbers" in done.stderr
