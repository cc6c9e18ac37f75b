"""Benchmark the batched SDF lookup (geomprep.sdf_lookup) at the trainer's batch size.

Usage: python bench/sdf_lookup.py [--envs 16384] [--points 5] [--objects 78] [--resolution 200]
                                  [--repeats 50] [--data-dir data/processed] [--threads N]
                                  [--spread surface|near|cube] [--no-compile]

Times ``SDFLookup.query`` for E envs x K fingertips (world points, random object poses and ids),
on the CPU and, if available, CUDA, in float32 and float16 storage, eager and under
``torch.compile`` (as the trainer's env calls it): milliseconds per query, the median (and the
10th and 90th percentiles) of --repeats calls after warm-up.  On the CPU both query kernels:
the C kernel (geomprep/sdf_lookup_cpu.c, the default) and the torch ops (the GPU's code, and the
CPU's without a C compiler), and their ratio.  Baselines in the same run, on the
same points, on a plain dense (N, R, R, R) stack: a naive lookup that gathers the 8 corners with
8 separate 4-D fancy-index reads, and scipy's RegularGridInterpolator called once per object
(its grids are numpy, so a loop over objects).
Prints the paper's figure (0.31 ms, RTX A6000), the targets, the memory of the resident grid
stacks (``SDFLookup.nbytes``) and what float16 storage moves the distances by.

Without --data-dir the grids are synthetic (distance to spheres of different radii): the timing
depends on the shapes of the tensors and the spread of the points, not on the values.
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import torch
from scipy.interpolate import RegularGridInterpolator

from geomgrasp.rotations import quat_to_matrix, random_quats
from geomprep.sdf import voxel_centers
from geomprep.sdf_lookup import SDFLookup, empty_grids

PAPER_MS = 0.31
TARGET_CPU_MS = 3.0
TARGET_GPU_MS = 0.1


def synthetic_grids(n_obj: int, resolution: int, extent: float = 0.5) -> Iterator[np.ndarray]:
    """N grids (R, R, R) float32, one at a time: signed distance to spheres of radius 3-10 cm
    at the origin."""
    c = voxel_centers(resolution, extent).astype(np.float32)
    r = np.sqrt(c[:, None, None] ** 2 + c[None, :, None] ** 2 + c[None, None, :] ** 2)
    for radius in np.linspace(0.03, 0.10, n_obj):
        yield r - np.float32(radius)


SPREADS = ("surface", "near", "cube")


def make_queries(
    n_env: int,
    n_points: int,
    n_obj: int,
    seed: int = 0,
    spread: str = "near",
    lookup: SDFLookup | None = None,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """World points (E, K, 3), poses (E, 3) and (E, 4) wxyz, ids (E,), object-frame points.

    spread, where the fingertips are in the object frame (the reads' working set, and so the
    cache and TLB misses, depends on it, not the values):
    - ``surface``: within 2 cm of the object's surface (voxels with |d| < 2 cm of its grid,
      jittered within the voxel; needs lookup), as while grasping: the realistic case.
    - ``near``: uniform within 15 cm of the origin (a 30 cm cube), approaching the object.
    - ``cube``: uniform over each object's whole grid cube: the worst case, every read a random
      one into the whole stack.
    """
    gen = torch.Generator().manual_seed(seed)
    ids = torch.randint(0, n_obj, (n_env,), generator=gen)
    if spread == "surface":
        assert lookup is not None, "spread='surface' needs the lookup's grids"
        local = torch.empty(n_env, n_points, 3)
        voxel = 1.0 / lookup.inv_voxel
        for n in range(n_obj):
            rows = (ids == n).nonzero().flatten()
            if len(rows) == 0:
                continue
            shell = (lookup.grid(n).abs() < 0.02).nonzero().float()
            pick = shell[torch.randint(0, len(shell), (len(rows) * n_points,), generator=gen)]
            pick += torch.rand(pick.shape, generator=gen) - 0.5
            centre = lookup.bounds_min[n] + (pick + 0.5) * voxel[n]
            local[rows] = centre.reshape(len(rows), n_points, 3)
    elif spread == "near":
        local = (torch.rand(n_env, n_points, 3, generator=gen) - 0.5) * 0.3
    elif spread == "cube":
        assert lookup is not None, "spread='cube' needs the lookup's grid bounds"
        lo = lookup.bounds_min[ids][:, None, :]
        size = lookup.resolution / lookup.inv_voxel[ids][:, None, None]
        local = lo + torch.rand(n_env, n_points, 3, generator=gen) * size
    else:
        raise ValueError(f"spread {spread!r}: one of {SPREADS}")
    pos = (torch.rand(n_env, 3, generator=gen) - 0.5) * 2.0
    quat = random_quats(n_env, generator=gen)
    world = torch.einsum("eij,ekj->eki", quat_to_matrix(quat), local) + pos[:, None, :]
    return world, pos, quat, ids, local


def naive_gather(
    grids: torch.Tensor, lookup: SDFLookup, local: torch.Tensor, ids: torch.Tensor
) -> torch.Tensor:
    """The straightforward version: 8 separate [id, i, j, k] reads of a dense (N, R, R, R)
    stack, no clamping rule subtleties.

    local: (E, K, 3) object-frame points, metres; returns (E, K) float32.
    """
    r = grids.shape[1]
    u = (local - lookup.bounds_min[ids][:, None]) * lookup.inv_voxel[ids][:, None, None] - 0.5
    u = u.clamp(0.0, r - 1.0)
    base = u.floor().clamp(max=r - 2.0)
    t = u - base
    i, j, k = base.long().unbind(-1)
    n = ids[:, None].expand_as(i)
    out = torch.zeros(local.shape[:2])
    for di in (0, 1):
        for dj in (0, 1):
            for dk in (0, 1):
                w = (
                    (t[..., 0] if di else 1 - t[..., 0])
                    * (t[..., 1] if dj else 1 - t[..., 1])
                    * (t[..., 2] if dk else 1 - t[..., 2])
                )
                out += w * grids[n, i + di, j + dj, k + dk].float()
    return out


def scipy_lookup(
    interpolators: list[RegularGridInterpolator], local: np.ndarray, ids: np.ndarray
) -> np.ndarray:
    """RegularGridInterpolator per object over its envs' points: (E, K) float64."""
    out = np.empty(local.shape[:2])
    for n in np.unique(ids):
        rows = ids == n
        out[rows] = interpolators[n](local[rows].reshape(-1, 3)).reshape(-1, local.shape[1])
    return out


def times_ms(fn: Callable[[], object], repeats: int, sync: Callable[[], None]) -> list[float]:
    """Wall times of fn in milliseconds, sorted, over repeats calls after 3 warm-up calls."""
    for _ in range(3):
        fn()
    sync()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        sync()
        times.append((time.perf_counter() - start) * 1e3)
    return sorted(times)


def median_ms(fn: Callable[[], object], repeats: int, sync: Callable[[], None]) -> float:
    """Median wall time of fn in milliseconds over repeats calls, after 3 warm-up calls."""
    return statistics.median(times_ms(fn, repeats, sync))


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--envs", type=int, default=16384)
    parser.add_argument("--points", type=int, default=5)
    parser.add_argument("--objects", type=int, default=78)
    parser.add_argument("--resolution", type=int, default=200)
    parser.add_argument("--repeats", type=int, default=50)
    parser.add_argument("--data-dir", type=Path, default=None, help="use data/processed/*.h5")
    parser.add_argument(
        "--devices", default="all",
        help="comma list of cpu, cuda; 'all': the CPU and, where present, the GPU",
    )
    parser.add_argument(
        "--compile",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="also time the query under torch.compile, as the trainer's env runs it",
    )
    parser.add_argument(
        "--threads", type=int, default=None, help="torch CPU threads (default: torch's choice)"
    )
    parser.add_argument(
        "--spread",
        choices=SPREADS,
        default="surface",
        help="fingertips within 2 cm of the surface (realistic), 15 cm of the origin, or "
        "anywhere in the grid cube (worst case); see make_queries",
    )
    args = parser.parse_args(argv)
    if args.threads:
        # On a loaded 2-core machine 2 intra-op threads wait on each other at every op.
        torch.set_num_threads(args.threads)

    r, n_obj = args.resolution, args.objects
    print(
        f"paper: {PAPER_MS} ms per query (RTX A6000); targets: <= {TARGET_CPU_MS} ms on the 2-core "
        f"CPU, <= {TARGET_GPU_MS} ms on a GPU; torch threads: {torch.get_num_threads()}"
    )

    if args.data_dir is not None:
        paths = sorted(args.data_dir.glob("*.h5"))[:n_obj]
        n_obj = len(paths)

        def build(dtype: torch.dtype) -> SDFLookup:
            return SDFLookup.from_hdf5(paths, dtype=dtype)
    else:

        def build(dtype: torch.dtype) -> SDFLookup:
            bounds, voxel = np.full((n_obj, 3), -0.5), np.full(n_obj, 1.0 / r)
            return SDFLookup(synthetic_grids(n_obj, r), bounds, voxel, dtype=dtype)

    lookups = {"float32": build(torch.float32), "float16": build(torch.float16)}
    lookup32 = lookups["float32"]
    print(
        f"grid memory resident (bricks), {n_obj} objects at {lookup32.resolution}^3: "
        + ", ".join(f"{k} {lk.nbytes() / 1e9:.2f} GB" for k, lk in lookups.items())
    )
    world, pos, quat, ids, local = make_queries(
        args.envs, args.points, n_obj, spread=args.spread, lookup=lookup32
    )
    print(f"{args.envs} envs x {args.points} points, {n_obj} objects, spread {args.spread}")

    devices = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])
    if args.devices != "all":
        devices = [d for d in args.devices.split(",") if d in devices]
    with torch.no_grad():
        for device in devices:
            sync = torch.cuda.synchronize if device == "cuda" else (lambda: None)
            q = [x.to(device) for x in (world, pos, quat, ids)]
            target = TARGET_CPU_MS if device == "cpu" else TARGET_GPU_MS
            for label, lookup in lookups.items():
                lk = lookup.to(device)
                with_c_kernel = device == "cpu" and lookup.use_cpu_kernel
                # On the CPU, the C kernel (the default) and the torch ops (the GPU's path, and
                # the fallback without a C compiler) on the same lookup.
                kernels = {"C kernel": True} if with_c_kernel else {}
                kernels["torch ops"] = False
                medians = {}
                for kernel, use_c in kernels.items():
                    lk.use_cpu_kernel = use_c
                    # The trainer's env calls the lookup inside its torch.compile'd step.
                    compiled = compile_query(lk) if args.compile else None
                    for mode, fn in (("eager", lk.query), ("compiled", compiled)):
                        if fn is None:
                            continue
                        ts = times_ms(lambda fn=fn, q=q: fn(*q), args.repeats, sync)
                        medians[kernel, mode] = statistics.median(ts)
                        # The spread says how much a shared machine disturbed the run.
                        p10, p90 = ts[len(ts) // 10], ts[(len(ts) * 9) // 10]
                        print(
                            f"{device:<5} SDFLookup.query {label} {kernel:<9} {mode:<8}: "
                            f"{medians[kernel, mode]:8.3f} ms (p10 {p10:.3f}, p90 {p90:.3f})   "
                            f"(target <= {target} ms)"
                        )
                lk.use_cpu_kernel = with_c_kernel
                if with_c_kernel:
                    print(
                        f"{device:<5}   {label}, eager: torch ops / C kernel = "
                        f"{medians['torch ops', 'eager'] / medians['C kernel', 'eager']:.1f}x"
                    )
                lookup.to("cpu")  # Module.to moves in place; the baselines below run on CPU

        # What float16 storage costs in accuracy, on the timed points.
        q = (world, pos, quat, ids)
        d32, d16 = lookups["float32"].query(*q), lookups["float16"].query(*q)
        err16 = (d16 - d32).abs()
        near = d32.abs() < 0.02
        near_err = float(err16[near].amax()) if near.any() else 0.0
        print(
            f"float16 vs float32 on these points: max |diff| {float(err16.max()) * 1e6:.1f} um, "
            f"within 2 cm of the surface {near_err * 1e6:.1f} um "
            f"({int(near.sum())} of {near.numel()} points)"
        )

        # Baselines on a plain dense (N, R, R, R) float32 stack of the same grids.
        dense = empty_grids((n_obj, r, r, r))
        for n in range(n_obj):
            dense[n] = lookup32.grid(n)
        local_cpu = torch.bmm(world - pos[:, None], quat_to_matrix(quat))
        naive_ms = median_ms(
            lambda: naive_gather(dense, lookup32, local_cpu, ids),
            max(5, args.repeats // 5),
            lambda: None,
        )
        fast_ms = median_ms(
            lambda: lookup32.query_local(local_cpu, ids), args.repeats, lambda: None
        )
        err = float(
            (naive_gather(dense, lookup32, local_cpu, ids) - lookup32.query_local(local_cpu, ids))
            .abs()
            .max()
        )
        print(
            f"cpu   baseline naive 8-gather, dense float32 (object frame): {naive_ms:8.3f} ms; "
            f"ours, float32 bricks (object frame) {fast_ms:.3f} ms; ratio "
            f"{naive_ms / fast_ms:.1f}x; max diff {err:.1e} m"
        )
        grids_np = dense.numpy()
        c = voxel_centers(r)
        interps = [
            RegularGridInterpolator((c, c, c), grids_np[n], bounds_error=False, fill_value=None)
            for n in range(n_obj)
        ]
        local_np, ids_np = local_cpu.numpy().astype(np.float64), ids.numpy()
        scipy_ms = median_ms(lambda: scipy_lookup(interps, local_np, ids_np), 5, lambda: None)
        diff = np.abs(
            scipy_lookup(interps, local_np, ids_np) - lookup32.query_local(local_cpu, ids).numpy()
        ).max()
        print(
            f"cpu   baseline scipy RegularGridInterpolator per object: {scipy_ms:8.3f} ms; "
            f"ratio {scipy_ms / fast_ms:.1f}x; max diff {diff:.1e} m"
        )


def compile_query(lookup: SDFLookup) -> Callable | None:
    """``torch.compile(lookup.query)``, or None (with a note) where it cannot compile."""
    fn = torch.compile(lookup.query, dynamic=False)
    try:
        fn(*make_queries(1, 1, 1)[:4])  # compile now (one env, one point), not in the timing
    except Exception as err:  # noqa: BLE001 (any compiler failure: report and go on)
        print(f"torch.compile unavailable ({str(err).splitlines()[0][:120]}): eager only")
        return None
    return fn


if __name__ == "__main__":
    main()
