"""The parts of a run's state (trainer.training): the run directory and its metrics file, the
checkpointed TrainState, and stopping a run on SIGINT / SIGTERM with a checkpoint."""

from __future__ import annotations

import csv
import dataclasses
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
import torch

from geomprep.config import Config
from tests.test_ppo import OBJECTS, main, metrics_iterations, tiny_config
from trainer.errors import TrainerError
from trainer.ppo import PPOUpdate, make_agent, make_train_state, minibatch_size, train
from trainer.tasks import make_env
from trainer.training.checkpoint import (
    TrainState,
    load_last_checkpoint,
    restore_global_rng,
    write_checkpoint,
)
from trainer.training.run_dir import METRICS, RunDir, changed_keys
from trainer.training.stop import StopSignals


def row(iteration: int) -> dict[str, float]:
    return {key: float(iteration) for key in METRICS} | {"iteration": iteration}


def test_metrics_rows_after_a_checkpoint_are_dropped_on_resume(tmp_path: Path) -> None:
    run = RunDir(tmp_path / "run")
    run.path.mkdir()
    for iteration in (1, 2, 3):
        run.append_metrics({**row(iteration), "not_a_column": 0.0})
    run.truncate_metrics(2)
    rows = list(csv.DictReader(run.metrics.read_text().splitlines()))
    assert [r["iteration"] for r in rows] == ["1", "2"] and list(rows[0]) == list(METRICS)
    run.truncate_metrics(0)
    assert run.metrics.read_text().splitlines() == [",".join(METRICS)]


def test_a_fresh_run_needs_overwrite_to_replace_one(tmp_path: Path) -> None:
    run = RunDir(tmp_path / "run")
    run.make_room(overwrite=False)  # nothing there yet
    run.path.mkdir()
    run.append_metrics(row(1))
    (run.path / "notes.txt").write_text("mine")
    with pytest.raises(TrainerError, match="already holds a run: start it afresh"):
        run.make_room(overwrite=False)
    run.make_room(overwrite=True)
    assert not run.holds_run() and (run.path / "notes.txt").read_text() == "mine"


def test_changed_keys_are_dotted_and_sorted() -> None:
    a = {"run": {"seed": 1, "total_steps": 5}, "env": {"reward": {"h_bar": 0.2}}}
    b = {"run": {"seed": 2, "total_steps": 5}, "env": {"reward": {"h_bar": 0.1}}, "x": 1}
    assert changed_keys(a, b) == ["env.reward.h_bar", "run.seed", "x"]


@pytest.fixture
def interactive_sigint() -> Iterator[None]:
    """SIGINT as in an interactive process (pytest-xdist's workers ignore it)."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, previous)


def test_stop_signals_defer_the_signal_to_the_end(interactive_sigint: None) -> None:
    seen: list[int] = []
    previous = signal.signal(signal.SIGTERM, lambda signum, frame: seen.append(signum))
    try:
        with StopSignals() as stop:
            os.kill(os.getpid(), signal.SIGTERM)
            assert stop.received == signal.SIGTERM and seen == []
            os.kill(os.getpid(), signal.SIGTERM)  # a second one: the earlier handler's
            assert seen == [signal.SIGTERM]
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
        stop.reraise()
        assert seen == [signal.SIGTERM] * 2
        with StopSignals() as quiet:
            pass
        quiet.reraise()  # nothing received: nothing delivered
        assert seen == [signal.SIGTERM] * 2
        signal.signal(signal.SIGINT, signal.SIG_IGN)  # an ignored signal stays ignored
        with StopSignals() as background:
            os.kill(os.getpid(), signal.SIGINT)
            assert background.received is None
        assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN
    finally:
        signal.signal(signal.SIGTERM, previous)


def _fresh_state(run: RunDir) -> TrainState:
    cfg = run.load_config()
    env = make_env(cfg.env, seed=cfg.run.seed)
    agent = make_agent(env, cfg.ppo)
    update = PPOUpdate.build(agent, cfg.ppo, minibatch_size(cfg))
    return make_train_state(cfg, env, agent, update.optimizer)


def assert_same(a: object, b: object, where: str = "") -> None:
    """Equal values, tensors equal element for element, nested."""
    if isinstance(a, dict):
        assert isinstance(b, dict) and list(a) == list(b), where
        for key in a:
            assert_same(a[key], b[key], f"{where}.{key}")
    elif isinstance(a, torch.Tensor):
        assert torch.equal(a, b), where
    elif hasattr(a, "keys") and hasattr(a, "items"):  # a TensorDict
        assert set(a.keys()) == set(b.keys()), where
        for key in a.keys():  # noqa: SIM118 (iterating a TensorDict walks its batch)
            assert_same(a[key], b[key], f"{where}.{key}")
    elif isinstance(a, (list, tuple)):
        assert len(a) == len(b), where
        for k, (x, y) in enumerate(zip(a, b, strict=True)):
            assert_same(x, y, f"{where}[{k}]")
    elif hasattr(a, "shape"):  # a numpy array
        assert (a == b).all(), where
    else:
        assert a == b, where


def test_train_state_reads_a_checkpoint_back_as_written(
    builtin_data: Config, tmp_path: Path
) -> None:
    """A checkpoint loaded into a fresh TrainState gives back the same dict (keys in order,
    every tensor equal) once the envs reset into its snapshot; one from before the lift
    curriculum and the per-object counters (no h_bar, target_outcomes, object_outcomes) loads
    with the task's h_bar and nothing recorded."""
    run = train(tiny_config(builtin_data.data_dir, iterations=2), tmp_path / "run",
                progress=False)
    written = load_last_checkpoint(run)
    state = _fresh_state(run)
    state.load_state_dict(written)
    restore_global_rng(written, state.env.device)
    state.env.reset()
    assert_same(state.state_dict(), written)

    older = {k: v for k, v in written.items()
             if k not in ("h_bar", "target_outcomes", "object_outcomes")}
    state = _fresh_state(run)
    state.load_state_dict(older)
    assert state.curriculum.h_bars == [0.2, 0.2] and not state.curriculum.outcomes
    assert state.episodes.objects.state_dict() == {}
    assert state.iteration == 2 and list(state.episodes.outcomes) == written["outcomes"]
    write_checkpoint(run, state.state_dict())  # iteration 2 again, now with all the keys
    assert load_last_checkpoint(run)["object_outcomes"] == {}


def test_sigterm_stops_a_run_with_a_checkpoint_and_resume_goes_on_bit_for_bit(
    builtin_data: Config, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys  # noqa: ANN001
) -> None:
    """``timeout`` sends SIGTERM: the run ends at the end of its iteration with a checkpoint
    (none is due: checkpoint_every is 1000), then dies of the signal; resumed, it continues
    exactly as a run that never stopped."""
    config = tmp_path / "tiny.toml"
    config.write_text(
        "max_steps = 20\n[ppo]\nframes_per_env = 8\nminibatches = 2\nmin_minibatch = 1\n"
        "epochs = 1\nhidden = [32, 32, 32]\n[run]\ncheckpoint_every = 1000\nseed = 3\n"
    )
    run = RunDir(tmp_path / "stopped")
    argv = ["run", "--repr", "com", "--objects", OBJECTS, "--num-envs", "4", "--steps",
            str(32 * 10_000), "--run-dir", str(run.path), "--config", str(config),
            "--data-dir", str(builtin_data.data_dir), "--no-compile"]
    process = subprocess.Popen(
        [sys.executable, "-m", "trainer.cli", *argv], stdout=subprocess.PIPE,
        stderr=subprocess.PIPE, text=True, env={**os.environ, "PYTHONPATH": os.getcwd()},
    )
    deadline = time.monotonic() + 300
    while not run.metrics.is_file() and process.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    process.send_signal(signal.SIGTERM)
    out, err = process.communicate(timeout=120)
    assert process.returncode == -signal.SIGTERM, err
    done = metrics_iterations(run.path)
    assert 1 <= len(done) < 10_000 and done == list(range(1, len(done) + 1))
    assert torch.load(run.last, weights_only=False)["iteration"] == done[-1]
    assert f"stopped: SIGTERM ({32 * done[-1]:,} env steps, iteration {done[-1]}" in out

    code, _, err = main(["run", "--resume", str(run.path), "--steps", str(32 * (done[-1] + 1))],
                        monkeypatch, capsys)
    assert code == 0, err
    assert metrics_iterations(run.path) == [*done, done[-1] + 1]
    straight = train(run.load_config(), tmp_path / "straight", progress=False)
    a = torch.load(straight.last, weights_only=False)
    b = torch.load(run.last, weights_only=False)
    assert a["iteration"] == b["iteration"] == done[-1] + 1
    for key in ("agent", "optimizer", "shuffle_rng", "torch_rng", "episode_return", "env"):
        assert_same(a[key], b[key], key)


def test_ctrl_c_stops_a_run_with_a_checkpoint_then_interrupts(
    builtin_data: Config, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
    interactive_sigint: None,
) -> None:
    """In the process itself: SIGINT during iteration 1 ends the run after it (checkpoint
    written), then raises KeyboardInterrupt as Ctrl-C does."""
    cfg = tiny_config(builtin_data.data_dir, iterations=4)
    cfg = dataclasses.replace(cfg, run=dataclasses.replace(cfg.run, checkpoint_every=1000))
    update = PPOUpdate.__call__

    def interrupted(self: PPOUpdate, *args: object) -> dict[str, float]:
        os.kill(os.getpid(), signal.SIGINT)
        return update(self, *args)

    monkeypatch.setattr(PPOUpdate, "__call__", interrupted)
    with pytest.raises(KeyboardInterrupt):
        train(cfg, tmp_path / "run", progress=False)
    assert metrics_iterations(tmp_path / "run") == [1]
    assert torch.load(RunDir(tmp_path / "run").last, weights_only=False)["iteration"] == 1
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
