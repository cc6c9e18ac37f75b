"""Benchmark superquadric recovery on YCB: EMS alone vs EMS + the paper's surface term.

Usage: python bench/sq.py [--objects N|a,b] [--ycb-dir DIR] [--figures DIR]

Each object is loaded and cleaned as the pipeline's ``mesh`` stage does (centred at its centre
of mass), sampled as the ``sq`` stage does (``Config().sq``), and fitted twice on one core:
EMS alone (``surface_weight = 0``) and EMS + regularisation (the configured weight, exact
closest points on the mesh from open3d). Per object and variant it prints the fit's seconds
and its quality (``geomprep.superquadric.fit_quality``): mesh->sq and sq->mesh distances in mm
(mean / 95th percentile) and the volume IoU against the mesh. The summary checks the targets:
<= 2 s per object; on the concave objects the regularised sq->mesh p95 below EMS alone's; on
the box-like objects mesh->sq within 10 % of EMS alone's.

``--figures DIR`` also writes ``DIR/sq_<name>.png`` for the objects in ``FIGURE_OBJECTS`` that
were run: both fits side by side, the mesh as grey points and the superquadric's surface samples
coloured by their distance to the mesh (as in the paper's figure).

``--objects N`` takes the first N objects in name order; the default is every object in the
YCB directory.
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
from pathlib import Path

import numpy as np

from geomprep import mesh as gmesh
from geomprep import pointcloud
from geomprep import superquadric as sq
from geomprep.config import Config

DEFAULT_YCB = Path("/work/shared/ycb")
CONCAVE = ("024_bowl", "025_mug", "029_plate", "065-a_cups")
BOXES = (
    "003_cracker_box",
    "004_sugar_box",
    "008_pudding_box",
    "009_gelatin_box",
    "036_wood_block",
    "061_foam_brick",
)
FIGURE_OBJECTS = (
    "024_bowl",
    "025_mug",
    "029_plate",
    "065-a_cups",
    "003_cracker_box",
    "013_apple",
    "005_tomato_soup_can",
)
VARIANTS = ("ems", "ems+surface")


def load_object(ycb_dir: Path, name: str) -> tuple[np.ndarray, np.ndarray]:
    """(V, 3) float64 vertices in metres, centred at the centre of mass, and (F, 3) faces."""
    source = gmesh.load_source(ycb_dir / name / "google_16k" / "textured.obj")
    norm = gmesh.normalize_mesh(source, Config().mesh, None, 500.0, label=name)
    return np.asarray(norm.vertices, dtype=np.float64), np.asarray(norm.faces, dtype=np.int64)


def fit_both(
    vertices: np.ndarray, faces: np.ndarray
) -> tuple[sq.MeshOracle, dict[str, tuple[np.ndarray, float, dict[str, float]]]]:
    """Fit both variants exactly as the ``sq`` stage does (``superquadric.fit_mesh``).

    Returns the mesh oracle (for the figures) and per variant (params (11,),
    seconds of fitting, without the quality report, diagnostics and quality dict).
    """
    cfg = Config().sq
    out: dict[str, tuple[np.ndarray, float, dict[str, float]]] = {}
    for variant in VARIANTS:
        weight = cfg.surface_weight if variant == "ems+surface" else 0.0
        params, info = sq.fit_mesh(vertices, faces, dataclasses.replace(cfg, surface_weight=weight))
        out[variant] = (params, info["fit_seconds"], info)
    return sq.MeshOracle(vertices, faces), out


def figure(
    name: str,
    vertices: np.ndarray,
    faces: np.ndarray,
    oracle: sq.MeshOracle,
    fits: dict[str, tuple[np.ndarray, float, dict[str, float]]],
    path: Path,
) -> None:
    """Write the figure for one object: EMS alone (left) | EMS + surface term (right).

    Top row: 3-D view, mesh surface samples in grey, superquadric surface samples coloured by
    their distance to the mesh. Bottom row: the slab |y - y_c| < 3 mm through the object's
    centre seen along y (a cross-section), same colours. The colour scale is shared and
    saturates at the regularised fit's 99th percentile (at least 10 mm), so that both the
    far-away parts of EMS alone and the residual gaps of the regularised fit stay visible.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rng = np.random.default_rng(0)
    mesh_pts, _ = pointcloud.sample_uniform(vertices, faces, 30000, rng)
    samples = {v: sq.sample_surface(fits[v][0], 1500, seed=1) for v in VARIANTS}
    dist_mm = {v: oracle.distance(samples[v]) * 1000 for v in VARIANTS}
    dense = {v: sq.sample_surface_dense(fits[v][0], 60000, seed=2) for v in VARIANTS}
    dense_mm = {v: oracle.distance(dense[v]) * 1000 for v in VARIANTS}
    vmax = max(10.0, float(np.percentile(dist_mm["ems+surface"], 99)))
    every = np.concatenate([mesh_pts, *samples.values()])
    centre = (every.max(axis=0) + every.min(axis=0)) / 2
    half = float((every.max(axis=0) - every.min(axis=0)).max()) / 2 * 1000 * 1.02
    y_c = float(np.mean(mesh_pts[:, 1]))

    fig = plt.figure(figsize=(10, 10))
    titles = {"ems": "EMS alone", "ems+surface": "EMS + surface term"}
    style = {"cmap": "plasma", "vmin": 0.0, "vmax": vmax, "linewidths": 0}
    for i, variant in enumerate(VARIANTS):
        params, _, q = fits[variant]
        m = (mesh_pts[::5] - centre) * 1000
        s = (samples[variant] - centre) * 1000
        ax = fig.add_subplot(2, 2, i + 1, projection="3d")
        ax.scatter(m[:, 0], m[:, 1], m[:, 2], s=1.5, c="0.35", alpha=0.5, linewidths=0)
        sc = ax.scatter(s[:, 0], s[:, 1], s[:, 2], s=4, c=dist_mm[variant], **style)
        for set_lim in (ax.set_xlim, ax.set_ylim, ax.set_zlim):
            set_lim(-half, half)
        ax.set_box_aspect((1, 1, 1))
        ax.view_init(elev=22, azim=-60)
        ax.set_xlabel("x mm", fontsize=8, labelpad=-2)
        ax.set_ylabel("y mm", fontsize=8, labelpad=-2)
        ax.set_zlabel("z mm", fontsize=8, labelpad=-2)
        ax.tick_params(labelsize=7, pad=0)
        ax.set_title(
            f"{titles[variant]}\n"
            f"sq->mesh {q['sq_to_mesh_mean_m'] * 1000:.1f} mm mean, "
            f"{q['sq_to_mesh_p95_m'] * 1000:.1f} p95\n"
            f"mesh->sq {q['mesh_to_sq_mean_m'] * 1000:.1f} mm mean, "
            f"{q['mesh_to_sq_p95_m'] * 1000:.1f} p95\n"
            f"IoU {q['volume_iou']:.2f}; eps {params[0]:.2f}, {params[1]:.2f}",
            fontsize=9,
        )

        ax2 = fig.add_subplot(2, 2, i + 3)
        in_slab = np.abs(mesh_pts[:, 1] - y_c) < 0.003
        ms = (mesh_pts[in_slab] - centre) * 1000
        ax2.scatter(ms[:, 0], ms[:, 2], s=1.5, c="0.35", linewidths=0, label="mesh")
        sq_slab = np.abs(dense[variant][:, 1] - y_c) < 0.003
        ss = (dense[variant][sq_slab] - centre) * 1000
        ax2.scatter(ss[:, 0], ss[:, 2], s=2, c=dense_mm[variant][sq_slab], **style)
        ax2.set_xlim(-half, half)
        ax2.set_ylim(-half, half)
        ax2.set_aspect("equal")
        ax2.set_xlabel("x mm", fontsize=8)
        ax2.set_ylabel("z mm", fontsize=8)
        ax2.tick_params(labelsize=7)
        ax2.set_title("cross-section |y - y_c| < 3 mm (grey: mesh)", fontsize=9)
    fig.subplots_adjust(left=0.06, right=0.86, top=0.9, bottom=0.05, wspace=0.15, hspace=0.2)
    cax = fig.add_axes((0.89, 0.25, 0.02, 0.5))
    cbar = fig.colorbar(sc, cax=cax, extend="max")
    cbar.set_label("distance of the superquadric's surface to the mesh (mm)")
    fig.suptitle(f"{name}: superquadric recovery", fontsize=12)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _row(name: str, fits: dict[str, tuple[np.ndarray, float, dict[str, float]]]) -> str:
    cells = [f"{name:22s}"]
    for variant in VARIANTS:
        _, seconds, q = fits[variant]
        mm = [q[k] * 1000 for k in ("mesh_to_sq_mean_m", "mesh_to_sq_p95_m")]
        mm += [q[k] * 1000 for k in ("sq_to_mesh_mean_m", "sq_to_mesh_p95_m")]
        cells.append(
            f"{seconds:5.2f} {mm[0]:5.1f} {mm[1]:5.1f} {mm[2]:6.1f} {mm[3]:6.1f} "
            f"{q['volume_iou']:4.2f}"
        )
    return " | ".join(cells)


def _summary(results: dict[str, dict[str, tuple[np.ndarray, float, dict[str, float]]]]) -> None:
    print()
    for variant in VARIANTS:
        secs = np.array([r[variant][1] for r in results.values()])
        iou = np.array([r[variant][2]["volume_iou"] for r in results.values()])
        print(
            f"{variant:12s} seconds per object: mean {secs.mean():.2f}, median "
            f"{np.median(secs):.2f}, max {secs.max():.2f} "
            f"({int(np.sum(secs <= 2.0))}/{len(secs)} <= 2 s); mean IoU {iou.mean():.3f}"
        )
    for name in CONCAVE:
        if name in results:
            ems = results[name]["ems"][2]["sq_to_mesh_p95_m"] * 1000
            reg = results[name]["ems+surface"][2]["sq_to_mesh_p95_m"] * 1000
            verdict = "ok" if reg < ems else "NOT smaller"
            print(f"concave {name:20s} sq->mesh p95 {ems:6.1f} -> {reg:6.1f} mm  {verdict}")
    for name in BOXES:
        if name in results:
            ems = results[name]["ems"][2]["mesh_to_sq_mean_m"] * 1000
            reg = results[name]["ems+surface"][2]["mesh_to_sq_mean_m"] * 1000
            verdict = "ok" if reg <= 1.1 * ems else "WORSE by > 10 %"
            print(f"box     {name:20s} mesh->sq mean {ems:5.2f} -> {reg:5.2f} mm  {verdict}")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--objects", default="", help="N (first N by name) or a,b,c")
    parser.add_argument("--ycb-dir", type=Path, default=DEFAULT_YCB)
    parser.add_argument("--figures", type=Path, default=None, help="write sq_<name>.png here")
    args = parser.parse_args(argv)
    logging.getLogger("trimesh").setLevel(logging.ERROR)

    available = sorted(
        p.name for p in args.ycb_dir.iterdir() if (p / "google_16k" / "textured.obj").exists()
    )
    if args.objects.isdigit():
        names = available[: int(args.objects)]
    elif args.objects:
        names = args.objects.split(",")
    else:
        names = available

    print(
        f"{'':22s} | {'EMS alone':^33s} | {'EMS + surface term':^33s}\n"
        f"{'object':22s} | {'s':>5s} {'m>sq':>5s} {'p95':>5s} {'sq>m':>6s} {'p95':>6s} "
        f"{'IoU':>4s} | {'s':>5s} {'m>sq':>5s} {'p95':>5s} {'sq>m':>6s} {'p95':>6s} {'IoU':>4s}"
    )
    results = {}
    for name in names:
        vertices, faces = load_object(args.ycb_dir, name)
        oracle, fits = fit_both(vertices, faces)
        results[name] = fits
        print(_row(name, fits), flush=True)
        if args.figures is not None and name in FIGURE_OBJECTS:
            figure(name, vertices, faces, oracle, fits, args.figures / f"sq_{name}.png")
    print("(seconds of the fit on one core; distances in mm: mean and p95; IoU by volume)")
    _summary(results)


if __name__ == "__main__":
    main()
