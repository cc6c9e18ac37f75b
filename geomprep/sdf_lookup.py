"""Batched signed-distance lookup in the objects' SDF grids, on the training device (torch).

All objects' grids are stacked into one tensor (of bricks, below), so a query for E environments,
each holding one object at its own pose, is one pass over the points with no Python loop over
environments: a C kernel on the CPU (geomprep/sdf_lookup_cpu.py), a handful of tensor
operations on a GPU (which ``torch.compile`` fuses into the trainer's env step):

    lookup = SDFLookup.from_hdf5([f"data/processed/{n}.h5" for n in names], device="cuda")
    d = lookup.query(points_world, object_pos, object_quat, object_ids)   # (E, K) metres

Conventions (the data contract, docs/data-contract.md):
- ``grid[i, j, k]`` is the signed distance (metres, negative inside) at the voxel centre
  ``bounds_min + ((i, j, k) + 0.5) * voxel_size`` of the object frame (origin at the COM).
- ``object_quat`` is (w, x, y, z), the rotation R taking object-frame vectors to the world
  (MuJoCo's ``xquat`` order); a world point p is at ``R^T (p - object_pos)`` in the object frame.
  Quaternions are normalised here, so slightly denormalised ones from an integrator are fine.
- Inside the grid cube the value is the trilinear interpolation of the 8 surrounding voxel
  centres (in the outer half voxel, where fewer than 8 exist, the coordinate is clamped to the
  outermost centres).  A point outside the cube gets the value of the closest voxel (its index
  clamped to the grid, the rule of Mosbach & Behnke 2022); this under-estimates the distance
  there, which is harmless for fingertips half a metre from the object.
- A point with a NaN coordinate gets NaN.

Storage: bricks.  Each grid is cut into cubes of 4 x 4 x 4 cells, and each brick stores the
5 x 5 x 5 voxel centres at its cells' corners (the shared faces are stored twice), padded to 128
values.  The 8 corners of any cell then lie in one brick, 31 values apart at most: one or two
adjacent cache lines per query in float16, where a plain (R, R, R) array puts them on 4 lines
up to R^2 values apart.  The reads into GB-sized stacks are what a query costs on a CPU
(16,384 x 5 fingertips in 78 grids of 200^3: 3.5 ms for the dense float32 gather alone, 1.2 ms
for the float16 bricks).  The bricks hold 128 / 64 = 2x the values of the dense grid, so 78
objects at 200^3 take 2.50 GB in float16 (the trainer's default) and 4.99 GB in float32.

float16 rounds a stored value d by at most ``|d| * 2**-11`` (below float16's smallest normal,
6.1e-5 m, by at most 2**-25 m), and interpolation is a convex combination, so a query moves by
at most ``2**-11`` times the largest of its 8 corner magnitudes: <= 10 um within 2 cm of the
surface, <= 0.43 mm at the grid's far corners (0.87 m).  Arithmetic is float32 either way.
"""

from __future__ import annotations

import ctypes
import mmap
import sys
from collections.abc import Iterable, Sequence
from pathlib import Path

import numpy as np
import torch

from geomgrasp.rotations import quat_to_matrix
from geomprep import sdf_lookup_cpu
from geomprep.contract import read_sdf_frame, read_sdf_grid
from geomprep.errors import GeomprepError

# Relative rounding error of float16 storage (half an ulp of an 11-bit significand).
FLOAT16_RELATIVE_ERROR = 2.0**-11

BRICK_CELLS = 4
"""Cells along each edge of a brick; a brick stores (BRICK_CELLS + 1)^3 voxel centres."""
BRICK_VALUES = 128
"""Values per brick: 5^3 = 125 centres, padded so that bricks start on cache lines."""
# Offsets of a centre (i, j, k) of a brick (each in 0..4) within it: i * 25 + j * 5 + k.
_BRICK_STRIDES = ((BRICK_CELLS + 1) ** 2, BRICK_CELLS + 1, 1)
# Steps within a brick to a cell's 8 corners, dk slowest and di fastest, the order in which the
# lerps consume them (z first).  sdf_lookup_cpu.c has the same layout constants.
_CORNER_STEPS = tuple(
    di * _BRICK_STRIDES[0] + dj * _BRICK_STRIDES[1] + dk
    for dk in (0, 1)
    for dj in (0, 1)
    for di in (0, 1)
)


def bricks_per_axis(resolution: int) -> int:
    """Bricks along each axis of an R^3 grid: its R - 1 cells in bricks of BRICK_CELLS."""
    return -(-(resolution - 1) // BRICK_CELLS)


def to_bricks(grid: torch.Tensor) -> torch.Tensor:
    """(B, B, B, BRICK_VALUES) bricks of one (R, R, R) grid, B = ``bricks_per_axis(R)``.

    Brick (a, b, c) holds centres 4a..4a+4 x 4b..4b+4 x 4c..4c+4 at ``i * 25 + j * 5 + k``;
    centres past the grid's last one (when R - 1 is not a multiple of 4) repeat the edge value,
    and no cell inside the grid uses them.  The 3 padding values are zero.
    """
    r = grid.shape[0]
    b = bricks_per_axis(r)
    pad = BRICK_CELLS * b + 1 - r
    padded = torch.nn.functional.pad(grid[None, None], (0, pad) * 3, mode="replicate")[0, 0]
    n = BRICK_CELLS + 1
    cubes = padded.unfold(0, n, BRICK_CELLS).unfold(1, n, BRICK_CELLS).unfold(2, n, BRICK_CELLS)
    out = grid.new_zeros(b, b, b, BRICK_VALUES)
    out[..., : n**3] = cubes.reshape(b, b, b, n**3)
    return out


_HUGE_PAGE = 2 << 20
_MADV_HUGEPAGE = 14


def empty_grids(
    shape: Sequence[int], dtype: torch.dtype = torch.float32, device: str | torch.device = "cpu"
) -> torch.Tensor:
    """Uninitialised tensor, on Linux CPU backed by 2 MiB transparent huge pages.

    A query's reads land all over the GB-sized grid stack; with 4 KiB pages nearly every one
    also misses the TLB (the 8 x 81,920 corner reads of 16,384 x 5 points in 78 dense grids of
    200^3, on a 2-core EPYC: 6.0 ms with 4 KiB pages, 3.2 ms with huge pages).  The pages are
    requested with madvise(MADV_HUGEPAGE) before anything is written to them (in the kernel's
    usual THP mode, ``madvise``, memory gets none otherwise); elsewhere this is ``torch.empty``.
    SDFLookup allocates its brick stack with it.
    """
    grids = torch.empty(tuple(shape), dtype=dtype, device=device)
    if grids.device.type == "cpu" and sys.platform == "linux":
        _advise_huge_pages(grids)
    return grids


def _advise_huge_pages(tensor: torch.Tensor) -> None:
    """Best effort: madvise(MADV_HUGEPAGE) the whole 2 MiB pages inside tensor's memory."""
    start = -(-tensor.data_ptr() // _HUGE_PAGE) * _HUGE_PAGE
    end = (tensor.data_ptr() + tensor.numel() * tensor.element_size()) // _HUGE_PAGE * _HUGE_PAGE
    if end <= start:
        return
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.madvise.argtypes = [ctypes.c_void_p, ctypes.c_size_t, ctypes.c_int]
        libc.madvise(start, end - start, getattr(mmap, "MADV_HUGEPAGE", _MADV_HUGEPAGE))
    except (OSError, AttributeError):
        pass


class SDFLookup(torch.nn.Module):
    """SDF grids of N objects, stored as bricks, with a batched, pose-aware trilinear query.

    Buffers (moved by ``.to(device)`` like any module state):
    - ``bricks``: (N, B, B, B, 128) float32 or float16, metres, negative inside (see the module
      docstring; ``grid(n)`` gives object n's dense (R, R, R) grid back).
    - ``bounds_min``: (N, 3) float32, metres, each grid cube's lower corner (object frame).
    - ``inv_voxel``: (N,) float32, 1 / voxel size, 1/metres; ``shift``: (N, 3) float32,
      ``-bounds_min / voxel - 0.5``, so ``p * inv_voxel + shift`` is p in voxel-centre units.
    """

    bricks: torch.Tensor
    bounds_min: torch.Tensor
    inv_voxel: torch.Tensor
    shift: torch.Tensor

    def __init__(
        self,
        grids: Iterable[torch.Tensor | np.ndarray],
        bounds_min: torch.Tensor | np.ndarray,
        voxel_size: torch.Tensor | np.ndarray | Sequence[float],
        dtype: torch.dtype = torch.float32,
        names: Sequence[str] | None = None,
        device: str | torch.device = "cpu",
        kernel: str = "auto",
    ) -> None:
        """grids: the N objects' (R, R, R) grids, metres (an (N, R, R, R) array or any iterable
        of grids: they are bricked one at a time, so a generator keeps one dense grid in
        memory); bounds_min: (N, 3) metres; voxel_size: (N,) metres.

        dtype: storage type, torch.float32 or torch.float16 (see module docstring).
        names: optional object names, ``names[i]`` being object id i.
        kernel: how CPU queries run: ``"auto"``, the C kernel (sdf_lookup_cpu.py) where it
        builds, else torch ops; ``"torch"``, always torch ops.  GPU queries are torch ops.
        """
        super().__init__()
        if dtype not in (torch.float32, torch.float16):
            raise GeomprepError(f"SDF lookup dtype {dtype}: use torch.float32 or torch.float16")
        if kernel not in ("auto", "torch"):
            raise GeomprepError(f"SDF lookup kernel {kernel!r}: use 'auto' or 'torch'")
        # Built (or loaded) here, once, not while torch.compile traces a query.
        self.use_cpu_kernel = (
            kernel == "auto"
            and torch.device(device).type == "cpu"
            and sdf_lookup_cpu.kernel() is not None
        )
        bounds = torch.as_tensor(np.asarray(bounds_min, dtype=np.float32)).reshape(-1, 3)
        n_obj = bounds.shape[0]
        voxel = torch.as_tensor(np.asarray(voxel_size, dtype=np.float32)).reshape(n_obj)
        self.names = list(names) if names is not None else [str(i) for i in range(n_obj)]
        bricks: torch.Tensor | None = None
        count = 0
        for n, grid in enumerate(grids):
            grid = torch.as_tensor(grid)
            if grid.ndim != 3 or not grid.shape[0] == grid.shape[1] == grid.shape[2]:
                raise GeomprepError(
                    f"SDF grid {n} has shape {tuple(grid.shape)}: need (R, R, R)"
                )
            if grid.shape[0] < 2:
                raise GeomprepError("SDF grids need at least 2 voxels per axis to interpolate")
            if bricks is None:
                self.resolution = int(grid.shape[0])
                b = bricks_per_axis(self.resolution)
                bricks = empty_grids((n_obj, b, b, b, BRICK_VALUES), dtype, device)
            elif grid.shape[0] != self.resolution:
                raise GeomprepError(
                    f"SDF grid {n} is {tuple(grid.shape)} but grid 0 is {(self.resolution,) * 3}:"
                    " build all objects at one SDF resolution"
                )
            if n >= n_obj:
                raise GeomprepError(f"more SDF grids than bounds ({n_obj})")
            bricks[n] = to_bricks(grid.to(dtype=torch.float32)).to(device=device, dtype=dtype)
            count = n + 1
        if bricks is None or count != n_obj:
            raise GeomprepError(f"{count} SDF grids for {n_obj} bounds: pass one grid per object")
        self.register_buffer("bricks", bricks)
        self.register_buffer("bounds_min", bounds.clone().to(device))
        self.register_buffer("inv_voxel", (1.0 / voxel).to(device))
        # u = p / voxel + shift puts voxel i's centre at u = i.
        self.register_buffer("shift", (-bounds / voxel[:, None] - 0.5).to(device))

    @classmethod
    def from_hdf5(
        cls,
        paths: Sequence[str | Path],
        dtype: torch.dtype = torch.float32,
        device: str | torch.device = "cpu",
        kernel: str = "auto",
    ) -> SDFLookup:
        """Load the SDF grids and their frames from processed object files (the names in
        ``geomprep.contract``), object id = list index.

        paths: ``data/processed/<name>.h5`` files (or stage files with an ``sdf`` group); all
        grids must have the same resolution.  Grids are read and bricked one at a time into the
        preallocated stack on ``device``, so peak host memory is one grid, not all of them.
        dtype, device, kernel: as for the constructor.
        """
        if not paths:
            raise GeomprepError("no SDF files given: pass at least one processed .h5 file")

        # Attributes first (the stack is allocated for all objects), then grids one at a time.
        frames = [read_sdf_frame(p) for p in paths]
        return cls(
            (read_sdf_grid(p) for p in paths),
            np.stack([bounds_min for bounds_min, _ in frames]),
            np.array([voxel_size for _, voxel_size in frames]),
            dtype=dtype,
            names=[Path(p).stem for p in paths],
            device=device,
            kernel=kernel,
        )

    @property
    def bricks_per_axis(self) -> int:
        return self.bricks.shape[1]

    @property
    def dtype(self) -> torch.dtype:
        """Storage type of the grids."""
        return self.bricks.dtype

    def nbytes(self) -> int:
        """Bytes held by the brick stack."""
        return self.bricks.numel() * self.bricks.element_size()

    def grid(self, n: int) -> torch.Tensor:
        """Object n's dense grid (R, R, R), in the storage dtype (for tests and inspection)."""
        r, nb = self.resolution, BRICK_CELLS + 1
        b = self.bricks_per_axis
        c = torch.arange(r, device=self.bricks.device)
        brick = (c // BRICK_CELLS).clamp(max=b - 1)
        within = c - BRICK_CELLS * brick
        cubes = self.bricks[n, ..., : nb**3].reshape(b, b, b, nb, nb, nb)
        bi, bj, bk = brick.view(-1, 1, 1), brick.view(1, -1, 1), brick.view(1, 1, -1)
        wi, wj, wk = within.view(-1, 1, 1), within.view(1, -1, 1), within.view(1, 1, -1)
        return cubes[bi, bj, bk, wi, wj, wk]

    def query(
        self,
        points_world: torch.Tensor,
        object_pos: torch.Tensor,
        object_quat: torch.Tensor,
        object_ids: torch.Tensor,
    ) -> torch.Tensor:
        """Signed distance (E, K) float32, metres, of K world points to each env's object.

        points_world: (E, K, 3) metres; object_pos: (E, 3) metres, the object frame's origin
        (COM) in the world; object_quat: (E, 4) (w, x, y, z), object-to-world rotation;
        object_ids: (E,) integer, index into the stacked grids.  A point with a NaN
        coordinate gets NaN.
        """
        if self.use_cpu_kernel and points_world.device.type == "cpu":
            return torch.ops.geomprep.sdf_query_cpu(
                self.bricks, self.resolution, points_world, object_pos, object_quat, object_ids,
                self.inv_voxel, self.shift,
            )  # fmt: skip
        return self._query_torch(points_world, object_pos, object_quat, object_ids)

    forward = query  # calling the module is querying it

    def query_local(self, local: torch.Tensor, object_ids: torch.Tensor) -> torch.Tensor:
        """Signed distance (E, K) float32, metres, at object-frame points local (E, K, 3)."""
        n_env = local.shape[0]
        identity = local.new_tensor([1.0, 0.0, 0.0, 0.0]).expand(n_env, 4)
        return self.query(local, local.new_zeros(n_env, 3), identity, object_ids)

    def _query_torch(
        self,
        points_world: torch.Tensor,
        object_pos: torch.Tensor,
        object_quat: torch.Tensor,
        object_ids: torch.Tensor,
    ) -> torch.Tensor:
        """``query`` in torch ops: on a GPU (where ``torch.compile`` fuses it into the env step)
        and on a CPU without the C kernel.  Same rule as sdf_lookup_cpu.c, to float32 rounding."""
        r = self.resolution
        ids = object_ids.long()
        local = (points_world.float() - object_pos.float()[:, None]) @ quat_to_matrix(
            object_quat.float()
        )
        u = local * self.inv_voxel[ids][:, None, None] + self.shift[ids][:, None, :]
        nan = u.isnan().any(-1)
        # Outside the cube (more than half a voxel beyond the outer centres) a point snaps to
        # the closest voxel; in the outer half voxel the coordinate is clamped to the outer
        # centres, and the cell stays inside the grid (t is then 0 or 1).
        outside = ((u < -0.5) | (u > r - 0.5)).any(-1, keepdim=True)
        u = u.nan_to_num(0.0).clamp(0.0, r - 1.0)
        lower = u.floor().clamp(max=r - 2.0)
        t = u - lower
        t = torch.where(outside, t.round(), t)
        cell = lower.long()
        nb = self.bricks_per_axis
        brick = cell // BRICK_CELLS
        within = cell - BRICK_CELLS * brick
        si, sj, sk = _BRICK_STRIDES
        flat = (
            ((ids[:, None] * nb + brick[..., 0]) * nb + brick[..., 1]) * nb + brick[..., 2]
        ) * BRICK_VALUES + within[..., 0] * si + within[..., 1] * sj + within[..., 2] * sk
        values = self.bricks.view(-1)
        corner = [values[flat + step].float() for step in _CORNER_STEPS]
        tx, ty, tz = t.unbind(-1)
        c = [torch.lerp(corner[i], corner[i + 4], tz) for i in range(4)]  # (dj, di)
        c = [torch.lerp(c[i], c[i + 2], ty) for i in range(2)]  # di
        return torch.lerp(c[0], c[1], tx).masked_fill(nan, float("nan"))


def naive_query(
    grids: np.ndarray,
    bounds_min: np.ndarray,
    voxel_size: np.ndarray,
    local: np.ndarray,
    object_ids: np.ndarray,
) -> np.ndarray:
    """Reference implementation, one point at a time in float64: (E, K) signed distances.

    grids (N, R, R, R); bounds_min (N, 3); voxel_size (N,); local (E, K, 3) object-frame points,
    metres; object_ids (E,).  Slow; for tests and as the benchmark's baseline.
    """
    r = grids.shape[1]
    out = np.empty(local.shape[:2])
    for e in range(local.shape[0]):
        n = int(object_ids[e])
        for k in range(local.shape[1]):
            u = (local[e, k] - bounds_min[n]) / voxel_size[n] - 0.5
            if np.any((u < -0.5) | (u > r - 0.5)):
                i, j, kk = np.clip(np.floor(u + 0.5), 0, r - 1).astype(int)
                out[e, k] = grids[n, i, j, kk]
                continue
            u = np.clip(u, 0, r - 1)
            base = np.minimum(np.floor(u), r - 2).astype(int)
            t = u - base
            value = 0.0
            for corner in np.ndindex(2, 2, 2):
                w = np.prod(np.where(np.array(corner) == 1, t, 1 - t))
                i, j, kk = base + np.array(corner)
                value += w * float(grids[n, i, j, kk])
            out[e, k] = value
    return out
