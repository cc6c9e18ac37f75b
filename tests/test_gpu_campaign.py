"""The GPU campaign (scripts/gpu_campaign.py, scripts/gpu-campaign.sh): its config is the paper's,
and its device side trains a chunk, brings the files back, and the next chunk continues the run,
here on the CPU with a tiny override (the GPU runs the same script on the packed libraries)."""

from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest
import torch

from geomprep.config import Config
from tests.tiny_runs import script

ROOT = Path(__file__).resolve().parents[1]


def test_campaign_config_is_the_papers() -> None:
    """Every setting of configs/paper.toml holds in the campaign's config, which only adds what
    runs where (objects, representation, backend, data, checkpoints)."""
    paper = tomllib.loads((ROOT / "configs" / "paper.toml").read_text())
    campaign = tomllib.loads((ROOT / "results/gpu-table1-campaign/campaign.toml").read_text())
    for key, value in paper.items():
        if isinstance(value, dict):
            for inner, setting in value.items():
                assert campaign[key][inner] == setting, f"[{key}] {inner}"
        else:
            assert campaign[key] == value, key
    assert campaign["backend"] == "warp" and campaign["device"] == "cuda"
    assert campaign["representation"] == "bbox"
    assert len(campaign["objects"].split(",")) == 10


@pytest.mark.slow
def test_two_chunks_continue_one_run(builtin_data: Config, tmp_path: Path) -> None:
    """Chunk 1 starts the run and brings back checkpoint, metrics, config, eval and a summary;
    ``collect`` files them under results; chunk 2 resumes from the collected checkpoint and its
    metrics continue the same run (iterations 1-2, then 3-4)."""
    override = f"""
objects = "builtin_dice,builtin_box"
backend = "cpu"
device = "cpu"
data_dir = "{builtin_data.data_dir}"
num_envs = 4
max_steps = 10
compile = false
[physics]
noslip_iterations = 0
[ppo]
frames_per_env = 4
minibatches = 1
min_minibatch = 1
epochs = 1
hidden = [16, 16]
[run]
checkpoint_every = 1
"""
    results = tmp_path / "campaign"
    run_dir = results / "run"
    # A kernel cache as Warp would leave it: returned in 15 MB pieces, reassembled by collect.
    kernels = tmp_path / "kernels"
    (kernels / "1.19.0").mkdir(parents=True)
    blob = os.urandom(1_500_000)  # incompressible: two pieces of 1 MB
    (kernels / "1.19.0" / "module.cubin").write_bytes(blob)
    env = dict(os.environ, GPU_CAMPAIGN_STAGE=str(tmp_path / "stage"), GPU_CAMPAIGN_SITE="none",
               GPU_CAMPAIGN_PYTHON=sys.executable, GPU_CAMPAIGN_RUN=str(run_dir),
               GPU_CAMPAIGN_OVERRIDE=override,
               GPU_CAMPAIGN_DEADLINE="400", GPU_CAMPAIGN_PIECE="1000000",
               WARP_CACHE_PATH=str(kernels))

    def chunk(steps: int, out: Path, episodes: int) -> dict:
        out.mkdir()
        done = subprocess.run(
            ["bash", "scripts/gpu-campaign.sh", "run"], cwd=ROOT, capture_output=True,
            text=True, timeout=300, env=dict(env, OUT=str(out), GPU_CAMPAIGN_STEPS=str(steps),
                                             GPU_CAMPAIGN_EPISODES=str(episodes)),
        )
        assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
        returned = sorted(p.name for p in out.iterdir())
        assert returned == ["chunk.log", "chunk.tar", "kcache.tar.xz.0", "kcache.tar.xz.1",
                            "last.pt"]
        assert all(p.stat().st_size <= 16 * 2**20 for p in out.iterdir())
        assert (tmp_path / "stage/kcache.tar.xz").stat().st_size > 1_000_000
        subprocess.run(
            [sys.executable, "scripts/gpu_campaign.py", "collect", str(out), "--results",
             str(results), "--pack-dir", str(tmp_path / "pack")], cwd=ROOT, check=True,
            capture_output=True,
        )
        assert (tmp_path / "pack/kcache/1.19.0/module.cubin").read_bytes() == blob
        # Between chunks only what was collected stays (a fresh machine, a fresh tree).
        for name in ("tb", "eval"):
            subprocess.run(["rm", "-rf", str(run_dir / name)], check=True)
        for stale in (run_dir / "checkpoints").glob("iter_*.pt"):
            stale.unlink()
        return next(csv.DictReader((results / "chunks.csv").read_text().splitlines()[:1]
                                   + (results / "chunks.csv").read_text().splitlines()[-1:]))

    first = chunk(32, tmp_path / "out1", episodes=1)  # 4 envs x 4 frames x 2 iterations
    assert int(first["iteration"]) == 2 and int(first["env_steps"]) == 32
    assert json.loads((results / "eval-iter0002.json").read_text()).keys() == {
        "builtin_dice", "builtin_box"}
    saved = torch.load(run_dir / "checkpoints" / "last.pt", weights_only=False)
    assert saved["iteration"] == 2
    second = chunk(64, tmp_path / "out2", episodes=0)  # no eval: quicker
    assert int(second["iteration"]) == 4 and int(second["env_steps"]) == 64
    rows = list(csv.DictReader((run_dir / "metrics.csv").read_text().splitlines()))
    assert [int(r["iteration"]) for r in rows] == [1, 2, 3, 4]
    launches = list(csv.DictReader((run_dir / "launches.csv").read_text().splitlines()))
    assert [int(r["first_iteration"]) for r in launches] == [1, 3]  # each chunk's machine
    assert json.loads((run_dir / "config.json").read_text())["env"]["num_envs"] == 4
    chunks = list(csv.DictReader((results / "chunks.csv").read_text().splitlines()))
    assert [int(c["iteration"]) for c in chunks] == [2, 4]
    assert not (results / "eval-iter0004.json").exists()


def test_slim_keeps_results_out_of_device_calls_and_unslim_restores(tmp_path: Path) -> None:
    """A device call carries at most 64 MiB of tree; results/ holds the runs' checkpoints.
    slim takes them out of what travels (the campaign's folder stays), touching no file and
    committing nothing; unslim leaves the repository as it was."""
    campaign = script("scripts", "gpu_campaign")

    def git(*args: str) -> str:
        return subprocess.run(["git", *args], cwd=tmp_path, check=True, capture_output=True,
                              text=True).stdout

    git("init", "-q")
    files = {"README.md": 10, "results/run/last.pt": 200_000,
             "results/gpu-table1-campaign/run/last.pt": 30_000}
    for name, size in files.items():
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_bytes(b"x" * size)
    git("add", ".")
    git("-c", "user.name=t", "-c", "user.email=t@t", "commit", "-q", "-m", "m")
    whole = campaign.tree_bytes(tmp_path)
    assert whole == sum(files.values())

    campaign.slim(tmp_path)
    assert campaign.tree_bytes(tmp_path) == 30_010  # the campaign's run travels, the rest not
    assert all((tmp_path / name).is_file() for name in files)
    campaign.slim(tmp_path)  # twice is once
    exclude = tmp_path / git("rev-parse", "--git-path", "info/exclude").strip()
    assert exclude.read_text().count("/results/*") == 1
    campaign.unslim(tmp_path)
    assert campaign.tree_bytes(tmp_path) == whole
    assert git("status", "--porcelain") == ""

    (tmp_path / "README.md").write_text("staged")
    git("add", "README.md")
    with pytest.raises(SystemExit, match="staged"):
        campaign.slim(tmp_path)
