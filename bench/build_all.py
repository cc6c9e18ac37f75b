"""Build N YCB objects from scratch and print per-stage seconds, then time a no-change rerun.

    python bench/build_all.py --ycb-dir ../shared/ycb --objects 10 --jobs 2

``--objects`` may name built-in objects (``builtin_dice``, or the set ``builtin``): they are
built from their generated meshes, without the YCB folder (the smallest run: one of them).

The baseline measured in the same run is the no-change rerun (the cost of the cache check):
the ratio printed is cold build time / cached rerun time. Targets (issue 2): all 78 objects
in under 20 minutes on 2 cores; a no-change rerun under 10 s.
"""

from __future__ import annotations

import argparse
import collections
import os
import tempfile
import time
from pathlib import Path

from geomprep import builtin, importer, pipeline, ycb
from geomprep.config import Config


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--ycb-dir", type=Path, default=Path(__file__).resolve().parents[2] / "shared" / "ycb"
    )
    parser.add_argument(
        "--objects", default="10", help="a count (first N YCB objects) or a comma list"
    )
    parser.add_argument("--jobs", type=int, default=os.cpu_count())
    parser.add_argument(
        "--data-dir", type=Path, default=None, help="default: a temporary directory"
    )
    args = parser.parse_args(argv)

    if args.objects.isdigit():
        names = list(ycb.OBJECTS[: int(args.objects)])
    else:
        names = [n.strip() for n in args.objects.split(",") if n.strip()]
    data_dir = args.data_dir or Path(tempfile.mkdtemp(prefix="geomprep-bench-")) / "data"
    cfg = Config(data_dir=data_dir)
    imported = [n for n in names if n != "builtin" and n not in builtin.NAMES]
    if imported:
        importer.import_directory(args.ycb_dir, cfg.raw_dir, imported)
    names = pipeline.resolve_objects(cfg, names)

    start = time.perf_counter()
    report = pipeline.build(cfg, names, jobs=args.jobs, progress=True)
    cold = time.perf_counter() - start
    start = time.perf_counter()
    rerun = pipeline.build(cfg, names, jobs=args.jobs, progress=False)
    warm = time.perf_counter() - start

    per_stage: dict[str, list[float]] = collections.defaultdict(list)
    for (_, stage), seconds in report.seconds.items():
        per_stage[stage].append(seconds)
    print(f"\n{len(names)} objects, {args.jobs} jobs, data in {data_dir}")
    print(f"{'stage':<10} {'total s':>9} {'mean s':>8} {'max s':>8}")
    for stage in (*pipeline.STAGES, "pack"):
        values = per_stage.get(stage, [0.0])
        print(f"{stage:<10} {sum(values):9.1f} {sum(values) / len(values):8.2f} {max(values):8.2f}")
    slowest = sorted(report.seconds.items(), key=lambda kv: -kv[1])[:5]
    print("slowest:", ", ".join(f"{n}/{s} {t:.1f}s" for (n, s), t in slowest))
    print(f"failed: {report.failed or 'none'}")
    print(f"cold build: {cold:.1f} s wall ({cold / len(names):.1f} s per object)")
    print(f"projected for 78 objects: {cold / len(names) * 78 / 60:.1f} min (target < 20 min)")
    print(
        f"no-change rerun: {warm:.2f} s ({len(rerun.skipped)} stages cached, "
        f"{len(rerun.seconds)} computed)"
    )
    print(f"ratio cold / cached rerun: {cold / warm:.0f}x")


if __name__ == "__main__":
    main()
