"""The ``geomprep`` command line: one line per problem and never a traceback, workers that die
with the build, ``show`` of a partly built object, and a fast start."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import trimesh

from geomprep import cli, importer, pipeline
from geomprep.config import Config
from tests.built_data import copy_built

try:
    import psutil
except ImportError:  # the /proc fallback below
    psutil = None


@pytest.fixture()
def box_data(tmp_path: Path, builtin_data: Config) -> Config:
    return copy_built(builtin_data, tmp_path / "data")


def _geomprep(*args: str, timeout: float = 600) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "geomprep.cli", *args],
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def _assert_one_error_line(result: subprocess.CompletedProcess, *fragments: str) -> str:
    assert result.returncode == 1, result.stderr
    assert "Traceback" not in result.stdout + result.stderr
    errors = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(errors) == 1 and errors[0].startswith("error: "), result.stderr
    for fragment in fragments:
        assert fragment in errors[0]
    return errors[0]


# ---- one line, once, never a traceback -------------------------------------------------------


def test_failed_object_is_reported_once(tmp_path):
    src = tmp_path / "src"
    src.mkdir()
    trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]]).export(src / "flat.obj")
    cfg = Config(data_dir=tmp_path / "data")
    importer.import_directory(src, cfg.raw_dir)
    result = _geomprep(
        "--data-dir", str(cfg.data_dir), "build-all", "--objects", "flat", "--no-progress"
    )
    line = _assert_one_error_line(result, "flat", "metres")
    assert (result.stdout + result.stderr).count(line.removeprefix("error: flat: ")) == 1
    # One stage of it: the error, and no output path named as if the stage had written it.
    result = _geomprep("--data-dir", str(cfg.data_dir), "mesh", "flat")
    _assert_one_error_line(result, "flat", "metres")
    assert "mesh.h5" not in result.stdout and "1 objects failed" in result.stdout


def test_empty_ycb_set_is_one_line(tmp_path):
    """No YCB object imported: 'build-all --objects ycb' says so instead of building nothing
    and exiting 0."""
    result = _geomprep("--data-dir", str(tmp_path / "data"), "build-all", "--objects", "ycb")
    _assert_one_error_line(result, "the object set 'ycb' is empty", "geomprep fetch")


def test_file_system_errors_are_one_line(box_data, tmp_path):
    not_a_dir = tmp_path / "plain_file"
    not_a_dir.write_text("")
    listed = _geomprep("--data-dir", str(not_a_dir / "data"), "list")
    _assert_one_error_line(listed, str(not_a_dir))

    shown = _geomprep(
        "--data-dir",
        str(box_data.data_dir),
        "show",
        "builtin_box",
        "--out",
        str(not_a_dir / "x.png"),
    )
    assert "Traceback" not in shown.stderr
    _assert_one_error_line(shown, "cannot write the preview", "--out")


def test_empty_object_list_is_one_line(box_data):
    result = _geomprep("--data-dir", str(box_data.data_dir), "build-all", "--objects", ",")
    _assert_one_error_line(result, "no object names")


# ---- worker processes ------------------------------------------------------------------------


def _descendants(pid: int) -> list[int]:
    """Live processes below ``pid`` (zombies count as gone: they hold no memory)."""
    if psutil is not None:
        try:
            children = psutil.Process(pid).children(recursive=True)
        except psutil.NoSuchProcess:
            return []
        return [c.pid for c in children if c.is_running() and c.status() != psutil.STATUS_ZOMBIE]
    parents: dict[int, int] = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if fields[0] != "Z":
            parents[int(stat.parent.name)] = int(fields[1])
    found, frontier = [], [pid]
    while frontier:
        kids = [p for p, parent in parents.items() if parent in frontier]
        found += kids
        frontier = kids
    return found


def _alive(pids: list[int]) -> list[int]:
    if psutil is not None:
        alive = []
        for pid in pids:
            try:
                if psutil.Process(pid).status() != psutil.STATUS_ZOMBIE:
                    alive.append(pid)
            except psutil.NoSuchProcess:
                pass
        return alive
    alive = []
    for pid in pids:
        try:
            state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
        except OSError:
            continue
        if state != "Z":
            alive.append(pid)
    return alive


def _start_parallel_build(cfg: Config, capture: bool) -> tuple[subprocess.Popen, list[int]]:
    """Start ``build-all -j 2`` with two SDF stages to do; return it and its worker pids as soon
    as both workers exist (they are still starting up then). Not ``capture``: the output is
    dropped, so no pipe is held open by workers that outlive the build."""
    for name in ("builtin_box", "builtin_dice"):
        pipeline.stage_path(cfg, name, "sdf").unlink()
    proc = subprocess.Popen(
        [sys.executable, "-m", "geomprep.cli", "--data-dir", str(cfg.data_dir), "build-all"]
        + ["--objects", "builtin_box,builtin_dice", "-j", "2", "--no-progress"],
        stdout=subprocess.PIPE if capture else subprocess.DEVNULL,
        stderr=subprocess.PIPE if capture else subprocess.DEVNULL,
        text=True,
        start_new_session=True,  # its own process group, as a shell job would have
        # As from a terminal: a test run started in the background (`cmd &` in a script)
        # inherits an ignored SIGINT, which would make the build ignore the Ctrl-C.
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    deadline = time.monotonic() + 120
    workers: list[int] = []
    while time.monotonic() < deadline and proc.poll() is None:
        workers = [pid for pid in _descendants(proc.pid) if b"spawn_main" in _cmdline(pid)]
        if len(workers) >= 2:
            return proc, workers
        time.sleep(0.01)
    proc.kill()
    proc.wait()
    pytest.fail(f"the build did not start two workers (exit status {proc.returncode})")


def _cmdline(pid: int) -> bytes:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes()
    except OSError:  # exited meanwhile
        return b""


def _kill(pids: list[int]) -> None:
    for pid in pids:
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGKILL)


def _wait_gone(pids: list[int], seconds: float = 10.0) -> list[int]:
    deadline = time.monotonic() + seconds
    while _alive(pids) and time.monotonic() < deadline:
        time.sleep(0.05)
    return _alive(pids)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_killed_build_leaves_no_workers(box_data):
    proc, workers = _start_parallel_build(box_data, capture=False)
    time.sleep(0.5)  # into their start-up (importing the stages takes seconds)
    descendants = _descendants(proc.pid)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    survivors = _wait_gone(descendants)
    _kill(survivors)  # a failing run must not leave them behind
    assert survivors == [], "workers outlived the killed build"
    assert set(workers) <= set(descendants)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_ctrl_c_while_workers_start_prints_aborted_only(box_data):
    proc, workers = _start_parallel_build(box_data, capture=True)
    os.killpg(proc.pid, signal.SIGINT)  # what the terminal does: the whole process group
    try:
        out, err = proc.communicate(timeout=120)
    finally:
        _kill([proc.pid, *_alive(workers)])
    assert proc.returncode == 130
    assert "Traceback" not in out + err and "KeyboardInterrupt" not in err
    assert err.strip() == "aborted"
    assert _wait_gone(workers) == []
    # Nothing half-written counts as done: the rerun completes the SDF stages.
    report = pipeline.build(box_data, ["builtin_box"], jobs=1, progress=False)
    assert not report.failed and ("builtin_box", "sdf") in report.seconds


@pytest.mark.skipif(not hasattr(signal, "pthread_sigmask"), reason="POSIX signal masks")
def test_ctrl_c_during_a_worker_spawn_waits_for_the_spawn_to_finish(request):
    """A Ctrl-C that the kernel hands to another thread of the build (the main thread blocks it)
    must not raise KeyboardInterrupt inside ``sigint_blocked``: raised in the middle of a spawn,
    it left the new worker reading a half-sent start-up message, and its traceback reached the
    terminal (seen once in a full test run). It is raised when the block ends."""
    import threading

    from geomprep import workers

    # As in a terminal: a test run started in the background (`cmd &`) inherits an ignored
    # SIGINT, and the block then rightly raises nothing.
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    request.addfinalizer(lambda: signal.signal(signal.SIGINT, previous))
    steps = []
    with pytest.raises(KeyboardInterrupt), workers.sigint_blocked():
        killer = threading.Thread(target=os.kill, args=(os.getpid(), signal.SIGINT))
        killer.start()
        killer.join()
        for _ in range(100):  # bytecode boundaries, where Python would raise it
            time.sleep(0.001)
        steps.append("the block ran to its end")
    assert steps == ["the block ran to its end"]
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


# ---- show ------------------------------------------------------------------------------------


def test_show_partly_built_object(box_data, tmp_path):
    pipeline.stage_path(box_data, "builtin_dice", "pack").unlink()
    pipeline.stage_path(box_data, "builtin_dice", "sdf").unlink()
    out = tmp_path / "dice.png"
    result = _geomprep(
        "--data-dir", str(box_data.data_dir), "show", "builtin_dice", "--out", str(out)
    )
    assert result.returncode == 0, result.stderr
    lines = result.stdout.splitlines()
    stages = next(line for line in lines if line.startswith("stages"))
    assert "missing sdf, pack" in stages and "done mesh, decompose, mjcf, bbox, sq, pc" in stages
    assert "geomprep build-all --objects builtin_dice" in result.stdout
    assert any(line.startswith("sdf") and "not built" in line for line in lines)
    assert any(line.startswith("hulls") and "vertices" in line for line in lines)
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_show_object_with_nothing_built(box_data):
    result = _geomprep("--data-dir", str(box_data.data_dir), "show", "builtin_mug")
    assert result.returncode == 0, result.stderr
    assert "missing mesh" in result.stdout and "nothing can be drawn" in result.stdout


# ---- start-up --------------------------------------------------------------------------------


def test_cli_import_leaves_the_heavy_libraries_alone():
    heavy = ("open3d", "trimesh", "coacd", "torch", "mujoco", "h5py")
    code = f"import sys, geomprep.cli; print([m for m in {heavy!r} if m in sys.modules])"
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "[]"


def test_stage_commands_are_the_pipeline_stages():
    """cli lists the stages itself (importing pipeline would import them all)."""
    assert tuple(cli.STAGE_HELP) == pipeline.STAGES


def test_set_overrides_a_stage_parameter_after_the_config_file(tmp_path: Path) -> None:
    """``geomprep --set section.key=value`` (as every trainer command's ``--set``): applied
    after the TOML file, values read as TOML; a bad one is one line naming the assignment."""
    from geomprep.config import load_config

    toml = tmp_path / "geomprep.toml"
    toml.write_text("[sdf]\nresolution = 100\nextent_m = 0.8\n")
    cfg = load_config(toml, tmp_path, ("sdf.resolution=64",))
    assert cfg.sdf.resolution == 64 and cfg.sdf.extent_m == 0.8  # the file's other key stays
    assert load_config(None, tmp_path, ()).sdf.resolution == 200
    data = str(tmp_path / "data")
    _assert_one_error_line(_geomprep("--data-dir", data, "--set", "sdf.resolution=abc", "list"),
                           "--set sdf.resolution=abc", "integer")
    _assert_one_error_line(_geomprep("--data-dir", data, "--set", "sdfresolution", "list"),
                           "write KEY=VALUE", "sdf.resolution=64")
