"""scripts/compare_runs.py: reference runs compare equal except for their timings."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

_SPEC = importlib.util.spec_from_file_location(
    "compare_runs", Path(__file__).resolve().parents[1] / "scripts" / "compare_runs.py"
)
compare_runs = importlib.util.module_from_spec(_SPEC)
_SPEC.loader.exec_module(compare_runs)  # type: ignore[union-attr]


def _run(root: Path, wall: str, success: str, table: str = "box 0/4\n") -> Path:
    run = root / "lift"
    (run / "eval").mkdir(parents=True)
    (run / "metrics.csv").write_text(
        f"iteration,wall_time_s,fps,success_rate\n1,{wall},10.0,{success}\n"
    )
    (run / "eval" / "per_object.csv").write_text("object,successes\nbox,0\n")
    (run / "eval" / "table.md").write_text(table)
    return root


def test_timings_may_differ_nothing_else(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    reference = _run(tmp_path / "a", "25.1", "0.5")
    assert compare_runs.main([str(_run(tmp_path / "b", "31.7", "0.5")), str(reference),
                              "--runs", "lift"]) == 0
    assert "lift: IDENTICAL" in capsys.readouterr().out
    changed = _run(tmp_path / "c", "25.1", "0.25", table="box 1/4\n")
    assert compare_runs.main([str(changed), str(reference), "--runs", "lift"]) == 1
    out = capsys.readouterr().out
    assert "lift: DIFFERENT" in out and "row 1 success_rate: 0.25 vs 0.5" in out
    assert "eval/table.md differs" in out
    # the machine, code and time of an evaluation (table.md's last line) are not a result
    other = _run(tmp_path / "d", "25.1", "0.5",
                 table="box 0/4\n\nEvaluated on AMD EPYC with code 0123abcd, 2026-11-30.\n")
    assert compare_runs.main([str(other), str(reference), "--runs", "lift"]) == 0
    assert compare_runs.differences(tmp_path / "none", reference / "lift") == [
        f"{tmp_path / 'none'} holds no metrics.csv"
    ]
