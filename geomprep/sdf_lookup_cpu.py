"""The SDF lookup's CPU kernel: ``sdf_lookup_cpu.c``, compiled on first use and called as the
torch op ``geomprep::sdf_query_cpu``.

On a CPU the query is bound by its 8 corner reads into a GB-sized stack of grids, and written in
torch ops it also makes ~25 passes over the points for the index arithmetic around them.  The C
kernel computes each point's index once, prefetches its corners' cache lines at once and reads
them a block of points later (16,384 x 5 points in 78 grids of 200^3, float16, on the 2-core
EPYC: 1.1-2.1 ms; 10-13 ms for SDFLookup's plain torch ops, 3-5 ms for torch ops tuned for the
CPU; see docs/benchmarks.md).

As a custom op it is opaque to ``torch.compile``: the trainer's compiled env step calls it with
no graph break, and the surrounding arithmetic is still fused.

Build: ``cc -O3 -march=native -fopenmp -shared`` (``$CC`` if set), about a second, cached under
``$XDG_CACHE_HOME/geomprep`` (``~/.cache/geomprep``) by a hash of the source, the command and the
CPU.  Where it cannot be built (no C compiler) ``kernel()`` warns once and returns None, and
SDFLookup uses its torch path.
"""

from __future__ import annotations

import ctypes
import functools
import hashlib
import os
import platform
import subprocess
import warnings
from pathlib import Path

import torch

from geomprep.errors import GeomprepError

SOURCE = Path(__file__).with_suffix(".c")
FLAGS = ("-O3", "-march=native", "-fopenmp", "-shared", "-fPIC", "-std=gnu11")


def _cache_dir() -> Path:
    root = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(root) / "geomprep"


def _cpu_signature() -> str:
    """The CPU model and feature flags (-march=native code is only valid on such a CPU)."""
    try:
        lines = Path("/proc/cpuinfo").read_text().splitlines()
    except OSError:
        return platform.machine() + platform.processor()
    wanted = ("model name", "flags", "Features", "CPU part")
    return "\n".join(sorted({line for line in lines if line.startswith(wanted)}))


@functools.cache
def kernel() -> ctypes.CDLL | None:
    """The compiled kernel (built on the first call or loaded from the cache), or None with a
    warning where it cannot be built."""
    compiler = os.environ.get("CC", "cc")
    command = [compiler, *FLAGS]
    key = hashlib.sha256(
        "\0".join([SOURCE.read_text(), " ".join(command), _cpu_signature()]).encode()
    ).hexdigest()[:16]
    path = _cache_dir() / f"sdf_lookup_cpu-{key}.so"
    if not path.exists():
        tmp = path.with_name(f"{path.name}.{os.getpid()}.tmp")
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            subprocess.run(
                [*command, "-o", str(tmp), str(SOURCE)], check=True, capture_output=True, text=True
            )
            os.replace(tmp, path)  # atomic: a concurrent build or a killed one leaves no half file
        except (OSError, subprocess.CalledProcessError) as err:
            lines = (getattr(err, "stderr", None) or str(err)).strip().splitlines() or [""]
            detail = next((line for line in lines if "error" in line), lines[-1])
            warnings.warn(
                f"cannot build the SDF lookup's CPU kernel with `{compiler}` ({detail.strip()}); "
                "the lookup uses its slower torch path (install gcc, or set CC)",
                stacklevel=2,
            )
            return None
        finally:
            tmp.unlink(missing_ok=True)
    lib = ctypes.CDLL(str(path))
    p, i64 = ctypes.c_void_p, ctypes.c_int64
    lib.sdf_query.argtypes = [p, ctypes.c_int, i64, i64, i64, p, p, p, p, p, p, i64, i64, p,
                              ctypes.c_int]  # fmt: skip
    lib.sdf_query.restype = i64
    return lib


@torch.library.custom_op("geomprep::sdf_query_cpu", mutates_args=(), device_types="cpu")
def sdf_query_cpu(
    bricks: torch.Tensor,
    resolution: int,
    points_world: torch.Tensor,
    object_pos: torch.Tensor,
    object_quat: torch.Tensor,
    object_ids: torch.Tensor,
    inv_voxel: torch.Tensor,
    shift: torch.Tensor,
) -> torch.Tensor:
    """SDFLookup.query on the CPU: (E, K) float32 metres (arguments as SDFLookup's buffers and
    query's; any float dtype and layout).  Needs ``kernel()``."""
    lib = kernel()
    if lib is None:
        raise GeomprepError("the SDF lookup's CPU kernel is not built: use SDFLookup's torch path")
    n_env, k = points_world.shape[:2]
    points = points_world.detach().to(torch.float32).contiguous()
    pos = object_pos.detach().to(torch.float32).contiguous()
    quat = object_quat.detach().to(torch.float32).contiguous()
    ids = object_ids.to(torch.int64).contiguous()
    out = torch.empty(n_env, k, dtype=torch.float32)
    if out.numel() == 0:
        return out
    bad = lib.sdf_query(
        bricks.data_ptr(), int(bricks.dtype == torch.float16), bricks.shape[0], bricks.shape[1],
        resolution, points.data_ptr(), pos.data_ptr(), quat.data_ptr(), ids.data_ptr(),
        inv_voxel.data_ptr(), shift.data_ptr(), n_env, k, out.data_ptr(), torch.get_num_threads(),
    )  # fmt: skip
    if bad:
        raise GeomprepError(
            f"{bad} envs have an object id outside 0..{bricks.shape[0] - 1}: "
            "ids index the lookup's objects (SDFLookup.names)"
        )
    return out


@sdf_query_cpu.register_fake
def _(bricks, resolution, points_world, object_pos, object_quat, object_ids, inv_voxel, shift):
    return points_world.new_empty(points_world.shape[:2], dtype=torch.float32)
