"""Ship a data directory's searched grasps with the package, so that a fresh machine running
the same hand and physics finds them instead of searching again (2-3 minutes of one core per
object): each object's grasp for ``--config``'s hand key (``trainer.grasps.searched.hand_key``)
goes into ``trainer/grasps/searched_by_hand.json``, without its search history; the entries of
other keys and objects already there are kept.

    python scripts/ship_searched_grasps.py --data-dir data --config configs/cpu-ycb.toml \\
        --source results/graspability-all-2026-11-29
"""

from __future__ import annotations

import json
from pathlib import Path

import click

from geomgrasp.files import atomic_path
from trainer.config import load_env_config
from trainer.errors import TrainerError
from trainer.grasps import searched

_DROPPED = ("history", "earlier")
"""What a shipped entry leaves out: the search's trace, not needed to run the grasp."""


def shipped_entries(data_dir: Path, key: str) -> dict[str, dict]:
    """Object name -> its data-directory grasp of hand ``key``, less ``_DROPPED``."""
    out = {}
    for path in sorted((Path(data_dir) / searched.STORE).glob("*.json")):
        entry = searched.read_object(data_dir, path.stem).get(key)
        if entry is not None:
            out[path.stem] = {k: v for k, v in entry.items() if k not in _DROPPED}
    return out


def ship(data_dir: Path, key: str, source: str, target: Path | None = None) -> int:
    """Merge ``data_dir``'s grasps of hand ``key`` into ``target``; returns how many."""
    target = target or searched.SHIPPED_PATH
    entries = shipped_entries(data_dir, key)
    if not entries:
        raise TrainerError(f"{Path(data_dir) / searched.STORE}: no searched grasp for hand key "
                           f"{key}: run trainer grasp-search with that config first")
    data = json.loads(target.read_text()) if target.is_file() else {}
    data.setdefault("sources", {})[key] = source
    data.setdefault("grasps", {})
    for name, entry in entries.items():
        data["grasps"].setdefault(name, {})[key] = entry
    data["grasps"] = dict(sorted(data["grasps"].items()))
    with atomic_path(target) as tmp:
        tmp.write_text(json.dumps(data, indent=1) + "\n")
    return len(entries)


@click.command()
@click.option("--data-dir", type=click.Path(path_type=Path), default=Path("data"),
              show_default=True)
@click.option("--config", "config_path", type=click.Path(path_type=Path), required=True,
              help="The config whose hand and physics the grasps were searched with.")
@click.option("--source", default="", help="Where their measurement is reported (results/...).")
@click.option("--out", type=click.Path(path_type=Path), default=None,
              help=f"[default: the package's {searched.SHIPPED_PATH.name}]")
def main(data_dir: Path, config_path: Path, source: str, out: Path | None) -> None:
    try:
        cfg = load_env_config(config_path, data_dir=data_dir)
        key = searched.hand_key(cfg)
        count = ship(data_dir, key, source, out)
    except TrainerError as exc:
        raise click.ClickException(str(exc)) from None
    click.echo(f"{count} objects' grasps for hand key {key} written to "
               f"{out or searched.SHIPPED_PATH}")


if __name__ == "__main__":
    main()
