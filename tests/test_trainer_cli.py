"""The ``trainer`` command line without training: it starts fast (no torch at import), and bad
options and paths are one ``error:`` line with exit status 1. (Runs: tests/test_ppo.py.)"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

import trainer.cli
import trainer.ppo
from trainer.config import config_dict, load_train_config


def test_importing_the_cli_does_not_import_torch() -> None:
    # torch, TorchRL and MuJoCo take seconds to import: --help and a mistyped option must not
    # wait for them.
    code = (
        "import sys, trainer.cli; "
        "print(sorted(m for m in ('torch', 'torchrl', 'tensordict', 'mujoco') "
        "if m in sys.modules))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=120
    )
    assert out.stdout.strip() == "[]"


def invoke(argv: list[str], monkeypatch: pytest.MonkeyPatch, capsys) -> tuple[int, str]:  # noqa: ANN001
    """Run the real entry point (as the installed ``trainer`` script does): exit code, stderr."""
    monkeypatch.setattr(sys, "argv", ["trainer", *argv])
    try:
        trainer.cli.main()
        code = 0
    except SystemExit as exc:
        code = int(exc.code or 0)
    return code, capsys.readouterr().err.strip()


@pytest.mark.parametrize(
    "argv, expected",
    [
        (["run", "--steps", "0"], "error: --steps 0: must be >= 1"),
        (["run", "--steps", "-5"], "error: --steps -5: must be >= 1"),
        (["run", "--seed", "-1"], "error: --seed -1: must be >= 0"),
        (["run", "--num-envs", "0"], "error: --num-envs 0: must be >= 1"),
        (["run", "--device", "bogus"], "error: --device bogus: not a torch device: use cpu or"),
        (["run", "--resume", "nowhere", "--num-envs", "4"],
         "error: --num-envs cannot change a resumed run"),
        (["run", "--resume", "nowhere", "--no-compile"],
         "error: --no-compile cannot change a resumed run"),
        (["run", "--resume", "nowhere"], "error: nowhere: no such run directory"),
        (["eval", "nowhere"], "error: nowhere: no such run directory"),
        (["eval", ".", "--episodes-per-object", "0"], "error: --episodes-per-object 0: must be"),
        (["eval", "."], "error: . is not a run directory (no config.json)"),
        (["play", "nowhere", "--object", "x"], "error: nowhere: no such run directory"),
        (["play", ".", "--object", "x", "--episodes", "0"], "error: --episodes 0: must be >= 1"),
        (["report", "nowhere"], "error: nowhere: no such run directory"),
        (["demo", "--trials", "0"], "error: --trials 0: must be >= 1"),
    ],
)
def test_bad_input_is_one_line(
    argv: list[str], expected: str, monkeypatch: pytest.MonkeyPatch, capsys, tmp_path: Path  # noqa: ANN001
) -> None:
    monkeypatch.chdir(tmp_path)
    code, err = invoke(argv, monkeypatch, capsys)
    assert code == 1 and err.startswith(expected) and "\n" not in err, err


def test_cuda_without_a_gpu_is_one_line(monkeypatch: pytest.MonkeyPatch, capsys) -> None:  # noqa: ANN001
    import torch

    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    code, err = invoke(["run", "--device", "cuda"], monkeypatch, capsys)
    assert code == 1 and err == (
        "error: --device cuda: no CUDA device is available (torch.cuda.is_available() is "
        "False): use --device cpu"
    )


def test_compile_flag_overrides_the_config_only_when_given(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys  # noqa: ANN001
) -> None:
    seen = []
    monkeypatch.setattr(trainer.ppo, "train", lambda cfg, run_dir, **kw: seen.append(cfg))
    config = tmp_path / "c.toml"
    config.write_text("compile = true\n")
    common = ["run", "--config", str(config), "--run-dir", str(tmp_path / "r")]
    assert invoke(common, monkeypatch, capsys)[0] == 0
    assert invoke([*common, "--no-compile"], monkeypatch, capsys)[0] == 0
    assert invoke(["run", "--run-dir", str(tmp_path / "r")], monkeypatch, capsys)[0] == 0
    assert invoke(["run", "--compile", "--run-dir", str(tmp_path / "r")], monkeypatch, capsys)[0] == 0  # noqa: E501
    # The config's value, the flag's, the one default (EnvConfig's), the flag's.
    assert [cfg.env.compile for cfg in seen] == [True, False, False, True]


def test_resume_checks_steps_and_needs_a_checkpoint(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys  # noqa: ANN001
) -> None:
    # A run killed before its first checkpoint: --steps is checked like the file's value, and
    # there is nothing to resume from.
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    (run_dir / "config.json").write_text(json.dumps(config_dict(load_train_config())))
    code, err = invoke(["run", "--resume", str(run_dir), "--steps", "0"], monkeypatch, capsys)
    assert code == 1 and err == "error: --steps 0: must be >= 1"
    code, err = invoke(["run", "--resume", str(run_dir)], monkeypatch, capsys)
    assert code == 1 and err.startswith(f"error: {run_dir}: no checkpoint yet"), err
