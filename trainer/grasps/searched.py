"""Where the searched grasps (``trainer grasp-search``) are kept, and how the ``searched``
family reads them.

- **The data directory**, per object: ``DATA_DIR/grasps/searched/<object>.json``, one grasp per
  hand and physics it was searched with (``hand_key``: the resolved ``[robot]`` and
  ``[physics]`` sections). ``trainer grasp-search`` writes there by default; never into the
  installed package.
- **The shipped grasps per hand**, ``searched_by_hand.json`` beside this module (read-only):
  data-directory entries shipped with the package (``scripts/ship_searched_grasps.py``), so
  that a fresh machine need not search them again (2-3 minutes of one core per object):
  ``{"sources": {hand_key: str}, "grasps": {name: {hand_key: entry}}}``.
- **The shipped seed**, ``searched.json`` beside this module (read-only): the grasps the
  ``searched`` family was measured with (results/graspability-search-2026-11-26/), one
  configuration for all objects: ``{"config": {...}, "objects": {name: entry}}``. ``trainer
  grasp-search --out FILE`` writes a file of this format.

An entry is ``{"theta": {param: value}, "lifted", "final_trials", "search", "history"}`` (and
``earlier``: the searches a ``--refine`` continued). The ``searched`` family's keyframe grasp
takes each object's row from the entry for the env's hand and physics where there is one (the
data directory's, else the shipped one: ``data_rows``), else from the seed.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
from pathlib import Path
from typing import TYPE_CHECKING, Any

from geomgrasp.files import atomic_path
from trainer.config import EnvConfig, without_neutral
from trainer.errors import TrainerError
from trainer.grasps.keyframes import PARAMS

if TYPE_CHECKING:
    from trainer.tasks import GraspTask

SEARCHED_PATH = Path(__file__).with_name("searched.json")
"""The shipped seed: the grasps ``trainer grasp-search`` found, per object, and the
configuration (hand, physics) they were searched and measured with (read-only)."""
SHIPPED_PATH = Path(__file__).with_name("searched_by_hand.json")
"""Searched grasps shipped per object and hand key (``scripts/ship_searched_grasps.py``)."""
STORE = Path("grasps") / "searched"
"""The searched grasps' folder in a data directory (one file per object)."""
_SCRIPT_ONLY = ("hand_action", "hand_relative_step")
"""``[robot]`` fields that do not change what a scripted grasp does (the scripts command
absolute hand targets: ``runner.script_config``)."""


def hand_key(cfg: EnvConfig) -> str:
    """The hand and physics of ``cfg`` as a short hash: the resolved ``[robot]`` (less how a
    policy's hand actions are read) and ``[physics]`` sections, less the fields that hold a
    neutral default (``trainer.config.NEUTRAL_DEFAULTS``). A grasp searched with one key is
    used only where the env's key is the same."""
    return key_of(hand_and_physics(cfg))


def key_of(hand_physics: dict[str, Any]) -> str:
    """The ``hand_key`` of a ``hand_and_physics`` dict (as stored beside each entry)."""
    payload = json.dumps(without_neutral(hand_physics), sort_keys=True)
    return hashlib.sha256(payload.encode()).hexdigest()[:16]


def _rekeyed(grasps: dict[str, dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """``grasps`` keyed by today's ``key_of`` their stored hand and physics (an entry without
    one keeps its key): a grasp searched before a neutral field existed keeps being found."""
    out = {}
    for key, entry in grasps.items():
        stored = entry.get("hand_and_physics")
        out[key_of(stored) if isinstance(stored, dict) else key] = entry
    return out


def hand_and_physics(cfg: EnvConfig) -> dict[str, Any]:
    """What ``hand_key`` hashes, as stored beside each data-directory entry (for reading)."""
    robot = {k: v for k, v in dataclasses.asdict(cfg.robot).items() if k not in _SCRIPT_ONLY}
    return json.loads(json.dumps({"robot": robot, "physics": dataclasses.asdict(cfg.physics)}))


def object_path(data_dir: Path, name: str) -> Path:
    """``DATA_DIR/grasps/searched/<name>.json``: the searched grasps of object ``name``."""
    return Path(data_dir) / STORE / f"{name}.json"


def _check_entries(entries: Any) -> None:
    for name, entry in entries.items():
        missing = [p for p in PARAMS if p not in entry["theta"]]
        if missing:
            raise KeyError(f"{name}: {missing[0]}")


def _damaged(path: Path, exc: Exception) -> TrainerError:
    return TrainerError(f"{path}: not a searched-grasp file ({exc}): rerun trainer grasp-search")


def load_searched(path: Path = SEARCHED_PATH) -> dict[str, Any]:
    """A searched-grasp file of one configuration (the shipped seed, or ``grasp-search --out
    FILE``): ``{"config": {...}, "objects": {name: {"theta": {param: value}, ...}}}`` (empty
    when there is none); a damaged one is a one-line error."""
    if not path.is_file():
        return {"config": {}, "objects": {}}
    try:
        data = json.loads(path.read_text())
        _check_entries(data["objects"])
    except (ValueError, KeyError, TypeError, AttributeError) as exc:
        raise _damaged(path, exc) from None
    return data


def read_object(data_dir: Path, name: str) -> dict[str, dict[str, Any]]:
    """Object ``name``'s searched grasps in the data directory: ``hand_key`` -> entry (empty
    when there are none); a damaged file is a one-line error."""
    path = object_path(data_dir, name)
    if not path.is_file():
        return {}
    try:
        grasps = json.loads(path.read_text())["grasps"]
        _check_entries(grasps)
        return _rekeyed(grasps)
    except (ValueError, KeyError, TypeError, AttributeError) as exc:
        raise _damaged(path, exc) from None


@functools.cache
def _shipped(path: Path) -> dict[str, dict[str, dict[str, Any]]]:
    if not path.is_file():
        return {}
    try:
        grasps = json.loads(path.read_text())["grasps"]
        for entries in grasps.values():
            _check_entries(entries)
        return {name: _rekeyed(entries) for name, entries in grasps.items()}
    except (ValueError, KeyError, TypeError, AttributeError) as exc:
        raise _damaged(path, exc) from None


def shipped_object(name: str, path: Path | None = None) -> dict[str, dict[str, Any]]:
    """Object ``name``'s searched grasps shipped with the package (``SHIPPED_PATH``):
    ``hand_key`` -> entry."""
    return _shipped(path or SHIPPED_PATH).get(name, {})


def entry_for(cfg: EnvConfig, name: str) -> dict[str, Any] | None:
    """Object ``name``'s searched grasp for ``cfg``'s hand and physics (``hand_key``): the data
    directory's, else the package's shipped one, else None."""
    key = hand_key(cfg)
    found = read_object(cfg.data_dir, name).get(key)
    return found if found is not None else shipped_object(name).get(key)


def write_entry(data_dir: Path, name: str, key: str, entry: dict[str, Any]) -> Path:
    """Store ``entry`` as object ``name``'s grasp for the hand and physics ``key`` (replacing
    the one of that key, keeping the others); returns the file."""
    grasps = read_object(data_dir, name)
    grasps[key] = entry
    path = object_path(data_dir, name)
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps({"object": name, "grasps": grasps}, indent=1) + "\n")
    return path


def grasp_for(cfg: EnvConfig, name: str) -> dict[str, Any] | None:
    """The grasp the ``searched`` family runs on object ``name`` with ``cfg``'s hand and
    physics: ``entry_for`` (the data directory's or the shipped one of that key), else the
    seed's, else None."""
    found = entry_for(cfg, name)
    return found if found is not None else load_searched()["objects"].get(name)


def theta_row(entry: dict[str, Any]) -> tuple[float, ...]:
    """An entry's parameters in the order of ``keyframes.PARAMS``."""
    return tuple(float(entry["theta"][p]) for p in PARAMS)


def data_rows(env: GraspTask) -> dict[str, tuple[float, ...]]:
    """Object name -> parameters, for the objects of ``env`` that have a grasp searched with its
    hand and physics (``entry_for``: in its data directory or shipped;
    ``KeyframeGrasp.extra_rows`` of the ``searched`` family)."""
    rows = {}
    for name in env.objects.names:
        entry = entry_for(env.cfg, name)
        if entry is not None:
            rows[name] = theta_row(entry)
    return rows
