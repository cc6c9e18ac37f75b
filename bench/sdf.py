"""Benchmark geomprep.sdf.compute_sdf against open3d's signed distance over the same grid.

Usage: python bench/sdf.py [--objects 025_mug,032_knife] [--ycb-dir DIR] [--resolution 200]

For each object (centred at its centre of mass) prints the baseline seconds (open3d
RaycastingScene.compute_signed_distance over all R^3 voxel centres), compute_sdf seconds, their
ratio, the max abs difference of |grid| against the baseline's unsigned distance, and the grid's
size in MB when written to HDF5 as the store writes it (float32, chunked 32^3, gzip level 4 +
shuffle); then the mean seconds and the ratio of the summed times.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import h5py
import numpy as np
import open3d as o3d
import trimesh

from geomprep.sdf import compute_sdf, voxel_centers

DEFAULT_OBJECTS = "025_mug,032_knife,062_dice,029_plate,019_pitcher_base"
DEFAULT_YCB = Path(__file__).resolve().parents[2] / "shared" / "ycb"


def load_centred(ycb_dir: Path, name: str) -> tuple[np.ndarray, np.ndarray]:
    """(V, 3) float64 vertices, metres, centred at the centre of mass, and (F, 3) faces."""
    mesh = trimesh.load(ycb_dir / name / "google_16k" / "textured.obj", force="mesh")
    return np.asarray(mesh.vertices) - mesh.center_mass, np.asarray(mesh.faces)


def baseline(vertices: np.ndarray, faces: np.ndarray, resolution: int) -> tuple[float, np.ndarray]:
    """Seconds and (R, R, R) float32 signed distance from open3d over the voxel centres."""
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(
        o3d.core.Tensor(vertices.astype(np.float32)), o3d.core.Tensor(faces.astype(np.uint32))
    )
    c = voxel_centers(resolution)
    points = np.stack(np.meshgrid(c, c, c, indexing="ij"), axis=-1).astype(np.float32)
    start = time.perf_counter()
    signed = scene.compute_signed_distance(o3d.core.Tensor(points)).numpy()
    return time.perf_counter() - start, signed


def compressed_mb(grid: np.ndarray) -> float:
    """MB of the grid in an HDF5 file written as geomprep.store does (32^3, gzip 4, shuffle)."""
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "sdf.h5"
        with h5py.File(path, "w") as f:
            f.create_dataset(
                "sdf",
                data=grid,
                chunks=(32, 32, 32),
                compression="gzip",
                compression_opts=4,
                shuffle=True,
            )
        return path.stat().st_size / 1e6


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--objects", default=DEFAULT_OBJECTS, help="comma-separated YCB names")
    parser.add_argument("--ycb-dir", type=Path, default=DEFAULT_YCB)
    parser.add_argument("--resolution", type=int, default=200)
    args = parser.parse_args(argv)
    print(f"{'object':<22}{'open3d s':>10}{'ours s':>9}{'ratio':>7}{'max err mm':>12}{'MB':>7}")
    base_total = ours_total = 0.0
    names = args.objects.split(",")
    for name in names:
        vertices, faces = load_centred(args.ycb_dir, name)
        base_s, signed = baseline(vertices, faces, args.resolution)
        start = time.perf_counter()
        sdf = compute_sdf(vertices, faces, resolution=args.resolution)
        ours_s = time.perf_counter() - start
        base_total, ours_total = base_total + base_s, ours_total + ours_s
        err_mm = float(np.max(np.abs(np.abs(sdf.grid) - np.abs(signed)))) * 1e3
        print(
            f"{name:<22}{base_s:>10.2f}{ours_s:>9.2f}{base_s / ours_s:>7.1f}{err_mm:>12.3f}"
            f"{compressed_mb(sdf.grid):>7.2f}",
            flush=True,
        )
    print(
        f"{'mean':<22}{base_total / len(names):>10.2f}{ours_total / len(names):>9.2f}"
        f"{base_total / ours_total:>7.1f}"
    )


if __name__ == "__main__":
    main()
