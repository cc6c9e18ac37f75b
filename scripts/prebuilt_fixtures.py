"""Build the tests' data fixtures for a machine that cannot build them, e.g. a GPU machine
without coacd and open3d or without network, to be used there with
``GEOMGRASP_TEST_PREBUILT=OUT`` (see tests/conftest.py).

Builds ``OUT/<label>/data`` for the fixtures the Warp tests use (``builtin``: the built-in set;
``ycb``: 032_knife, 062_dice, 025_mug, 029_plate; ``grasp``: 077_rubiks_cube, 013_apple,
005_tomato_soup_can, from the YCB folder), with SDF grids at ``--sdf-resolution`` (default
64^3, ~1 MB per object instead of ~16 MB at 200^3: the three fixtures compress to ~20 MB) and
without geomprep's intermediate stage files (only their build records are kept: the trainer
checks those). Physics, contacts and the Warp tests do not depend on the grid's resolution.

    python scripts/prebuilt_fixtures.py OUT [--sdf-resolution 64] [--ycb DIR]
    tar cJf prebuilt.tar.xz -C OUT .

``--objects NAMES --label LABEL`` builds one set of your own instead (e.g. the 10 objects of
``results/cpu-table1/table1.toml`` for a training run on a GPU machine) into
``OUT/LABEL/data``.
"""

from __future__ import annotations

import argparse
import dataclasses
import shutil
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from geomprep import builtin  # noqa: E402
from geomprep.config import Config, SDFParams  # noqa: E402
from tests.conftest import GRASP_TEST_OBJECTS, YCB_TEST_OBJECTS, build_fixture  # noqa: E402

FIXTURES = {"builtin": tuple(builtin.NAMES), "ycb": YCB_TEST_OBJECTS, "grasp": GRASP_TEST_OBJECTS}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("out", type=Path)
    parser.add_argument("--sdf-resolution", type=int, default=64)
    parser.add_argument("--ycb", type=Path, default=ROOT.parent / "shared" / "ycb",
                        help="the YCB folder (default: ../shared/ycb)")
    parser.add_argument("--objects", help="comma-separated object names: build only this set")
    parser.add_argument("--label", default="custom", help="folder name of the --objects set")
    args = parser.parse_args()
    fixtures = FIXTURES
    if args.objects:
        fixtures = {args.label: tuple(n.strip() for n in args.objects.split(",") if n.strip())}
    for label, names in fixtures.items():
        data = args.out / label / "data"
        shutil.rmtree(data, ignore_errors=True)
        cfg = dataclasses.replace(
            Config(data_dir=data), sdf=SDFParams(resolution=args.sdf_resolution)
        )
        source = None if all(n in builtin.NAMES for n in names) else args.ycb
        if source is not None and not (source / names[0]).is_dir():
            print(f"{label}: skipped, no YCB models in {source} (pass --ycb DIR)")
            continue
        build_fixture(cfg, names, source)
        for stage_file in cfg.interim_dir.rglob("*.h5"):
            stage_file.unlink()
        size = sum(p.stat().st_size for p in data.rglob("*") if p.is_file())
        print(f"{label}: {len(names)} objects, {size / 1e6:.1f} MB in {data}")


if __name__ == "__main__":
    main()
