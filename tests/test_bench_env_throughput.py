"""bench/env_throughput.py --policy: the run's own env config driven by its trained policy, one
more configuration per --variant, timed in the same rounds, with each one's contact load."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest

from geomprep.config import Config
from tests.tiny_runs import script, tiny_run

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "bench" / "env_throughput.py"


def bench(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(SCRIPT), *args],
                          capture_output=True, text=True, cwd=ROOT, timeout=600)


def bench_here(
    args: list[str], monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> tuple[int, str]:
    """The script's ``main`` in this process (no interpreter to start, no torch to import):
    (exit status, stderr) as its command line would end, a ``SystemExit`` message printed as
    Python prints it; any other exception propagates (a traceback on the command line)."""
    import torch

    spec = importlib.util.spec_from_file_location("env_throughput", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    monkeypatch.setattr(sys, "argv", [str(SCRIPT), *args])
    threads = torch.get_num_threads()
    try:
        module.main()
        code, message = 0, ""
    except SystemExit as exc:
        code, message = (1, f"{exc.code}\n") if isinstance(exc.code, str) else (exc.code, "")
    finally:
        torch.set_num_threads(threads)  # main sets 1 for its timings
    return code, capsys.readouterr().err + message


def test_policy_driven_rows_per_variant(builtin_data: Config, tmp_path: Path) -> None:
    run = tiny_run(builtin_data, tmp_path / "run", "builtin_box", compile=False)
    done = bench("--policy", str(run.path), "--envs", "3", "--advance", "4", "--steps", "2",
                 "--rounds", "2", "--variant", "physics.noslip_iterations=0")
    assert done.returncode == 0, done.stderr[-2000:]
    lines = done.stdout.splitlines()
    assert lines[0].startswith(f"{run.path}: lift, 1 objects, repr bbox, 3 envs, cpu on cpu")
    # each configuration's line as soon as it is built (a device call's deadline keeps them)
    built = [line for line in lines if line.startswith("  built and timed once")]
    assert [line.rsplit(": ", 1)[1] for line in built] == ["default",
                                                           "physics.noslip_iterations=0"]
    header = next(i for i, line in enumerate(lines) if line.startswith("policy+env steps/s"))
    rows = [line.split() for line in lines[header + 1:header + 3]]
    assert rows[0][-1] == "default" and rows[1][-1] == "physics.noslip_iterations=0"
    assert float(rows[0][-2]) == 1.0  # the first configuration against itself
    for row in rows:
        env_rate, phys_rate, contacts = float(row[0]), float(row[1]), float(row[4])
        assert 0 < env_rate < phys_rate  # the env step does the physics and more
        assert contacts >= 1.0  # the box rests on the table in every env, at least


def test_an_interrupted_policy_bench_prints_what_it_timed(
    builtin_data: Config, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """A device call's deadline interrupts the bench (SIGINT) while a later configuration is
    being built: the configurations timed so far still get their table, marked interrupted."""
    run = tiny_run(builtin_data, tmp_path / "run", "builtin_box", compile=False)
    module = script("bench", "env_throughput")
    built = []

    class Interrupted(module.PolicyStepper):
        def __init__(self, *args: object) -> None:
            if built:
                raise KeyboardInterrupt  # as SIGINT arrives while the second one is built
            built.append(1)
            super().__init__(*args)

    monkeypatch.setattr(module, "PolicyStepper", Interrupted)
    monkeypatch.setattr(sys, "argv", [str(SCRIPT), "--policy", str(run.path), "--envs", "3",
                                      "--advance", "2", "--steps", "2", "--rounds", "2",
                                      "--variant", "physics.noslip_iterations=0"])
    import torch

    threads = torch.get_num_threads()
    try:
        module.main()
    finally:
        torch.set_num_threads(threads)
    lines = capsys.readouterr().out.splitlines()
    header = next(i for i, line in enumerate(lines) if line.startswith("policy+env steps/s"))
    assert lines[header + 1].split()[-1] == "default"
    assert float(lines[header + 1].split()[0]) > 0
    assert lines[-1] == "interrupted: 1 of 2 configurations timed, 1 round(s) each in the table"


def test_unknown_run_or_key_is_one_line(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    code, err = bench_here(["--policy", str(tmp_path / "nowhere")], monkeypatch, capsys)
    assert code != 0 and "Traceback" not in err
    assert "--policy" in err.strip().splitlines()[-1]


def test_a_bad_set_or_variant_is_one_line_before_anything_is_built(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    for option, text in (("--set", "physics.substep=0"), ("--variant", "physics.sleep=maybe")):
        code, err = bench_here([option, text], monkeypatch, capsys)
        err = err.strip()
        assert code != 0 and "\n" not in err, err
        assert err.startswith(f"env_throughput: {option} {text}: "), err
