"""Every config key from one source (trainer.config_keys): ``trainer config`` prints them,
docs/config.md is written from them and kept up to date, and each key says in a few lines what
it does and whether the paper states it."""

from __future__ import annotations

import re
import sys
from pathlib import Path

import pytest

import trainer.cli
from geomgrasp.config_schema import field_docs
from trainer.config import load_train_config
from trainer.config_keys import all_keys, markdown

ROOT = Path(__file__).resolve().parents[1]


def invoke(argv: list[str], monkeypatch: pytest.MonkeyPatch, capsys) -> tuple[int, str, str]:  # noqa: ANN001
    """The real entry point (as the installed ``trainer`` script): exit code, stdout, stderr."""
    monkeypatch.setattr(sys, "argv", ["trainer", *argv])
    try:
        trainer.cli.main()
        code = 0
    except SystemExit as exc:
        code = int(exc.code or 0)
    out = capsys.readouterr()
    return code, out.out, out.err.strip()


def test_docs_config_md_is_up_to_date() -> None:
    written = (ROOT / "docs" / "config.md").read_text(encoding="utf-8")
    assert written == markdown(), (
        "docs/config.md is out of date: run trainer config --markdown docs/config.md"
    )


def test_every_key_has_a_short_docstring_whose_links_exist() -> None:
    keys = all_keys()
    assert len(keys) == 118 and len({k.path for k in keys}) == 118
    for key in keys:
        doc = field_docs(key.owner).get(key.name)
        assert doc, f"{key.path} has no docstring"
        assert len(doc.splitlines()) <= 4, f"{key.path}: {len(doc.splitlines())} lines"
        for path in re.findall(r"results/[\w.\-/]*\w", doc):
            assert (ROOT / path).exists(), f"{key.path} links {path}, which does not exist"
    # The history moved to results/: each entry there is a key's.
    evidence = (ROOT / "results" / "config-evidence.md").read_text(encoding="utf-8")
    entries = re.findall(r"^### `([\w.]+)`$", evidence, re.M)
    assert {"run.warmup_objects", "run.init_agent_unseen"} <= set(entries)
    assert set(entries) <= {k.path for k in keys}
    assert "1.06 M env steps on the tuna can" in evidence  # warmup_objects' history, kept


PAPER_KEYS = {
    "num_envs", "task", "representation", "objects", "max_steps", "physics.control_hz",
    "robot.kind", "reward.kind", "reward.h_bar", "reward.c1", "reward.c2", "reward.c3",
    "reward.eps_h", "reward.eps_sdf", "bin.num_objects", "ppo.frames_per_env", "ppo.epochs",
    "ppo.minibatches", "ppo.hidden", "run.total_steps",
}


def test_the_paper_keys_are_marked_and_paper_toml_holds_their_numbers() -> None:
    keys = all_keys()
    assert {k.path for k in keys if k.paper is not None} == PAPER_KEYS
    # Where the paper states one number, configs/paper.toml (the paper's settings) has it.
    paper = load_train_config(ROOT / "configs" / "paper.toml")
    checked = 0
    for key in keys:
        number = re.fullmatch(r"(\d+(?:\.\d+)?)(?: \(.*\))?", key.paper or "")
        if number:
            node = paper.env if key.section not in ("ppo", "run") else paper
            for part in key.path.split("."):
                node = getattr(node, part)
            assert node == float(number.group(1)), key.path
            checked += 1
    assert checked == 13


def test_trainer_config_prints_a_paper_key_and_a_project_key(
    monkeypatch: pytest.MonkeyPatch, capsys  # noqa: ANN001
) -> None:
    code, out, err = invoke(["config", "reward.c3", "noslip"], monkeypatch, capsys)
    assert code == 0 and not err
    lines = out.splitlines()
    assert lines[0].startswith("[physics]  Simulation timing")
    assert re.fullmatch(r"  physics\.noslip_iterations = 5 +an integer >= 0 +ours", lines[1])
    assert lines[2].startswith("      Passes of MuJoCo's no-slip solver")
    assert lines[3] == "" and lines[4].startswith("[reward]  r = c1 /")
    assert re.fullmatch(r"  reward\.c3 = 1\.0 +a number +paper: 1 \(ablation: 0\)", lines[5])
    assert lines[6] == "      Weight of the contact term."
    # --paper: the paper's keys only; every key without arguments.
    code, out, _ = invoke(["config", "--paper"], monkeypatch, capsys)
    assert code == 0 and " ours\n" not in out and out.count("paper: ") == len(PAPER_KEYS)
    code, out, _ = invoke(["config"], monkeypatch, capsys)
    assert code == 0 and out.count("\n      ") == 118
    code, _, err = invoke(["config", "no_such_key"], monkeypatch, capsys)
    assert code == 1 and err == (
        "error: no key matches no_such_key: trainer config with no argument lists them all"
    )


def test_trainer_config_writes_the_markdown(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys  # noqa: ANN001
) -> None:
    out = tmp_path / "docs" / "config.md"
    code, stdout, _ = invoke(["config", "--markdown", str(out)], monkeypatch, capsys)
    assert code == 0 and stdout == f"written: {out}\n"
    assert out.read_text(encoding="utf-8") == markdown()
