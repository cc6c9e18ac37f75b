"""Stage 1, mesh: load a source mesh, clean it, check units, move the origin to the centre of mass.

Two meshes come out of this stage:
- the *geometry* mesh (vertices merged, degenerate and duplicate faces dropped, closed parts that
  overlap replaced by their union), which every later stage (hulls, SDF, box, superquadric,
  samples) works on;
- the *visual* mesh: the source mesh with its texture coordinates kept (merging vertices would
  weld UV seams), only translated, written into the MJCF as the visual geom.
Both are in the object frame: metres, origin at the centre of mass, axes of the source mesh.

The solid a mesh stands for has union semantics: a point is inside when it is inside any closed
part (CAD exports often leave parts interpenetrating instead of merged), so overlapping closed
parts are unioned (manifold3d) before the mass properties are integrated, and the geometry mesh
is that union.  Where parts overlap and one of them is open, the inside cannot be decided
reliably, and a point enclosed twice is rejected rather than given a wrong sign
(:func:`inside_mask`, shared with the SDF stage).

Mass properties are integrated after moving the vertices (float64) to their bounding-box centre:
at 3 km from the origin the integrals' products of large coordinates cancel to a 25 % error.

Large meshes: this stage, the SDF (certified to 0.5 mm), the point clouds and the superquadric
fit work at full resolution; the two steps whose cost grows faster than the mesh and that need
only its outline, the box's min-volume axis search and the convex decomposition, work on
:func:`reduced`'s coarser copy within their ``max_faces`` budget.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import trimesh
from PIL import Image
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from geomprep.config import MeshParams
from geomprep.errors import GeomprepError
from geomprep.syslibs import import_open3d

if TYPE_CHECKING:
    import open3d

VERSION = 3
"""Bump when the stage's output changes for the same input, to invalidate caches."""

SUPPORTED_SUFFIXES = (".obj", ".ply", ".stl", ".off", ".glb")

# Odd number of ray directions voted over by every inside test (mass voxels and the SDF sign).
SIGN_RAYS = 7
# The fewest triangles that can enclose volume (a tetrahedron): smaller connected parts, such as
# the 1-3 stray triangles 20 of the YCB scans carry, cannot overlap a solid in any sense.
MIN_PART_FACES = 4


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
    n_unioned: int = 0
    """How many overlapping closed parts were replaced by their union (0: none overlapped)."""


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


def clean_geometry(
    source: trimesh.Trimesh, merge_tolerance_m: float, label: str = "mesh"
) -> trimesh.Trimesh:
    """Geometry mesh: merged vertices, no degenerate/duplicate faces, no unreferenced vertices.

    Raises GeomprepError when no triangle has any area (the file holds only points or lines).
    """
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
        raise GeomprepError(
            f"{label} has no triangle with any area (only points or lines), so it is not a "
            "surface: re-export it as a closed triangle mesh"
        )
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


def far_offset(vertices: np.ndarray) -> np.ndarray:
    """(3,) float64 metres to subtract from vertices (V, 3) before integrating over them: their
    bounding-box centre when it lies farther from the origin than the box's diagonal, else 0.

    Far away (a 5 cm cube 3 km out), products of coordinates in the mass integrals cancel to a
    25 % inertia error and open3d's float32 scenes lose millimetres.  Near the origin the error
    is already at rounding level, and leaving those meshes alone keeps their results
    bit-identical (a sphere's 64-vertex hull, for one, flips with the last bit).
    """
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    centre = (lo + hi) / 2.0
    if np.linalg.norm(centre) > np.linalg.norm(hi - lo):
        return centre
    return np.zeros(3)


def thickness(vertices: np.ndarray) -> float:
    """Extent, metres, of vertices (V, 3) along their direction of least spread (the smallest
    principal axis): 0 when they all lie in one plane."""
    centred = vertices - vertices.mean(axis=0)
    _, axes = np.linalg.eigh(centred.T @ centred)  # eigenvalues ascending
    return float(np.ptp(centred @ axes[:, 0]))


def check_not_flat(vertices: np.ndarray, params: MeshParams, label: str) -> None:
    """Reject a mesh whose vertices (V, 3, metres) all lie within ``params.min_thickness_m`` of a
    plane: a sheet encloses no volume, so it has no mass properties and no inside."""
    flat = thickness(vertices)
    if flat < params.min_thickness_m:
        raise GeomprepError(
            f"{label} is flat (zero volume): it is only {flat:.2g} m thick across its thinnest "
            f"direction ([mesh] min_thickness_m = {params.min_thickness_m:g}), so it is not a "
            "solid: give the sheet a thickness (e.g. solidify it in a modeller) and re-export it"
        )


@dataclass(frozen=True)
class Solid:
    """A mesh prepared for mass properties and inside tests (:func:`solid`)."""

    mesh: trimesh.Trimesh
    """The input with its overlapping closed parts replaced by their union (the input itself
    when none overlapped)."""
    n_unioned: int
    """How many closed parts the union merged (0: none overlapped)."""
    open_overlap: bool
    """Whether parts overlap (by bounding box) of which at least one is open, so that an inside
    test must check that no point is enclosed twice (:func:`inside_mask`)."""


def solid(mesh: trimesh.Trimesh, label: str = "mesh", merged: bool = False) -> Solid:
    """The solid ``mesh`` stands for, with union semantics (module docstring).

    Parts are the edge-connected components of at least ``MIN_PART_FACES`` triangles; a part is
    closed when each of its directed edges meets exactly one opposite edge.  Closed parts whose
    bounding boxes overlap another closed part's are replaced by their manifold3d union (a part
    wound inwards is a cavity and is subtracted); the rest of the mesh is kept unchanged.  An
    ordinary mesh (one part, or parts apart) comes back as it is, after one connectivity pass.

    ``merged``: the caller guarantees that no two vertices coincide (``clean_geometry``'s
    output), which saves merging them here.

    Raises GeomprepError when overlapping closed parts cannot be unioned (manifold3d refuses a
    part), since summing them would count the overlap twice.
    """
    unique = np.asarray(mesh.vertices, dtype=np.float64)
    faces = np.asarray(mesh.faces, dtype=np.int64)
    if not merged:
        # Parts by exactly coincident vertices, so a mesh split at UV seams still shows them.
        unique, inverse = np.unique(unique, axis=0, return_inverse=True)
        faces = inverse.reshape(-1)[faces]
    n_parts, labels = _part_labels(faces, len(unique))
    big = np.flatnonzero(np.bincount(labels, minlength=n_parts) >= MIN_PART_FACES)
    if len(big) < 2:
        return Solid(mesh, 0, False)
    order = np.argsort(labels, kind="stable")
    starts = np.searchsorted(labels[order], np.arange(n_parts + 1))  # part k: starts[k:k + 2]
    tri = unique[faces[order]]  # (F, 3, 3), faces grouped by part
    lo = np.minimum.reduceat(tri.min(axis=1), starts[:-1])[big]
    hi = np.maximum.reduceat(tri.max(axis=1), starts[:-1])[big]
    overlap = _boxes_overlap(lo, hi)
    if not overlap.any():
        return Solid(mesh, 0, False)
    open_faces = ~_closed_faces(faces, len(unique))
    closed = np.bincount(labels, weights=open_faces, minlength=n_parts)[big] == 0
    open_overlap = bool((overlap & ~(closed[:, None] & closed[None, :])).any())
    merge = closed & (overlap & closed[None, :]).any(axis=1)
    if not merge.any():
        return Solid(mesh, 0, open_overlap)

    import manifold3d  # only meshes with overlapping closed parts need it

    # Signed volume per part (divergence theorem): negative for a part wound inwards (a cavity).
    det = np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2]))
    part_volume = np.add.reduceat(det, starts[:-1])
    solids, cavities = [], []
    for k in big[merge]:
        part = faces[order[starts[k] : starts[k + 1]]]
        if part_volume[k] < 0:
            part = part[:, ::-1]
        used, local = np.unique(part, return_inverse=True)
        body = manifold3d.Manifold(
            manifold3d.Mesh64(
                vert_properties=np.ascontiguousarray(unique[used]),
                tri_verts=local.reshape(-1, 3).astype(np.uint64),
            )
        )
        if body.status() != manifold3d.Error.NoError:
            raise GeomprepError(
                f"{label}: {int(merge.sum())} closed parts overlap but manifold3d cannot union "
                f"them ({body.status().name}), and summing them would count the overlap twice: "
                "union the parts in a modeller and re-export the mesh"
            )
        (cavities if part_volume[k] < 0 else solids).append(body)
    if not solids:  # an inside-out mesh, not overlapping solids: leave it to the volume check
        return Solid(mesh, 0, open_overlap)
    union = manifold3d.Manifold.batch_boolean(solids, manifold3d.OpType.Add)
    if cavities:
        union = manifold3d.Manifold.batch_boolean([union, *cavities], manifold3d.OpType.Subtract)
    out = union.to_mesh64()
    union_vertices = np.asarray(out.vert_properties, dtype=np.float64)[:, :3]
    rest = faces[~np.isin(labels, big[merge])]
    result = trimesh.Trimesh(
        np.concatenate([union_vertices, unique]),
        np.concatenate([np.asarray(out.tri_verts, dtype=np.int64), rest + len(union_vertices)]),
        process=False,
    )
    result.remove_unreferenced_vertices()
    return Solid(result, int(merge.sum()), open_overlap)


def _part_labels(faces: np.ndarray, n_vertices: int) -> tuple[int, np.ndarray]:
    """Edge-connected components of a mesh: their count and each face's (F,) label.

    Faces meet when they share an edge that no other face has (as trimesh's face adjacency, so a
    stray triangle on a non-manifold edge is a part of its own); one sort of the 3 F edge keys,
    3x faster than trimesh's adjacency on a 550k-face mesh.
    """
    edges = np.sort(np.stack([faces, np.roll(faces, -1, axis=1)], axis=-1), axis=-1)
    keys = (edges[..., 0] * n_vertices + edges[..., 1]).reshape(-1)
    order = np.argsort(keys, kind="stable")
    ordered = keys[order]
    _, start, count = np.unique(ordered, return_index=True, return_counts=True)
    pair = start[count == 2]  # sorted positions of the first of an edge's two faces
    a, b = order[pair] // 3, order[pair + 1] // 3  # the faces on either side
    graph = coo_matrix((np.ones(len(a), dtype=np.int8), (a, b)), shape=(len(faces),) * 2)
    return connected_components(graph, directed=False)


def _boxes_overlap(lo: np.ndarray, hi: np.ndarray, chunk: int = 1024) -> np.ndarray:
    """(K, K) bool: whether axis-aligned boxes (K, 3) lo..hi (metres) intersect, diagonal False."""
    k = len(lo)
    out = np.zeros((k, k), dtype=bool)
    for start in range(0, k, chunk):
        sl = slice(start, start + chunk)
        out[sl] = np.all((lo[sl, None] <= hi[None]) & (lo[None] <= hi[sl, None]), axis=-1)
    np.fill_diagonal(out, False)
    return out


def _closed_faces(faces: np.ndarray, n_vertices: int) -> np.ndarray:
    """(F,) bool: faces whose three directed edges each occur once and meet exactly one opposite
    edge (the watertight, consistently wound condition, per face)."""
    tail, head = faces, np.roll(faces, -1, axis=1)
    forward = tail * n_vertices + head  # (F, 3) int64 keys of directed edges
    keys, counts = np.unique(forward, return_counts=True)

    def count(query: np.ndarray) -> np.ndarray:
        at = np.minimum(np.searchsorted(keys, query), len(keys) - 1)
        return np.where(keys[at] == query, counts[at], 0)

    ok = (count(forward) == 1) & (count(head * n_vertices + tail) == 1)
    return ok.all(axis=1)


def _ray_directions() -> np.ndarray:
    """(SIGN_RAYS, 3) fixed unit directions, generic so no ray runs along a mesh's axes."""
    directions = np.random.default_rng(20240611).normal(size=(SIGN_RAYS, 3))
    return directions / np.linalg.norm(directions, axis=1, keepdims=True)


def inside_mask(
    scene: open3d.t.geometry.RaycastingScene,
    mesh: trimesh.Trimesh,
    points: np.ndarray,
    open_overlap: bool,
    label: str = "mesh",
    chunk: int = 1 << 20,
) -> np.ndarray:
    """(N,) bool: which points (N, 3, metres) are inside the solid, by a majority of rays.

    ``scene`` holds ``mesh``'s triangles in order; ``open_overlap`` is :func:`solid`'s flag.
    Each of ``SIGN_RAYS`` rays votes by the parity of its surface crossings; the majority is not
    fooled by small holes.  Parity calls a point inside two overlapping parts outside: closed
    parts are unioned by :func:`solid`, so that can only happen where an open part overlaps
    another.  There the crossings are also counted with their direction (exits minus entries:
    the winding number along the ray of a consistently wound mesh) and a point that most rays
    find enclosed twice raises GeomprepError instead of getting the wrong sign.
    """
    open3d = import_open3d()  # only inside tests need it

    points = np.ascontiguousarray(points, dtype=np.float32)
    if not open_overlap:
        votes = scene.compute_occupancy(open3d.core.Tensor(points), nsamples=SIGN_RAYS)
        return votes.numpy() > 0.5
    if not mesh.is_winding_consistent:
        raise GeomprepError(
            f"{label}: parts of the mesh overlap, some are open and its faces are not "
            "consistently wound, so its inside is ambiguous: union the parts or close their "
            "holes in a modeller and re-export the mesh"
        )
    tri = np.asarray(mesh.vertices)[np.asarray(mesh.faces)]
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    if np.einsum("ij,ij->", tri[:, 0], normals) < 0:  # wound inwards overall
        normals = -normals
    inside = np.zeros(len(points), dtype=bool)
    for start in range(0, len(points), chunk):
        block = points[start : start + chunk]
        odd = np.zeros(len(block), dtype=np.int64)
        twice = np.zeros(len(block), dtype=np.int64)
        for direction in _ray_directions():
            rays = np.concatenate([block, np.broadcast_to(direction, block.shape)], axis=1)
            hits = scene.list_intersections(open3d.core.Tensor(rays.astype(np.float32)))
            ray, face = hits["ray_ids"].numpy(), hits["primitive_ids"].numpy()
            odd += np.bincount(ray, minlength=len(block)) % 2
            exits = np.sign(normals[face] @ direction)
            twice += np.bincount(ray, weights=exits, minlength=len(block)) >= 2
        doubled = np.flatnonzero(2 * twice > SIGN_RAYS)
        if doubled.size:
            where = np.array2string(block[doubled[0]], precision=3, separator=", ")
            raise GeomprepError(
                f"{label}: parts of the mesh overlap and not all of them are closed, so its "
                f"inside is ambiguous (the point {where} m is enclosed twice): union the parts "
                "or close their holes in a modeller and re-export the mesh"
            )
        inside[start : start + chunk] = 2 * odd > SIGN_RAYS
    return inside


def mass_properties(
    mesh: trimesh.Trimesh, voxels_per_side: int = 64, label: str = "mesh"
) -> tuple[float, np.ndarray, np.ndarray, str]:
    """Volume (m^3), centre of mass (3,), inertia per kg about the COM (3, 3, m^2), method.

    Of the solid the mesh stands for (:func:`solid`: overlapping closed parts count once), with
    the vertices moved to their bounding-box centre first so a mesh far from the origin keeps
    its precision; the COM is returned in the mesh's own frame.  See :func:`_mass_properties`.
    """
    shift = far_offset(np.asarray(mesh.vertices, dtype=np.float64))
    centred = trimesh.Trimesh(np.asarray(mesh.vertices) - shift, mesh.faces, process=False)
    volume, com, inertia, method = _mass_properties(solid(centred, label), voxels_per_side, label)
    return volume, com + shift, inertia, method


def _mass_properties(
    parts: Solid, voxels_per_side: int = 64, label: str = "mesh"
) -> tuple[float, np.ndarray, np.ndarray, str]:
    """Volume (m^3), centre of mass (3,), inertia per kg about the COM (3, 3, m^2), method, of
    a :func:`solid` whose vertices lie near the origin.

    A closed mesh integrates its own volume exactly ('volume'). An open scan (20 of the 78 YCB
    meshes are not watertight: each is a closed part plus 1-3 stray triangles on non-manifold
    edges) has no well-defined signed volume, so it is voxelized instead
    ('voxels'): a voxel centre is solid when most of several rays from it cross the surface an
    odd number of times, which small holes do not fool (:func:`inside_mask`). A scan too thin
    for that grid falls back to its convex hull ('convex_hull').
    """
    mesh = parts.mesh
    if mesh.is_watertight and mesh.volume > 0:
        return (
            float(mesh.volume),
            mesh.center_mass.copy(),
            mesh.moment_inertia / mesh.volume,
            "volume",
        )
    solid_centres, voxel = _solid_voxels(parts, voxels_per_side, label)
    if len(solid_centres) >= 200:
        com = solid_centres.mean(axis=0)
        r = solid_centres - com
        # Point masses plus each voxel's own inertia (a cube: voxel^2 / 6 per kg).
        inertia = (np.eye(3) * np.sum(r * r, axis=1).sum() - r.T @ r) / len(solid_centres)
        inertia += np.eye(3) * voxel**2 / 6.0
        return float(len(solid_centres) * voxel**3), com, inertia, "voxels"
    hull = mesh.convex_hull
    return (
        float(hull.volume),
        hull.center_mass.copy(),
        hull.moment_inertia / hull.volume,
        "convex_hull",
    )


def _solid_voxels(parts: Solid, voxels_per_side: int, label: str) -> tuple[np.ndarray, float]:
    """Centres (N, 3) of the voxels inside an open mesh by a 7-ray majority vote, and the voxel
    size (m). The grid covers the mesh's bounding box with ``voxels_per_side`` along its
    longest side."""
    o3d = import_open3d()  # only open scans need it

    mesh = parts.mesh
    lo, hi = mesh.bounds
    voxel = float((hi - lo).max()) / voxels_per_side
    axes = [np.arange(a + voxel / 2, b, voxel) for a, b in zip(lo, hi, strict=True)]
    centres = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(
        o3d.core.Tensor(np.asarray(mesh.vertices, dtype=np.float32)),
        o3d.core.Tensor(np.asarray(mesh.faces, dtype=np.uint32)),
    )
    return centres[inside_mask(scene, mesh, centres, parts.open_overlap, label)], voxel


def _checked_mass(
    volume: float,
    mass_kg: float | None,
    density_kg_m3: float | None,
    params: MeshParams,
    label: str,
) -> float:
    """The object's mass, kg: ``mass_kg``, else density times ``volume`` (m^3), refused when the
    density it implies lies outside ``params``' plausible range (a unit mistake)."""
    lo, hi = params.min_density_kg_m3, params.max_density_kg_m3
    if mass_kg is None:
        density = density_kg_m3 or params.density_kg_m3
        if not lo <= density <= hi:
            raise GeomprepError(
                f"{label}: density {density:g} kg/m^3 is outside the plausible {lo:g}-{hi:g} "
                "kg/m^3 ([mesh] min_density_kg_m3, max_density_kg_m3): give it in kg/m^3 "
                "(water is 1000)"
            )
        return density * volume
    if not mass_kg > 0:
        raise GeomprepError(
            f"{label}: mass {mass_kg} kg is not positive: fix masses.csv or the density"
        )
    density = mass_kg / volume
    implied = f"{label}: {mass_kg:g} kg in {volume:.3g} m^3 is {density:.3g} kg/m^3"
    if density > hi:
        raise GeomprepError(
            f"{implied}, denser than the plausible {hi:g} kg/m^3 ([mesh] max_density_kg_m3): "
            "is masses.csv in grams? it must be kilograms"
        )
    if density < lo:
        raise GeomprepError(
            f"{implied}, lighter than the plausible {lo:g} kg/m^3 ([mesh] min_density_kg_m3): "
            "check that masses.csv is in kilograms and the mesh in metres"
        )
    return float(mass_kg)


def normalize_mesh(
    source: trimesh.Trimesh,
    params: MeshParams,
    mass_kg: float | None,
    density_kg_m3: float | None,
    label: str = "mesh",
) -> NormalizedMesh:
    """Clean ``source``, check its units, shape and density, and move its origin to the COM.

    Mass: ``mass_kg`` if given, else ``density_kg_m3`` (or the params' default) times the volume.
    Raises GeomprepError for an empty, non-finite, wrongly scaled or flat mesh, overlapping
    parts whose inside is ambiguous, and a mass or density outside the plausible range.
    """
    vertices = np.asarray(source.vertices, dtype=np.float64)
    if len(vertices) == 0 or len(source.faces) == 0:
        raise GeomprepError(f"{label} is empty (no vertices or faces): re-export the mesh")
    check_finite_and_units(vertices, params, label)
    shift = far_offset(vertices)
    centred = trimesh.Trimesh(vertices - shift, np.asarray(source.faces), process=False)
    geometry = clean_geometry(centred, params.merge_tolerance_m, label)
    check_not_flat(np.asarray(geometry.vertices), params, label)
    if geometry.is_watertight:
        trimesh.repair.fix_normals(geometry)
    parts = solid(geometry, label, merged=True)
    geometry = parts.mesh
    volume, com, inertia_per_kg, com_method = _mass_properties(parts, label=label)
    if not volume > 0:
        raise GeomprepError(
            f"{label} encloses no volume ({com_method}): it is not a solid; close its surface "
            "and re-export it"
        )
    mass_kg = _checked_mass(volume, mass_kg, density_kg_m3, params, label)

    uv = None
    texture = None
    visual = getattr(source, "visual", None)
    if isinstance(visual, trimesh.visual.TextureVisuals) and visual.uv is not None:
        uv = np.asarray(visual.uv, dtype=np.float32)
        image = getattr(visual.material, "image", None)
        texture = image.convert("RGB") if image is not None else None
    origin = shift + com
    return NormalizedMesh(
        vertices=np.asarray(geometry.vertices) - com,
        faces=np.asarray(geometry.faces).astype(np.int32),
        mass_kg=float(mass_kg),
        volume_m3=volume,
        inertia_kg_m2=inertia_per_kg * mass_kg,
        watertight=bool(geometry.is_watertight),
        com_offset=origin,
        com_method=com_method,
        visual_vertices=vertices - origin,
        visual_faces=np.asarray(source.faces, dtype=np.int32),
        visual_uv=uv,
        texture=texture,
        n_unioned=parts.n_unioned,
    )


def reduced(
    vertices: np.ndarray, faces: np.ndarray, max_faces: int
) -> tuple[np.ndarray, np.ndarray]:
    """A coarser copy of a mesh, at most ``max_faces`` triangles, for stages that need its shape
    but not its detail: the box axes (``bbox``) and the convex decomposition (``decompose``).
    The mesh stage, the SDF (exact to 0.5 mm), the point clouds and the superquadric fit use the
    full mesh.

    vertices: (V, 3) metres; faces: (F, 3) int.  Returns (V', 3) float64 and (F', 3) int64,
    the input itself when F <= max_faces (every YCB google_16k mesh has 16,384 faces).

    Above the budget, open3d's vertex clustering merges the vertices in each cell of a grid
    sized so that about ``max_faces`` triangles remain (a surface of area A meshed at spacing c
    has about 2 A / c^2 of them), growing the cell until they fit.  It moves the surface by
    less than a cell diagonal (measured: at most 0.8 mm on a 550k-face mug at 50,000 faces) and
    costs about 0.3 s for 500k faces; open3d's quadric decimation keeps more detail but takes
    6-7 s for the same mesh, more than it saves in the stages that use it.
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    if len(faces) <= max_faces:
        return vertices, faces
    o3d = import_open3d()  # only large meshes need it

    area = 0.0
    for start in range(0, len(faces), 1 << 16):  # in blocks: (F, 3, 3) temporaries cost 200 MB
        tri = vertices[faces[start : start + (1 << 16)]]
        area += 0.5 * float(
            np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1).sum()
        )
    cell = np.sqrt(2.0 * area / max_faces)
    source = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(vertices), o3d.utility.Vector3iVector(faces)
    )
    while True:
        coarse = source.simplify_vertex_clustering(cell)
        coarse.remove_degenerate_triangles()
        coarse.remove_duplicated_triangles()
        coarse.remove_unreferenced_vertices()
        n_faces = len(coarse.triangles)
        if n_faces <= max_faces:
            return np.asarray(coarse.vertices), np.asarray(coarse.triangles, dtype=np.int64)
        # Triangle count goes as 1 / cell^2; 5 % more so the next try lands under the budget.
        cell *= 1.05 * np.sqrt(n_faces / max_faces)
