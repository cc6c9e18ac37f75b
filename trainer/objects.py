"""The objects of a run: geomprep's artifacts for every object, loaded once into tensors.

geomprep is reached through its read-only contract (``geomprep.contract``: which objects, are
they current, read one) and its SDF lookup (``geomprep.sdf_lookup``), neither of which imports
the mesh stack; and, on a data directory's first use, through the build step that writes the
built-in objects' sources (``geomprep.importer.import_builtin``, which loads the mesh stack
only when it writes).

Object id = index in ``ObjectSet.names``. All quantities are in the object frame (origin at the
centre of mass, the frame of the MJCF free body and of the SDF grid), metres.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from geomprep import builtin, contract, importer
from geomprep.errors import GeomprepError
from geomprep.sdf_lookup import SDFLookup
from trainer.config import EnvConfig
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
    """Object names from a set (``builtin``, ``ycb``, ``all``) or a comma list; the built-in
    objects among them are written into the raw store if they are not there yet."""
    dirs = contract.DataDirs(Path(data_dir))
    try:
        names = contract.resolve_objects(dirs, spec)
        importer.import_builtin(dirs.raw_dir, [n for n in names if n in builtin.NAMES])
    except GeomprepError as exc:
        raise TrainerError(str(exc)) from None
    if not names:
        raise TrainerError(
            f"object set {spec!r} is empty in {data_dir}: import objects with `geomprep fetch`"
        )
    return names


def task_names(cfg: EnvConfig) -> list[str]:
    """The objects a task of ``cfg`` holds: ``objects`` less ``held_out``. A held-out name not
    among ``objects``, or nothing left to train on, is a one-line error."""
    names = resolve_names(cfg.objects, cfg.data_dir)
    if not cfg.held_out:
        return names
    held = resolve_names(cfg.held_out, cfg.data_dir)
    stray = [n for n in held if n not in names]
    if stray:
        raise TrainerError(f"held_out names {', '.join(stray)}, not among objects "
                           f"({cfg.objects!r}): hold out objects of the set")
    left = [n for n in names if n not in held]
    if not left:
        raise TrainerError(f"held_out holds out every object of {cfg.objects!r}: leave some to "
                           "train on")
    return left


def task_objects(cfg: EnvConfig, names: list[str], device: torch.device) -> ObjectSet:
    """The objects ``names`` as a task of ``cfg`` needs them: with their SDF grids (in
    ``cfg.sdf_dtype``) where the representation, the reward's fingertip distances or the hold
    test (``reward.hold_tips``, telling a held lift from a toss) reads them."""
    need_sdf = (
        cfg.representation == "sdf" or cfg.reward.kind.startswith("sdf")
        or cfg.reward.hold_tips > 0
    )
    sdf_dtype = torch.float16 if cfg.sdf_dtype == "float16" else torch.float32
    return load_objects(names, cfg.data_dir, need_sdf, device, sdf_dtype)


def load_objects(
    names: list[str],
    data_dir: Path,
    need_sdf: bool,
    device: str | torch.device = "cpu",
    sdf_dtype: torch.dtype = torch.float32,
) -> ObjectSet:
    """Read ``data_dir/processed/<name>.h5`` for every name (``geomprep.contract``).

    Only files geomprep has verified: every object's processed files must match geomprep's
    build record and come from its current source (``geomprep.contract.verify_processed``), so
    a damaged file, a failed rebuild or a re-imported source is refused, not trained on."""
    dirs = contract.DataDirs(Path(data_dir))
    h5_paths = [contract.processed_path(dirs, name) for name in names]
    missing = [n for n, p in zip(names, h5_paths, strict=True) if not p.is_file()]
    if missing:
        raise TrainerError(
            f"no geomprep output for {', '.join(missing[:5])}"
            f"{' ...' if len(missing) > 5 else ''} in {dirs.processed_dir}: run "
            f"`geomprep build-all --objects {','.join(missing)}`"
        )
    problems = {
        n: why for n in names if (why := contract.verify_processed(dirs, n)) is not None
    }
    if problems:
        first = next(iter(problems.values()))
        more = f" (and {len(problems) - 1} more objects)" if len(problems) > 1 else ""
        raise TrainerError(
            f"{first}{more}: rebuild with `geomprep build-all --objects {','.join(problems)}`"
        )
    try:
        objects = [contract.read_object(dirs, name) for name in names]
    except GeomprepError as exc:
        raise TrainerError(str(exc)) from None

    def stack(arrays: list[np.ndarray]) -> torch.Tensor:
        return torch.as_tensor(np.stack(arrays), dtype=torch.float32, device=device)

    sdf = SDFLookup.from_hdf5(h5_paths, dtype=sdf_dtype, device=device) if need_sdf else None
    return ObjectSet(
        names=list(names),
        xml_paths=[o.xml_path for o in objects],
        h5_paths=h5_paths,
        mjcf_keys=[o.mjcf_key for o in objects],
        bbox_center=stack([o.bbox_center for o in objects]),
        bbox_rotation=stack([o.bbox_rotation for o in objects]),
        bbox_extents=stack([o.bbox_extents for o in objects]),
        sq_params=stack([o.sq_params for o in objects]),
        points=stack([o.points for o in objects]),
        sdf=sdf,
    )
