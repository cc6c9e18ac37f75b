"""The reports under results/ show what they name: every video or figure a report points at is
in the repository (until 2026-11-26 ``*.mp4`` was git-ignored and ten videos that reports
described were never committed; those few are listed here and their reports say so)."""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "results"

MEDIA = re.compile(r"(?<![\w/.-])((?:\.\./|results/)?[\w.-]+(?:/[\w.-]+)*\.(?:mp4|png|gif))")
CODE = re.compile(r"^[ \t]*```.*?^[ \t]*```|^ {4,}\S[^\n]*", re.S | re.M)
"""Fenced code blocks and indented (4 spaces) code lines."""

LOST = {
    "results/cpu-bin5-builtin/mug.mp4",
    "results/cpu-lift-clearance-2026-11-26/duplo.mp4",
    "results/cpu-home-2026-11-26/cube-above.mp4",
    "results/cpu-perobject-2026-11-26/apple.mp4",
    "results/cpu-perobject-2026-11-26/ball-candidate.mp4",
    "results/cpu-perobject-2026-11-26/cups.mp4",
    "results/cpu-perobject-2026-11-26/dice-seed1.mp4",
    "results/cpu-table1-together-2026-11-26/tuna.mp4",
}
"""Videos that reports describe but that were never committed (their runs' checkpoints were not
kept either); each report says so."""


def named_media(readme: Path) -> set[str]:
    """The media files a report names, as paths from the repository root: every ``results/...``
    path, and outside code blocks (where commands write to the working directory) every path
    relative to the report's folder."""
    text = readme.read_text()
    names = {name for name in MEDIA.findall(text) if name.startswith("results/")}
    for name in MEDIA.findall(CODE.sub("", text)):
        if not name.startswith("results/"):
            names.add((readme.parent / name).resolve().relative_to(ROOT).as_posix())
    return names


def media_by_report() -> dict[Path, set[str]]:
    """Each results report (the index and every folder's README) and the media it names."""
    reports = sorted(RESULTS.glob("*/README.md")) + [RESULTS / "README.md"]
    return {readme: named_media(readme) for readme in reports}


def test_every_video_and_figure_a_report_names_is_committed() -> None:
    by_report = media_by_report()
    assert len(by_report) > 20
    named = set().union(*by_report.values())
    missing = sorted(n for n in named if not (ROOT / n).is_file() and n not in LOST)
    assert not missing, f"reports name media that are not in the repository: {missing}"
    assert named >= LOST, "a lost video is no longer named: drop it from LOST"
    assert not [n for n in LOST if (ROOT / n).is_file()], "a lost video is back: drop it from LOST"


def test_reports_say_which_videos_were_lost() -> None:
    by_report = media_by_report()
    for name in sorted(LOST):
        readers = [readme for readme, names in by_report.items() if name in names]
        assert any("not in the repository" in r.read_text() for r in readers), name


def test_videos_under_results_are_not_ignored_by_git() -> None:
    if not (ROOT / ".git").exists() or shutil.which("git") is None:
        pytest.skip("not a git checkout")

    def ignored(path: str) -> bool:
        return subprocess.run(["git", "check-ignore", "-q", path], cwd=ROOT).returncode == 0

    assert not ignored("results/some-run/grasp.mp4")
    assert ignored("runs/some-run/grasp.mp4") and ignored("grasp.mp4")


def test_reports_and_logs_hold_only_relative_paths() -> None:
    """Committed results name files relative to the repository, never a machine's directories."""
    absolute = re.compile(r"(?<![\w.])/(?:work|tmp|home|root|Users)/")
    offenders = [path.relative_to(ROOT).as_posix()
                 for path in sorted(RESULTS.rglob("*"))
                 if path.suffix in {".md", ".log", ".csv", ".json", ".toml", ".txt"}
                 and absolute.search(path.read_text(errors="replace"))]
    assert not offenders, f"absolute paths in {offenders}"
