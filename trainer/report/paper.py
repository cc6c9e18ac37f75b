"""The paper's numbers the report sets beside ours: Table I (success per object and over all 78
YCB objects) and Table II (env steps and minutes to 90 % and 95 % success), per representation in
the order of its columns (``PAPER_ORDER``)."""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

PAPER_ORDER = ("com", "sdf", "bbox", "sq", "pc32", "pc128", "pc512")
"""The representations in the order of the paper's Table I and II columns / rows."""


_P = PAPER_ORDER
PAPER_TABLE_I: dict[str, dict[str, tuple[float, float]]] = {
    # Table I of the paper ("Variations in lifting success rates for different representations of
    # object geometry", label object_specific_success_rates): final test success, mean and std
    # over seeds, columns COM, SDF, BBox, SQ, PC-32, PC-128, PC-512 (PAPER_ORDER).
    name: dict(zip(_P, cells, strict=True))
    for name, cells in {
        "007_tuna_fish_can": ((0.99, 0.0), *[(1.0, 0.0)] * 6),
        "013_apple": ((1.0, 0.0),) * 7,
        "029_plate": ((0.74, 0.14), (0.95, 0.0), (0.93, 0.02), (0.95, 0.04), (0.5, 0.39),
                      (0.94, 0.03), (0.94, 0.04)),
        "032_knife": ((0.77, 0.07), (0.81, 0.07), (0.96, 0.02), (0.85, 0.1), (0.71, 0.02),
                      (0.9, 0.02), (0.79, 0.06)),
        "053_mini_soccer_ball": ((1.0, 0.0),) * 7,
        "062_dice": ((0.65, 0.3), (0.85, 0.08), (0.95, 0.02), (0.94, 0.01), (0.55, 0.07),
                     (0.86, 0.0), (0.6, 0.12)),
        "065-a_cups": ((0.99, 0.0), *[(1.0, 0.0)] * 6),
        "072-a_toy_airplane": ((0.93, 0.02), (0.99, 0.01), (0.99, 0.01), (0.97, 0.03),
                               (0.95, 0.01), (0.99, 0.0), (0.96, 0.02)),
        "073-g_lego_duplo": ((0.9, 0.01), (0.97, 0.01), (0.99, 0.0), (0.96, 0.02), (0.95, 0.01),
                             (0.99, 0.0), (0.98, 0.01)),
        "077_rubiks_cube": ((1.0, 0.0),) * 7,
    }.items()
}
PAPER_ALL_OBJECTS: dict[str, tuple[float, float]] = dict(zip(_P, (
    # Table I's last row, "All 78 YCB objects".
    (0.95, 0.02), (0.96, 0.01), (0.97, 0.01), (0.96, 0.02), (0.92, 0.03), (0.97, 0.0),
    (0.95, 0.02),
), strict=True))
PAPER_TABLE_II: dict[str, dict[float, tuple[tuple[float, float], tuple[float, float]]]] = {
    # Table II of the paper ("Sample efficiency of different object representations",
    # label sample_efficiency_of_object_representations): per threshold, (env steps in
    # millions, runtime in minutes), each (mean, std) over seeds.
    rep: {0.9: (cells[0], cells[1]), 0.95: (cells[2], cells[3])}
    for rep, cells in zip(_P, (
        ((149, 30), (47, 9), (550, 161), (116, 34)),
        ((134, 5), (72, 3), (276, 51), (152, 28)),
        ((165, 8), (69, 3), (274, 44), (127, 23)),
        ((178, 18), (58, 6), (436, 52), (220, 26)),
        ((196, 15), (52, 4), (474, 170), (178, 63)),
        ((173, 4), (47, 2), (232, 1), (65, 1)),
        ((219, 19), (62, 6), (277, 12), (87, 4)),
    ), strict=True)
}


def paper_overall(representation: str, objects: Iterable[str]) -> tuple[float, str]:
    """The paper's overall success of a representation to set beside ours on ``objects``: its
    Table I mean over the same objects where it lists them all, else its all-78-objects value.
    Returns (value, which of the two it is in words)."""
    objects = sorted(set(objects))
    if objects and all(name in PAPER_TABLE_I for name in objects):
        values = [PAPER_TABLE_I[name][representation][0] for name in objects]
        return float(np.mean(values)), "its mean over the same objects"
    return PAPER_ALL_OBJECTS[representation][0], "its value over all 78 objects"
