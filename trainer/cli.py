"""The ``trainer`` command line: the scripted-grasp demo, PPO training, evaluation, reports."""

from __future__ import annotations

import os

# MuJoCo picks its OpenGL backend at import: EGL renders offscreen without a display.
os.environ.setdefault("MUJOCO_GL", "egl")

import dataclasses  # noqa: E402
from pathlib import Path  # noqa: E402

import click  # noqa: E402

from geomprep.errors import run_cli  # noqa: E402
from trainer.config import (  # noqa: E402
    REPRESENTATIONS,
    REWARDS,
    ROBOTS,
    load_env_config,
    load_train_config,
)
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


@cli.command()
@click.option("--repr", "representation", type=click.Choice(REPRESENTATIONS), default=None,
              help="Object representation the policy sees [default: sq].")
@click.option("--reward", type=click.Choice(REWARDS), default=None,
              help="sdf (the paper), com (distance to the centre of mass), none (no shaping).")
@click.option("--robot", type=click.Choice(ROBOTS), default=None, help="[default: ur5e]")
@click.option("--objects", default=None, help="Object set (builtin, ycb, all) or names.")
@click.option("--num-envs", type=int, default=None, help="Parallel environments [64].")
@click.option("--steps", type=int, default=None, help="Total environment steps [10M].")
@click.option("--seed", type=int, default=None, help="[0]")
@click.option("--device", default=None, help="Torch device of the networks and tensors [cpu].")
@click.option("--run-dir", type=click.Path(path_type=Path, file_okay=False), default=None,
              help="Where the run goes [runs/REPR-REWARD-ROBOT-sSEED].")
@click.option("--resume", "resume_dir", type=click.Path(path_type=Path, file_okay=False),
              default=None, help="Continue a killed run from its last checkpoint.")
@click.option("--compile/--no-compile", "compile_env", default=True, show_default=True,
              help="torch.compile the per-step task computations (faster after ~1 min of "
              "compilation; needs a C++ compiler on CPU).")
@_config_options
def run(
    representation: str | None, reward: str | None, robot: str | None, objects: str | None,
    num_envs: int | None, steps: int | None, seed: int | None, device: str | None,
    run_dir: Path | None, resume_dir: Path | None, compile_env: bool,
    config_path: Path | None, data_dir: Path | None,
) -> None:
    """Train a grasping policy with PPO (TorchRL collector, GAE, ClipPPOLoss, Adam).

    The run directory gets config.json (everything resolved), metrics.csv and tb/ (TensorBoard),
    and checkpoints/. Options override the --config TOML ([ppo], [run] and env sections).
    """
    from trainer.ppo import train

    if resume_dir is not None:
        run_path = train(None, resume_dir, resume=True).path  # type: ignore[arg-type]
        click.echo(f"run: {run_path}")
        return
    env = {
        k: v for k, v in {
            "representation": representation, "objects": objects, "num_envs": num_envs,
            "device": device, "data_dir": data_dir, "compile": compile_env,
        }.items() if v is not None
    }
    run_over = {k: v for k, v in {"total_steps": steps, "seed": seed}.items() if v is not None}
    cfg = load_train_config(config_path, env=env, run=run_over)
    if reward is not None or robot is not None:
        cfg = dataclasses.replace(cfg, env=dataclasses.replace(
            cfg.env,
            reward=dataclasses.replace(cfg.env.reward, kind=reward or cfg.env.reward.kind),
            robot=dataclasses.replace(cfg.env.robot, kind=robot or cfg.env.robot.kind),
        ))
    if run_dir is None:
        e = cfg.env
        run_dir = Path("runs") / (
            f"{e.representation}-{e.reward.kind}-{e.robot.kind}-s{cfg.run.seed}"
        )
    click.echo(f"run: {run_dir}")
    train(cfg, run_dir)


@cli.command("eval")
@click.argument("run_dir", type=click.Path(path_type=Path, file_okay=False, exists=True))
@click.option("--episodes-per-object", default=10, show_default=True)
@click.option("--objects", default=None, help="Evaluate on these objects instead.")
def eval_cmd(run_dir: Path, episodes_per_object: int, objects: str | None) -> None:
    """Success per object of the deterministic policy (eval/per_object.csv, eval/table.md)."""
    from trainer.evaluation import evaluate

    result = evaluate(run_dir, episodes_per_object, objects)
    width = max(len(n) for n in result.names)
    for k, name in enumerate(result.names):
        click.echo(f"{name:<{width}}  {result.successes[k]}/{result.episodes[k]}")
    click.echo(f"{'overall':<{width}}  {result.overall:.3f}")


@cli.command()
@click.argument("run_dirs", nargs=-1, required=True,
                type=click.Path(path_type=Path, file_okay=False, exists=True))
@click.option("--out", type=click.Path(path_type=Path, file_okay=False), default=Path("report"),
              show_default=True)
@click.option("--compare", default=None, help="BASE,OTHER: per-object gain plot of OTHER over "
              "BASE (representation names or group labels).")
def report(run_dirs: tuple[Path, ...], out: Path, compare: str | None) -> None:
    """Tables (final success, steps and minutes to 90 % / 95 %) and plots over runs and seeds."""
    from trainer.report import write_report

    pair = tuple(compare.split(",")) if compare else None
    if pair is not None and len(pair) != 2:
        raise TrainerError("--compare takes two labels: BASE,OTHER (e.g. com,sq)")
    for path in write_report(list(run_dirs), out, pair):
        click.echo(str(path))


@cli.command()
@click.argument("run_dir", type=click.Path(path_type=Path, file_okay=False, exists=True))
@click.option("--object", "object_name", required=True, help="Object to grasp.")
@click.option("--video", type=click.Path(path_type=Path, dir_okay=False),
              default=Path("play.mp4"), show_default=True)
@click.option("--episodes", default=1, show_default=True, help="Episodes side by side.")
@click.option("--seed", default=0, show_default=True)
def play(run_dir: Path, object_name: str, video: Path, episodes: int, seed: int) -> None:
    """Render episodes of the trained (deterministic) policy into a video."""
    from trainer.env import GraspEnv
    from trainer.evaluation import run_episodes
    from trainer.ppo import load_agent
    from trainer.video import EnvRecorder

    cfg, agent = load_agent(run_dir)
    env = GraspEnv(dataclasses.replace(cfg.env, objects=object_name, num_envs=episodes), seed)
    recorder = EnvRecorder(env, range(min(episodes, 4)), width=480, height=360)
    success, length = run_episodes(env, agent.actor, on_step=recorder.capture)
    recorder.save(video, fps=cfg.env.physics.control_hz)
    recorder.close()
    env.close()
    click.echo(f"{object_name}: success {int(success.sum())}/{episodes}, "
               f"{int(length.max())} steps; video: {video}")


def main() -> None:
    """Entry point: TrainerError becomes a one-line message and exit status 1."""
    run_cli(cli, (TrainerError,))


if __name__ == "__main__":
    main()
