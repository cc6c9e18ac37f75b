"""HDF5 storage: atomic writes, stage outputs, and the per-object file of the data contract.

Every stage writes one file, ``interim/<name>/<stage>.h5``, holding its datasets and, as root
attributes, its cache key, parameters and code version. A file is written to ``*.tmp`` and
renamed into place only when complete, so a killed build never leaves a file that looks done.
``pack`` then copies every stage's groups into ``processed/<name>.h5``, the file the trainer reads
(its layout is named in ``geomprep.contract``).
Whether a file is still what was written is ``cache``'s business (the build records).
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from geomgrasp.files import atomic_path
from geomprep.contract import STAGE_ATTR_PREFIX, STAGE_GROUPS  # noqa: F401 (store.STAGE_GROUPS)


def _write_attrs(obj: h5py.HLObject, attrs: Mapping[str, Any]) -> None:
    for key, value in attrs.items():
        if isinstance(value, dict | list) and not _is_numeric_list(value):
            value = json.dumps(value, sort_keys=True)
        elif value is None:
            value = "none"
        obj.attrs[key] = value


def _is_numeric_list(value: Any) -> bool:
    return (
        isinstance(value, list) and all(isinstance(v, int | float) for v in value) and value != []
    )


def write_stage(
    path: Path,
    groups: Mapping[str, tuple[Mapping[str, np.ndarray], Mapping[str, Any]]],
    root_attrs: Mapping[str, Any],
    compression: str | None = "gzip",
) -> None:
    """Atomically write one stage's output file.

    ``groups`` maps a group name to (datasets, attrs): dataset names are relative to the group
    and may contain ``/``. float64 arrays are stored as float32 (the contract's precision).
    Arrays of 4096 elements or more are chunked and compressed. ``root_attrs`` (cache key,
    params, code version) go on the file itself.
    """
    with atomic_path(path) as tmp, h5py.File(tmp, "w") as f:
        for group, (datasets, attrs) in groups.items():
            g = f.create_group(group)
            for name, array in datasets.items():
                array = np.asarray(array)
                if array.dtype == np.float64:
                    array = array.astype(np.float32)
                big = array.size >= 4096 and compression is not None
                g.create_dataset(
                    name,
                    data=array,
                    compression=compression if big else None,
                    chunks=_chunks(array) if big else None,
                    shuffle=big,
                )
            _write_attrs(g, attrs)
        _write_attrs(f, root_attrs)


def _chunks(array: np.ndarray) -> tuple[int, ...] | bool:
    # 32^3 chunks let a reader pull one region of an SDF grid without inflating all of it.
    if array.ndim == 3:
        return tuple(min(32, n) for n in array.shape)
    return True


def _decode(value: Any) -> Any:
    if isinstance(value, bytes):
        value = value.decode()
    if isinstance(value, str) and value[:1] in "{[":
        try:
            return json.loads(value)
        except json.JSONDecodeError:
            return value
    if isinstance(value, np.generic):
        return value.item()
    return value


def read_group(path: Path, group: str) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """All datasets (loaded) and attributes of one group of an HDF5 file."""
    with h5py.File(path, "r") as f:
        g = f[group]
        datasets: dict[str, np.ndarray] = {}
        g.visititems(
            lambda name, obj: (
                datasets.__setitem__(name, obj[()]) if isinstance(obj, h5py.Dataset) else None
            )
        )
        return datasets, {k: _decode(v) for k, v in g.attrs.items()}


def pack(stage_files: Mapping[str, Path], out_path: Path, root_attrs: Mapping[str, Any]) -> None:
    """Copy every stage file's group into one per-object file, atomically.

    Each copied group also receives its stage's root attributes (params, code version, cache key)
    so the packed file records how each part was made.
    """
    with atomic_path(out_path) as tmp, h5py.File(tmp, "w") as out:
        for stage, src_path in stage_files.items():
            group = STAGE_GROUPS[stage]
            with h5py.File(src_path, "r") as src:
                src.copy(src[group], out, name=group)
                for key, value in src.attrs.items():
                    out[group].attrs[f"{STAGE_ATTR_PREFIX}{key}"] = value
        _write_attrs(out, root_attrs)
