"""``geomprep show``: a text summary of an object's artifacts and a PNG preview.

The preview has five panels side by side, all in the object frame with equal axes: the mesh,
the collision hulls, the oriented bounding box, the superquadric and the 512-point cloud, plus
a slice of the SDF through the origin.

Both take ``sources``, the file holding each group of the data contract: the packed
``processed/<name>.h5`` for every group of a built object, or the stage files that are done for
a partly built one. A group without a source is reported (and drawn) as not built.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING

import h5py
import numpy as np

from geomgrasp.files import atomic_path
from geomprep import decompose, store, superquadric

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

GROUPS = ("mesh", "decomposition", "mjcf", "sdf", "bbox", "superquadric", "pointcloud")


def _mm(metres: np.ndarray) -> list[float]:
    """Lengths in mm, one decimal, as plain floats (float32 would print 132.3000030517578)."""
    return np.round(np.asarray(metres, dtype=np.float64) * 1000, 1).tolist()


def summary(sources: Mapping[str, Path], absent: Mapping[str, str] | None = None) -> str:
    """Human-readable lines: mass, size, hulls, box, superquadric, SDF and settle facts; for a
    group without a source, one line saying why (``absent``, default ``not built``). Needs the
    mesh group."""
    lines = [_mesh_lines(sources["mesh"])]
    for group, label in (
        ("decomposition", "hulls"),
        ("mjcf", "mjcf"),
        ("bbox", "bbox"),
        ("superquadric", "superquad."),
        ("sdf", "sdf"),
        ("pointcloud", "pointcloud"),
    ):
        if group in sources:
            with h5py.File(sources[group], "r") as f:
                lines.append(_LINES[group](f[group], sources[group]))
        else:
            lines.append(f"{label:<12}({(absent or {}).get(group, 'not built')})")
    return "\n".join(lines)


def _mesh_lines(path: Path) -> str:
    with h5py.File(path, "r") as f:
        m = f["mesh"].attrs
        vertices = f["mesh/vertices"][()]
        span = np.ptp(vertices, axis=0) * 1000
        return (
            f"mesh        {len(vertices)} vertices, {len(f['mesh/faces'])} faces, "
            f"{span[0]:.1f} x {span[1]:.1f} x {span[2]:.1f} mm, "
            f"watertight={bool(m['watertight'])}   ({path})\n"
            f"mass        {float(m['mass_kg']) * 1000:.1f} g ({m['mass_source']}), "
            f"volume {float(m['volume_m3']) * 1e6:.1f} cm^3, COM by {m['com_method']}"
        )


def _hulls_line(g: h5py.Group, path: Path) -> str:
    d = g.attrs
    return (
        f"hulls       {int(d['n_hulls'])} (max {int(d['max_hull_vertices'])} vertices), "
        f"{float(d['covered_fraction_1mm']) * 100:.1f}% of vertices within 1 mm"
    )


def _mjcf_line(g: h5py.Group, path: Path) -> str:
    j = g.attrs
    return (
        f"mjcf        {j['xml']}: settled at {float(j['settle_final_height_m']) * 1000:.1f} mm, "
        f"speed {float(j['settle_final_speed_m_s']) * 1000:.2f} mm/s"
    )


def _bbox_line(g: h5py.Group, path: Path) -> str:
    return (
        f"bbox        extents {_mm(g['extents'][()])} mm, "
        f"{float(g.attrs['contained_fraction']) * 100:.1f}% of vertices inside"
    )


def _sq_lines(g: h5py.Group, path: Path) -> str:
    params = g["params"][()]
    return (
        f"superquad.  eps {params[0]:.2f}, {params[1]:.2f}; semi-axes {_mm(params[2:5])} mm\n"
        + _sq_quality_line(dict(g.attrs))
    )


def _sdf_line(g: h5py.Group, path: Path) -> str:
    return (
        f"sdf         {g['grid'].shape}, voxel {float(g.attrs['voxel_size']) * 1000:.2f} mm, "
        f"min {float(g['grid'][()].min()) * 1000:.1f} mm, "
        f"{path.stat().st_size / 1e6:.1f} MB file"
    )


def _pc_line(g: h5py.Group, path: Path) -> str:
    return f"pointcloud  {', '.join(k for k in g if k.startswith('pc'))}"


_LINES = {
    "decomposition": _hulls_line,
    "mjcf": _mjcf_line,
    "bbox": _bbox_line,
    "superquadric": _sq_lines,
    "sdf": _sdf_line,
    "pointcloud": _pc_line,
}


def _sq_quality_line(attrs: dict) -> str:
    """Superquadric fit quality in mm (attrs in metres), or a note for files without it."""
    keys = ("mesh_to_sq_mean_m", "mesh_to_sq_p95_m", "sq_to_mesh_mean_m", "sq_to_mesh_p95_m")
    if not all(k in attrs for k in keys):
        return "            (no quality figures: rebuild the sq stage)"
    mm = [float(attrs[k]) * 1000 for k in keys]
    iou = f", volume IoU {float(attrs['volume_iou']):.2f}" if "volume_iou" in attrs else ""
    return (
        f"            mesh->sq {mm[0]:.1f} mm mean / {mm[1]:.1f} p95, "
        f"sq->mesh {mm[2]:.1f} / {mm[3]:.1f}{iou}"
    )


def _box_edges(center: np.ndarray, rotation: np.ndarray, extents: np.ndarray) -> list[np.ndarray]:
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]) * extents / 2
    corners = corners @ rotation.T + center
    pairs = [(a, b) for a in range(8) for b in range(a + 1, 8) if bin(a ^ b).count("1") == 1]
    return [corners[[a, b]] for a, b in pairs]


def render(sources: Mapping[str, Path], out: Path, title: str) -> None:
    """Write the preview PNG; a panel whose group has no source says "not built". Needs the
    mesh group (every panel is drawn in its frame and at its scale)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    def group(name: str) -> dict[str, np.ndarray] | None:
        return store.read_group(sources[name], name)[0] if name in sources else None

    if "mesh" not in sources:
        raise ValueError("the preview is drawn around the mesh: no mesh source given")
    mesh_arrays = store.read_group(sources["mesh"], "mesh")[0]
    hull_arrays, box, sq, pc = (
        group(g) for g in ("decomposition", "bbox", "superquadric", "pointcloud")
    )
    vertices, faces = mesh_arrays["vertices"], mesh_arrays["faces"]
    radius = float(np.abs(vertices).max()) * 1.15

    fig = plt.figure(figsize=(22, 4.6))
    titles = ["mesh", "convex hulls", "oriented bbox", "superquadric", "point cloud (512)"]
    axes = [fig.add_subplot(1, 6, k + 1, projection="3d") for k in range(5)]
    for ax, panel_title in zip(axes, titles, strict=True):
        ax.set_title(panel_title)
        ax.set_xlim(-radius, radius)
        ax.set_ylim(-radius, radius)
        ax.set_zlim(-radius, radius)
        ax.set_box_aspect((1, 1, 1))
        ax.set_axis_off()

    step = max(1, len(faces) // 4000)  # matplotlib is slow beyond a few thousand polygons
    mesh_poly = Poly3DCollection(vertices[faces[::step]], facecolor="0.7", edgecolor="none")
    axes[0].add_collection3d(mesh_poly)
    if hull_arrays is None:
        _not_built(axes[1])
    else:
        colors = plt.get_cmap("tab20")
        for k, (hv, hf) in enumerate(decompose.unpack_hulls(hull_arrays)):
            axes[1].add_collection3d(
                Poly3DCollection(
                    hv[hf], facecolor=colors(k % 20), edgecolor="k", linewidth=0.1, alpha=0.8
                )
            )
    for ax in axes[2:4]:
        ax.add_collection3d(
            Poly3DCollection(vertices[faces[:: step * 2]], facecolor="0.8", alpha=0.3)
        )
    if box is None:
        _not_built(axes[2])
    else:
        for edge in _box_edges(box["center"], box["rotation"], box["extents"]):
            axes[2].plot(*edge.T, color="tab:red")
    if sq is None:
        _not_built(axes[3])
    else:
        surface = superquadric.sample_surface(sq["params"].astype(np.float64), 1500)
        axes[3].scatter(*surface.T, s=1, color="tab:green")
    if pc is None:
        _not_built(axes[4])
    else:
        points = pc["pc512"]
        axes[4].scatter(*points.T, s=4, c=points[:, 2], cmap="viridis")

    ax = fig.add_subplot(1, 6, 6)
    ax.set_title("SDF, y = 0 slice (mm)")
    if "sdf" in sources:
        _draw_sdf_slice(fig, ax, sources["sdf"], radius)
    else:
        ax.set_axis_off()
        _not_built(ax)
    fig.suptitle(title)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(out) as tmp:
        fig.savefig(tmp, dpi=80, format="png")
    plt.close(fig)


def _not_built(ax: Axes) -> None:
    # A 3-D axes' text() takes a z coordinate; text2D is its text in axes coordinates.
    text = ax.text2D if hasattr(ax, "text2D") else ax.text
    text(0.5, 0.5, "not built", transform=ax.transAxes, ha="center", color="0.4")


def _draw_sdf_slice(fig: Figure, ax: Axes, path: Path, radius: float) -> None:
    with h5py.File(path, "r") as f:
        grid = f["sdf/grid"]
        sdf_slice = grid[:, grid.shape[1] // 2, :]
        lo, hi = f["sdf"].attrs["bounds_min"], f["sdf"].attrs["bounds_max"]
    limit = radius * 1000  # colour only the neighbourhood; far values would wash it out
    image = ax.imshow(
        sdf_slice.T * 1000,
        origin="lower",
        extent=(lo[0], hi[0], lo[2], hi[2]),
        cmap="RdBu",
        vmin=-limit,
        vmax=limit,
    )
    ax.contour(
        np.linspace(lo[0], hi[0], sdf_slice.shape[0]),
        np.linspace(lo[2], hi[2], sdf_slice.shape[1]),
        sdf_slice.T,
        levels=[0.0],
        colors="k",
    )
    ax.set_xlim(-radius * 2, radius * 2)
    ax.set_ylim(-radius * 2, radius * 2)
    fig.colorbar(image, ax=ax, shrink=0.8)
