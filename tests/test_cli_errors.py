"""Both command lines turn a user error into one ``error: ...`` line and exit status 1."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

import geomprep.cli
import trainer.cli
from geomprep.config import Config


@pytest.mark.parametrize(
    "main, argv",
    [
        (geomprep.cli.main, ["geomprep", "--config", "{bad}", "list"]),
        (trainer.cli.main, ["trainer", "run", "--config", "{bad}", "--no-compile"]),
    ],
)
def test_bad_config_is_one_line_error(main, argv, tmp_path: Path, monkeypatch, capsys) -> None:  # noqa: ANN001
    bad = tmp_path / "bad.toml"
    bad.write_text("num_envs = [")
    monkeypatch.setattr(sys, "argv", [a.replace("{bad}", str(bad)) for a in argv])
    with pytest.raises(SystemExit) as exit_info:
        main()
    assert exit_info.value.code == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"error: config file {bad} is not valid TOML")
    assert "\n" not in err


def test_bin_larger_than_the_object_set_is_one_line(
    builtin_data: Config, tmp_path: Path, monkeypatch, capsys  # noqa: ANN001
) -> None:
    # Found when the bin env is built (the object set is resolved there): still one line.
    argv = ["trainer", "run", "--task", "bin", "--bin-objects", "8", "--objects", "builtin",
            "--data-dir", str(builtin_data.data_dir), "--run-dir", str(tmp_path / "run"),
            "--num-envs", "2", "--steps", "8", "--no-compile"]
    monkeypatch.setattr(sys, "argv", argv)
    with pytest.raises(SystemExit) as exit_info:
        trainer.cli.main()
    assert exit_info.value.code == 1
    assert capsys.readouterr().err.strip() == (
        "error: bin of 8 objects: the object set 'builtin' has only 7; lower --bin-objects or "
        "pass a larger --objects"
    )
