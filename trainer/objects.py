"""The objects of a run: geomprep's artifacts for every object, loaded once into tensors.

Object id = index in ``ObjectSet.names``. All quantities are in the object frame (origin at the
centre of mass, the frame of the MJCF free body and of the SDF grid), metres.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np
import torch

from geomprep.config import Config, load_config
from geomprep.errors import GeomprepError
from geomprep.pipeline import resolve_objects, verify_processed
from geomprep.sdf_lookup import SDFLookup
from trainer.errors import TrainerError


@dataclass
class ObjectSet:
    """Artifacts of N objects, stacked (float32 tensors on one device)."""

    names: list[str]
    xml_paths: list[Path]
    h5_paths: list[Path]
    mjcf_keys: list[str]
    """geomprep's cache key of each object's model: a new model invalidates cached init states."""
    bbox_center: torch.Tensor
    """(N, 3) box centre."""
    bbox_rotation: torch.Tensor
    """(N, 3, 3) box axes as columns."""
    bbox_extents: torch.Tensor
    """(N, 3) full edge lengths."""
    sq_params: torch.Tensor
    """(N, 11) eps1, eps2, a1, a2, a3, extrinsic xyz Euler (rad), translation."""
    points: torch.Tensor
    """(N, 512, 3) farthest-point surface samples; the first 32 / 128 are the smaller sets."""
    sdf: SDFLookup | None
    """Signed-distance grids, loaded only when the representation or reward needs them."""


def resolve_names(spec: str, data_dir: Path) -> list[str]:
    """Object names from a set (``builtin``, ``ycb``, ``all``) or a comma list."""
    try:
        names = resolve_objects(load_config(data_dir=data_dir), spec)
    except GeomprepError as exc:
        raise TrainerError(str(exc)) from None
    if not names:
        raise TrainerError(
            f"object set {spec!r} is empty in {data_dir}: import objects with `geomprep fetch`"
        )
    return names


def load_objects(
    names: list[str],
    data_dir: Path,
    need_sdf: bool,
    device: str | torch.device = "cpu",
    sdf_dtype: torch.dtype = torch.float32,
) -> ObjectSet:
    """Read ``data_dir/processed/<name>.h5`` for every name (see the README's data contract).

    Only files geomprep has verified: every object's processed files must match geomprep's
    build record and come from its current source (``geomprep.pipeline.verify_processed``), so
    a damaged file, a failed rebuild or a re-imported source is refused, not trained on."""
    processed = Path(data_dir) / "processed"
    h5_paths = [processed / f"{name}.h5" for name in names]
    missing = [n for n, p in zip(names, h5_paths, strict=True) if not p.is_file()]
    if missing:
        raise TrainerError(
            f"no geomprep output for {', '.join(missing[:5])}"
            f"{' ...' if len(missing) > 5 else ''} in {processed}: run "
            f"`geomprep build-all --objects {','.join(missing)}`"
        )
    geomprep_cfg = Config(data_dir=Path(data_dir))  # only its directories are used
    problems = {n: why for n in names if (why := verify_processed(geomprep_cfg, n)) is not None}
    if problems:
        first = next(iter(problems.values()))
        more = f" (and {len(problems) - 1} more objects)" if len(problems) > 1 else ""
        raise TrainerError(
            f"{first}{more}: rebuild with `geomprep build-all --objects {','.join(problems)}`"
        )
    centers, rotations, extents, sq, points, keys, xmls = [], [], [], [], [], [], []
    for name, path in zip(names, h5_paths, strict=True):
        try:
            with h5py.File(path, "r") as f:
                centers.append(f["bbox/center"][:])
                rotations.append(f["bbox/rotation"][:])
                extents.append(f["bbox/extents"][:])
                sq.append(f["superquadric/params"][:])
                points.append(f["pointcloud/pc512"][:])
                keys.append(str(f["mjcf"].attrs["stage_cache_key"]))
                xmls.append(processed / str(f["mjcf"].attrs["xml"]))
        except (KeyError, OSError) as exc:
            raise TrainerError(
                f"{path} is incomplete ({exc}): rebuild it with `geomprep build-all --objects "
                f"{name}`"
            ) from None

    def stack(arrays: list[np.ndarray]) -> torch.Tensor:
        return torch.as_tensor(np.stack(arrays), dtype=torch.float32, device=device)

    sdf = SDFLookup.from_hdf5(h5_paths, dtype=sdf_dtype, device=device) if need_sdf else None
    return ObjectSet(
        names=list(names),
        xml_paths=xmls,
        h5_paths=h5_paths,
        mjcf_keys=keys,
        bbox_center=stack(centers),
        bbox_rotation=stack(rotations),
        bbox_extents=stack(extents),
        sq_params=stack(sq),
        points=stack(points),
        sdf=sdf,
    )
