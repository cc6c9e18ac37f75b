"""Research scripts: scripts/home_heights.py (the per-object home heights of ``[robot]
home_above_objects``) and scripts/early_lifts.py (what the initial policy's low lifts are)."""

from __future__ import annotations

import sys
from pathlib import Path

from geomprep.config import Config

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))

import home_heights  # noqa: E402


def test_home_heights_lists_each_object(builtin_data: Config) -> None:
    lines = home_heights.main(["builtin_dice,builtin_cylinder", str(builtin_data.data_dir)])
    rows = {line.split(" | ")[0]: line.split(" | ") for line in lines[2:]}
    assert rows["builtin_dice"][1] == "0"  # a lying dice never reaches the hand at 0.14 m
    assert int(rows["builtin_cylinder"][1]) > 0  # a standing cylinder does: raised
    low, _, high = (float(x) for x in rows["builtin_cylinder"][2].split(" / "))
    assert low >= 0.14 and high > 0.14


def test_tilt_between_orientations() -> None:
    """scripts/early_lifts.py measures how far an object turned: a quarter turn about any axis
    is 90 degrees, no turn 0."""
    import math

    import torch
    from early_lifts import tilt_degrees

    half = math.sqrt(0.5)
    before = torch.tensor([[1.0, 0, 0, 0], [1.0, 0, 0, 0], [half, 0, half, 0]])
    after = torch.tensor([[half, half, 0, 0], [1.0, 0, 0, 0], [half, 0, half, 0]])
    torch.testing.assert_close(tilt_degrees(before, after), torch.tensor([90.0, 0.0, 0.0]),
                               atol=1e-3, rtol=0)

