"""The ``trainer`` command line: the scripted-grasp demo, PPO training, evaluation, reports."""

from __future__ import annotations

import os

# MuJoCo picks its OpenGL backend at import: EGL renders offscreen without a display.
os.environ.setdefault("MUJOCO_GL", "egl")

import dataclasses  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

import click  # noqa: E402

from trainer.config import ROBOTS, load_env_config  # noqa: E402
from trainer.errors import TrainerError  # noqa: E402

DEMO_OBJECTS = "077_rubiks_cube,013_apple,005_tomato_soup_can"


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
def cli() -> None:
    """Learn dexterous grasping with PPO on batched MuJoCo (UR5e + Schunk SIH hand).

    \b
    Typical use:
      trainer demo                          # scripted grasps + video: the physics can grasp
      trainer run --repr sq                 # train (run directory under runs/)
      trainer eval runs/NAME                # per-object success table
      trainer report runs/*                 # mean +- std tables and plots over seeds
      trainer play runs/NAME --object 013_apple --video out.mp4

    Objects come from geomprep's output (``data/processed``); build them first with
    ``geomprep build-all``.
    """


def _config_options(func):  # noqa: ANN001, ANN202
    """Options shared by every command that builds environments."""
    func = click.option(
        "--config", "config_path", type=click.Path(path_type=Path, dir_okay=False),
        help="TOML file overriding any environment knob ([physics], [robot], [reward], ...).",
    )(func)
    func = click.option(
        "--data-dir", type=click.Path(path_type=Path, file_okay=False), default=None,
        help="geomprep's data directory (default: ./data, or data_dir in the config).",
    )(func)
    return func


@cli.command()
@click.option("--objects", default=DEMO_OBJECTS, show_default=True, help="Object set or names.")
@click.option("--trials", default=10, show_default=True, help="Randomized trials per object.")
@click.option("--robot", type=click.Choice(ROBOTS), default="ur5e", show_default=True)
@click.option("--seed", default=0, show_default=True, help="Seed of the initial states.")
@click.option(
    "--video", type=click.Path(path_type=Path, dir_okay=False), default=Path("demo.mp4"),
    show_default=True, help="Video of one trial per object (.mp4 or .gif); '' for none.",
)
@_config_options
def demo(
    objects: str, trials: int, robot: str, seed: int, video: Path, config_path: Path | None,
    data_dir: Path | None,
) -> None:
    """Scripted grasps (approach from above, close, lift): proof that the hand can grasp.

    Runs TRIALS randomized trials per object at once and prints how many lifted the object by
    0.2 m. The video shows the first trial of each object (up to four) side by side.
    """
    from trainer.env import GraspEnv
    from trainer.objects import resolve_names
    from trainer.scripted import ScriptedGrasp, run_scripted_grasp

    overrides = {"data_dir": data_dir} if data_dir else {}
    cfg = load_env_config(config_path, **overrides)
    names = resolve_names(objects, cfg.data_dir)
    cfg = dataclasses.replace(
        cfg, num_envs=trials * len(names), objects=",".join(names),
        robot=dataclasses.replace(cfg.robot, kind=robot),
    )
    env = GraspEnv(cfg, seed=seed)
    recorder = None
    if str(video) not in ("", "."):
        from trainer.video import EnvRecorder

        firsts = [int((env.env_object == k).nonzero()[0, 0]) for k in range(len(names))]
        recorder = EnvRecorder(env, firsts[:4], width=320, height=240)
    script = ScriptedGrasp()
    with click.progressbar(length=script.total_steps, label="scripted grasp") as bar:

        def on_step(step: int) -> None:
            if recorder is not None:
                recorder.capture()
            bar.update(1)

        lifted = run_scripted_grasp(env, script, on_step)
    width = max(len(n) for n in names)
    for k, name in enumerate(names):
        mine = env.env_object == k
        click.echo(f"{name:<{width}}  lifted {int(lifted[mine].sum())}/{int(mine.sum())}")
    if recorder is not None:
        path = recorder.save(video, fps=cfg.physics.control_hz)
        recorder.close()
        click.echo(f"video: {path}")
    env.close()


def main() -> None:
    """Entry point: TrainerError becomes a one-line message and exit status 1."""
    try:
        cli.main(standalone_mode=False)
    except TrainerError as exc:
        click.echo(f"error: {exc}", err=True)
        sys.exit(1)
    except click.exceptions.Abort:
        click.echo("aborted", err=True)
        sys.exit(130)
    except click.ClickException as exc:
        exc.show()
        sys.exit(exc.exit_code)


if __name__ == "__main__":
    main()
