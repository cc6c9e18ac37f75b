"""README stays a front page: at most 250 lines, the two commands exactly as CI and a newcomer
run them, and every preset in configs/ in its table (issue 60)."""

from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"

COMMANDS = (
    "scripts/setup.sh && . .venv/bin/activate && geomprep build-all && geomprep show builtin_mug",
    "scripts/setup.sh dev,dvc,gpu && . .venv/bin/activate && python -m pytest -q -n 2",
)


def test_readme_is_short_and_holds_the_two_commands() -> None:
    lines = README.read_text().splitlines()
    assert len(lines) <= 250
    for command in COMMANDS:
        assert command in lines, command


def test_every_preset_has_a_line_in_the_readme_table() -> None:
    rows = [line for line in README.read_text().splitlines() if line.startswith("| `configs/")]
    for preset in sorted((ROOT / "configs").glob("*.toml")):
        assert any(row.startswith(f"| `configs/{preset.name}` |") for row in rows), preset.name
