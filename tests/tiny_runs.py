"""Tiny trained runs (one PPO iteration on built-in objects, an untrained policy) for the tests
of what reads a run: the evaluation session, ``trainer eval``, the probe scripts; and the
scripts of scripts/ and bench/ loaded as modules (they are files, not a package)."""

from __future__ import annotations

import functools
import importlib.util
import sys
from pathlib import Path
from types import ModuleType

from geomprep.config import Config
from trainer.training.run_dir import RunDir

ROOT = Path(__file__).resolve().parents[1]
TINY_PPO = {"frames_per_env": 8, "minibatches": 2, "min_minibatch": 1, "epochs": 1,
            "hidden": (16, 16)}
"""One small PPO iteration of 4 envs x 8 frames."""


def tiny_run(data: Config, path: Path, objects: str, **env: object) -> RunDir:
    """A one-iteration bbox run of 4 envs and 12-action episodes on ``objects`` (more env
    config in ``env``), with a checkpoint, in ``path``."""
    from trainer.config import load_train_config
    from trainer.ppo import train

    cfg = load_train_config(
        env={"num_envs": 4, "objects": objects, "representation": "bbox",
             "data_dir": data.data_dir, "max_steps": 12, **env},
        ppo=TINY_PPO,
        run={"total_steps": 32, "checkpoint_every": 1, "seed": 0},
    )
    return train(cfg, path, progress=False)


def tiny_dice_mug_run(data: Config, path: Path) -> RunDir:
    """The built-in dice and mug: both start upright and upside down across resets."""
    return tiny_run(data, path, "builtin_dice,builtin_mug")


@functools.cache
def script(folder: str, name: str) -> ModuleType:
    """``folder/name.py`` of the repository (``scripts`` or ``bench``) as a module."""
    spec = importlib.util.spec_from_file_location(f"{folder}_{name}", ROOT / folder / f"{name}.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up there
    spec.loader.exec_module(module)
    return module


def tiny_grasp_start_config(data: Config, **run: object):  # noqa: ANN201
    """A 4-env bbox run on the built-in cylinder whose training episodes start half from the
    top grasp's recorded states (one trial per env), one 32-step iteration; ``run`` overrides
    ``[run]`` keys."""
    from trainer.config import load_train_config

    return load_train_config(
        env={"num_envs": 4, "objects": "builtin_cylinder", "representation": "bbox",
             "data_dir": data.data_dir, "max_steps": 12,
             "robot": {"home_above_objects": True}},
        ppo={"frames_per_env": 8, "minibatches": 2, "min_minibatch": 1, "epochs": 1,
             "hidden": (16, 16)},
        run={"total_steps": 32, "seed": 0, "grasp_starts": 0.5, "grasp_start_family": "top",
             "grasp_start_rounds": 1, **run},
    )


def own_data_dir(data: Config, path: Path) -> Path:
    """``path``: a data directory whose built objects (and settled banks) are ``data``'s,
    linked, and whose other contents (searched grasps, recorded grasp starts) are its own, so
    that what a test stores there is not found by another test of the session."""
    path.mkdir(parents=True)
    for part in ("raw", "interim", "processed"):
        (path / part).symlink_to(data.data_dir / part)
    return path


def trainer_main(argv: list[str], monkeypatch, capsys) -> tuple[int, str, str]:  # noqa: ANN001
    """``trainer ARGV`` through the real entry point (as the installed script): exit code,
    stdout, stderr (as written)."""
    import trainer.cli

    monkeypatch.setattr(sys, "argv", ["trainer", *argv])
    try:
        trainer.cli.main()
        code = 0
    except SystemExit as exc:
        code = int(exc.code or 0)
    out = capsys.readouterr()
    return code, out.out, out.err
