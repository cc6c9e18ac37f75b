"""Stage 1, mesh: load a source mesh, clean it, check units, move the origin to the centre of mass.

Two meshes come out of this stage:
- the *geometry* mesh (vertices merged, degenerate and duplicate faces dropped), which every
  later stage (hulls, SDF, box, superquadric, samples) works on;
- the *visual* mesh: the source mesh with its texture coordinates kept (merging vertices would
  weld UV seams), only translated, written into the MJCF as the visual geom.
Both are in the object frame: metres, origin at the centre of mass, axes of the source mesh.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh
from PIL import Image

from geomprep.config import MeshParams
from geomprep.errors import GeomprepError

VERSION = 2
"""Bump when the stage's output changes for the same input, to invalidate caches."""

SUPPORTED_SUFFIXES = (".obj", ".ply", ".stl", ".off", ".glb")


@dataclass(frozen=True)
class NormalizedMesh:
    """The mesh stage's result. All arrays in the object frame (metres, origin at the COM)."""

    vertices: np.ndarray
    """(V, 3) float64 geometry-mesh vertices."""
    faces: np.ndarray
    """(F, 3) int32 geometry-mesh triangles, outward winding where it could be made consistent."""
    mass_kg: float
    volume_m3: float
    inertia_kg_m2: np.ndarray
    """(3, 3) float64 inertia tensor about the centre of mass, in the object frame."""
    watertight: bool
    com_offset: np.ndarray
    """(3,) float64: the source-frame point that became the origin (subtracted from the source)."""
    com_method: str
    """How mass properties were found: 'volume' (closed), 'voxels' (open scan), 'convex_hull'."""
    visual_vertices: np.ndarray
    """(Vv, 3) float64 visual-mesh vertices (UV seams kept)."""
    visual_faces: np.ndarray
    """(Fv, 3) int32 visual-mesh triangles."""
    visual_uv: np.ndarray | None
    """(Vv, 2) float32 texture coordinates, or None for an untextured source."""
    texture: Image.Image | None
    """The texture image, or None."""


def load_source(path: Path) -> trimesh.Trimesh:
    """Load a mesh file as one unprocessed trimesh (scenes are concatenated), texture kept.

    Raises GeomprepError for a missing file, an unsupported format or a file without triangles.
    """
    path = Path(path)
    if not path.is_file():
        raise GeomprepError(
            f"mesh file not found: {path}: re-import the object with 'geomprep fetch'"
        )
    if path.suffix.lower() not in SUPPORTED_SUFFIXES:
        raise GeomprepError(
            f"unsupported mesh format '{path.suffix}' ({path}): convert it to one of "
            f"{', '.join(SUPPORTED_SUFFIXES)}"
        )
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            loaded = trimesh.load(path, force="mesh", process=False)
    except Exception as exc:  # trimesh raises many types for broken files
        raise GeomprepError(f"cannot read mesh {path}: {exc}; check or re-export the file") from exc
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        raise GeomprepError(f"mesh {path} has no triangles: re-export it as a triangle mesh")
    return loaded


def clean_geometry(source: trimesh.Trimesh, merge_tolerance_m: float) -> trimesh.Trimesh:
    """Geometry mesh: merged vertices, no degenerate/duplicate faces, no unreferenced vertices."""
    vertices = np.asarray(source.vertices, dtype=np.float64)
    faces = np.asarray(source.faces, dtype=np.int64)
    # Snap to the tolerance grid so that vertices split only by UV seams become identical.
    snapped = np.round(vertices / merge_tolerance_m) * merge_tolerance_m
    unique, inverse = np.unique(snapped, axis=0, return_inverse=True)
    faces = inverse.reshape(-1)[faces]
    mesh = trimesh.Trimesh(unique, faces, process=False)
    keep = mesh.nondegenerate_faces(height=merge_tolerance_m)
    keep &= mesh.unique_faces()
    mesh.update_faces(keep)
    mesh.remove_unreferenced_vertices()
    if len(mesh.faces) == 0:
        raise GeomprepError("mesh has only degenerate triangles: re-export it with real geometry")
    return mesh


def check_finite_and_units(vertices: np.ndarray, params: MeshParams, label: str) -> None:
    """Reject NaN/inf vertices and meshes whose size says they are not in metres."""
    if not np.isfinite(vertices).all():
        bad = int((~np.isfinite(vertices)).any(axis=1).sum())
        raise GeomprepError(
            f"{label}: {bad} vertices are NaN or infinite: repair or re-export the mesh"
        )
    extent = float(np.linalg.norm(np.ptp(vertices, axis=0)))
    if extent > params.max_extent_m:
        hint = " (it looks like millimetres: scale it by 0.001)" if extent > 20 else ""
        raise GeomprepError(
            f"{label} is {extent:.3g} m across, more than the {params.max_extent_m} m limit{hint}: "
            "geomprep expects metres; rescale the file and re-import it"
        )
    if extent < params.min_extent_m:
        raise GeomprepError(
            f"{label} is only {extent * 1000:.3g} mm across: geomprep expects metres; "
            "rescale the file and re-import it"
        )


def mass_properties(
    mesh: trimesh.Trimesh, voxels_per_side: int = 64
) -> tuple[float, np.ndarray, np.ndarray, str]:
    """Volume (m^3), centre of mass (3,), inertia per kg about the COM (3, 3, m^2), method.

    A closed mesh integrates its own volume exactly ('volume'). An open scan (20 of the 78 YCB
    meshes have holes) has no well-defined signed volume, so it is voxelized instead
    ('voxels'): a voxel centre is solid when most of several rays from it cross the surface an
    odd number of times, which small holes do not fool. A scan too thin for that grid
    falls back to its convex hull ('convex_hull').
    """
    if mesh.is_watertight and mesh.volume > 0:
        return (
            float(mesh.volume),
            mesh.center_mass.copy(),
            mesh.moment_inertia / mesh.volume,
            "volume",
        )
    solid, voxel = _solid_voxels(mesh, voxels_per_side)
    if len(solid) >= 200:
        com = solid.mean(axis=0)
        r = solid - com
        # Point masses plus each voxel's own inertia (a cube: voxel^2 / 6 per kg).
        inertia = (np.eye(3) * np.sum(r * r, axis=1).sum() - r.T @ r) / len(solid)
        inertia += np.eye(3) * voxel**2 / 6.0
        return float(len(solid) * voxel**3), com, inertia, "voxels"
    hull = mesh.convex_hull
    return (
        float(hull.volume),
        hull.center_mass.copy(),
        hull.moment_inertia / hull.volume,
        "convex_hull",
    )


def _solid_voxels(mesh: trimesh.Trimesh, voxels_per_side: int) -> tuple[np.ndarray, float]:
    """Centres (N, 3) of the voxels inside an open mesh by a 7-ray majority vote, and the voxel
    size (m). The grid covers the mesh's bounding box with ``voxels_per_side`` along its
    longest side."""
    import open3d as o3d  # only open scans need it

    lo, hi = mesh.bounds
    voxel = float((hi - lo).max()) / voxels_per_side
    axes = [np.arange(a + voxel / 2, b, voxel) for a, b in zip(lo, hi, strict=True)]
    centres = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(
        o3d.core.Tensor(np.asarray(mesh.vertices, dtype=np.float32)),
        o3d.core.Tensor(np.asarray(mesh.faces, dtype=np.uint32)),
    )
    votes = scene.compute_occupancy(o3d.core.Tensor(centres.astype(np.float32)), nsamples=7)
    return centres[votes.numpy() > 0.5], voxel


def normalize_mesh(
    source: trimesh.Trimesh,
    params: MeshParams,
    mass_kg: float | None,
    density_kg_m3: float | None,
    label: str = "mesh",
) -> NormalizedMesh:
    """Clean ``source``, check its units and move its origin to the centre of mass.

    Mass: ``mass_kg`` if given, else ``density_kg_m3`` (or the params' default) times the volume.
    """
    vertices = np.asarray(source.vertices, dtype=np.float64)
    if len(vertices) == 0 or len(source.faces) == 0:
        raise GeomprepError(f"{label} is empty (no vertices or faces): re-export the mesh")
    check_finite_and_units(vertices, params, label)
    geometry = clean_geometry(source, params.merge_tolerance_m)
    if geometry.is_watertight:
        trimesh.repair.fix_normals(geometry)
    volume, com, inertia_per_kg, com_method = mass_properties(geometry)
    if mass_kg is None:
        mass_kg = (density_kg_m3 or params.density_kg_m3) * volume
    if not mass_kg > 0:
        raise GeomprepError(
            f"{label}: mass {mass_kg} kg is not positive: fix masses.csv or the density"
        )

    uv = None
    texture = None
    visual = getattr(source, "visual", None)
    if isinstance(visual, trimesh.visual.TextureVisuals) and visual.uv is not None:
        uv = np.asarray(visual.uv, dtype=np.float32)
        image = getattr(visual.material, "image", None)
        texture = image.convert("RGB") if image is not None else None
    return NormalizedMesh(
        vertices=geometry.vertices - com,
        faces=geometry.faces.astype(np.int32),
        mass_kg=float(mass_kg),
        volume_m3=volume,
        inertia_kg_m2=inertia_per_kg * mass_kg,
        watertight=bool(geometry.is_watertight),
        com_offset=com,
        com_method=com_method,
        visual_vertices=vertices - com,
        visual_faces=np.asarray(source.faces, dtype=np.int32),
        visual_uv=uv,
        texture=texture,
    )
