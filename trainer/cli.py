"""The ``trainer`` command line: the scripted-grasp demo, PPO training, evaluation, reports.

Torch, TorchRL and MuJoCo take seconds to import, so only the commands that use them import them:
``trainer --help`` and a mistyped option answer at once (``tests/test_trainer_cli.py``).
"""

from __future__ import annotations

import os

# MuJoCo picks its OpenGL backend at import: EGL renders offscreen without a display.
os.environ.setdefault("MUJOCO_GL", "egl")

import contextlib  # noqa: E402
import dataclasses  # noqa: E402
import warnings  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import TYPE_CHECKING  # noqa: E402

import click  # noqa: E402

from geomgrasp.cli import run_cli  # noqa: E402
from trainer.config import (  # noqa: E402
    BACKENDS,
    CONTEXTS,
    REPRESENTATIONS,
    REWARDS,
    ROBOTS,
    TASKS,
    check_backend,
    check_device,
    dotted_overrides,
    load_env_config,
    load_train_config,
    override,
    read_config_toml,
)
from trainer.errors import TrainerError, TrainerWarning  # noqa: E402

if TYPE_CHECKING:
    from collections.abc import Iterator

    from trainer.grasps import Variant

DEMO_OBJECTS = "077_rubiks_cube,013_apple,005_tomato_soup_can"
RUN_OPTIONS = {
    "representation": "--repr", "reward.kind": "--reward", "robot.kind": "--robot",
    "objects": "--objects", "num_envs": "--num-envs", "device": "--device",
    "data_dir": "--data-dir", "compile": "--compile", "total_steps": "--steps", "seed": "--seed",
    "max_minutes": "--minutes", "init_agent": "--init-agent",
    "task": "--task", "bin.num_objects": "--bin-objects", "context": "--context",
    "backend": "--backend",
}
"""The config field each ``trainer run`` option sets (a bad value's error names the option)."""


def _at_least(option: str, value: int, minimum: int) -> None:
    if value < minimum:
        raise TrainerError(f"{option} {value}: must be >= {minimum}")


def _run_dir(path: Path) -> Path:
    # Checked here rather than by click so that the error is one line like every other.
    if not path.is_dir():
        raise TrainerError(f"{path}: no such run directory: pass one written by trainer run")
    return path


def _sets(texts: tuple[str, ...], training: bool = False) -> dict:
    """The ``--set`` options, checked (``trainer.config_keys.parse_sets``); ``training``:
    ``[ppo]`` and ``[run]`` keys too."""
    from trainer.config_keys import parse_sets

    return parse_sets(texts, training=training)


def _one_source(sets: dict, options: dict[str, str]) -> None:
    """Refuse a key set both by ``--set`` and by an option (``options``: key -> the option that
    set it): which should win?"""
    if clash := sorted(sets.keys() & options.keys()):
        key = clash[0]
        raise TrainerError(f"--set {key} and {options[key]} both set {key}: drop one")


def _device(device: str | None) -> None:
    if device is not None:
        check_device(device, f"--device {device}", "use --device cpu")


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
def cli() -> None:
    """Learn dexterous grasping with PPO on batched MuJoCo (UR5e + Schunk SIH hand).

    \b
    Typical use:
      trainer demo                          # scripted grasps + video: the physics can grasp
      trainer grasp --family pinch          # scripted trials, each outcome classified
      trainer grasp-search --objects NAMES  # search a grasp where no script lifts
      trainer run --repr sq                 # train (run directory under runs/)
      trainer eval runs/NAME                # per-object success table
      trainer report runs/*                 # mean +- std tables and plots over seeds
      trainer play runs/NAME --object 013_apple --video out.mp4
      trainer config [KEY...]               # every config key: default, range, the paper's

    Objects come from geomprep's output (``data/processed``); build them first with
    ``geomprep build-all``.
    """


def _config_options(func):  # noqa: ANN001, ANN202
    """Options shared by every command that reads a config (``--set``: ``_sets``)."""
    func = click.option(
        "--set", "sets", multiple=True, metavar="SECTION.KEY=VALUE",
        help="Set one config key as if the --config file said it (repeatable; the value as "
        "TOML writes it: 12, 0.5, true, hulls, [1, 2]). trainer config lists the keys.",
    )(func)
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
@click.option("--family", "family_spec", default="top", show_default=True,
              help="Grasp family, optionally FAMILY:VARIANT (e.g. pinch:press6+noslip); the "
              "variant's physics overrides apply. 'best': each Table I object's best family "
              "with the candidate hand (one video per family).")
@click.option(
    "--video", type=click.Path(path_type=Path, dir_okay=False), default=Path("demo.mp4"),
    show_default=True, help="Video of one trial per object (.mp4 or .gif); '' for none.",
)
@_config_options
def demo(
    objects: str, trials: int, robot: str, seed: int, family_spec: str, video: Path,
    config_path: Path | None, sets: tuple[str, ...], data_dir: Path | None,
) -> None:
    """Scripted grasps (by default the top grasp: approach from above, close, lift): proof that
    the hand can grasp.

    Runs TRIALS randomized trials per object at once (the lift task, one object on the table,
    whatever task the config names) and prints how many lifted the object by 0.2 m. The video
    shows the first trial of each object (up to four) side by side.
    """
    _at_least("--trials", trials, 1)
    _at_least("--seed", seed, 0)
    given = _sets(sets)
    from trainer.grasps import FAMILIES, family_variants, searched
    from trainer.grasps.families import best_variants
    from trainer.objects import resolve_names

    variant = None
    if family_spec != "best":  # an unknown family or variant is reported before the objects
        family_name, _, variant_name = family_spec.partition(":")
        variant = family_variants(family_name, [variant_name or "base"])[variant_name or "base"]
    overrides = {"data_dir": data_dir} if data_dir else {}
    names = resolve_names(objects, load_env_config(config_path, given, **overrides).data_dir)
    if variant is not None:
        batches = {family_spec: (variant, names)}
    else:
        # The hand and physics the searched batch runs with (_demo_batch): its grasps' key.
        hand = load_env_config(config_path, given, **overrides,
                               **FAMILIES["searched"].variants["base"].env)
        batches = best_variants(names, searched=[
            n for n in names if searched.grasp_for(hand, n) is not None])
    for spec, (variant, mine) in batches.items():
        if len(batches) > 1:
            click.echo(f"\n{spec}:")
        clip = video
        if len(batches) > 1 and str(video) not in ("", "."):
            clip = video.with_name(f"{video.stem}-{spec.replace(':', '-')}{video.suffix}")
        _demo_batch(mine, variant, trials, robot, seed, clip, config_path, given, data_dir)


def _demo_batch(
    names: list[str], variant: Variant, trials: int, robot: str, seed: int, video: Path,
    config_path: Path | None, sets: dict, data_dir: Path | None,
) -> None:
    """One batch of ``trainer demo``: ``trials`` per object of ``variant``, printed, and the
    first trial of each object (up to four) filmed into ``video``."""
    from trainer.grasps import run_scripted_grasp
    from trainer.grasps.runner import episode_config
    from trainer.tasks import make_env

    overrides = {"data_dir": data_dir} if data_dir else {}
    cfg = load_env_config(config_path, sets, task="lift", context="none", **overrides,
                          **variant.env)
    check_device(cfg.device, f"device {cfg.device!r} in {config_path}", 'set device = "cpu"')
    cfg = dataclasses.replace(
        cfg, num_envs=trials * len(names), objects=",".join(names),
        robot=dataclasses.replace(cfg.robot, kind=robot),
    )
    env = make_env(episode_config(cfg, variant.script), seed=seed)
    targets = env.target_objects().cpu()  # lift: the env's one object, fixed at build
    recorder = None
    if str(video) not in ("", "."):
        from trainer.video import EnvRecorder

        firsts = [int((targets == k).nonzero()[0, 0]) for k in range(len(names))]
        recorder = EnvRecorder(env, firsts[:4], width=320, height=240)
    script = variant.script
    with click.progressbar(length=script.total_steps, label="scripted grasp") as bar:

        def on_step(step: int) -> None:
            if recorder is not None:
                recorder.capture()
            bar.update(1)

        lifted = run_scripted_grasp(env, script, on_step)
    width = max(len(n) for n in names)
    lifted = lifted.cpu()
    for k, name in enumerate(names):
        mine = targets == k
        click.echo(f"{name:<{width}}  lifted {int(lifted[mine].sum())}/{int(mine.sum())}")
    if recorder is not None:
        path = recorder.save(video, fps=cfg.physics.control_hz)
        recorder.close()
        click.echo(f"video: {path}")
    env.close()


@cli.command()
@click.option("--family", "family_name", default="top", show_default=True,
              help="Grasp family: top (palm down, close, lift), pinch (thumb tip against "
              "index tip at table height), slide (palm up under a flat object's rim: tips the "
              "plate, lifts nothing yet) or searched (trainer grasp-search's grasps).")
@click.option("--variants", default="base", show_default=True,
              help="The family's named variants (comma-separated; 'all': every one).")
@click.option("--grid", is_flag=True, help="Instead of --variants: the family's geometry grid.")
@click.option("--objects", default=None,
              help="Object set or names [the family's: top the Table I objects, pinch the "
              "dice, knife, tuna can and plate; --grid: the grid's].")
@click.option("--trials", default=10, show_default=True, help="Randomized trials per object.")
@click.option("--seed", default=0, show_default=True, help="Seed of the initial states.")
@click.option("--backend", type=click.Choice(BACKENDS), default=None,
              help="Physics backend [cpu]; warp: MuJoCo Warp.")
@click.option("--device", default=None, help="Torch / Warp device [cpu].")
@click.option("--hold-tips", type=int, default=None,
              help="Success: lifted by h_bar with this many fingertip pads on the target (0: "
              "any rise) [reward.hold_tips, 2].")
@click.option("--out", type=click.Path(path_type=Path, dir_okay=False), default=None,
              help="CSV with one row per variant and object (rewritten after each variant).")
@_config_options
def grasp(
    family_name: str, variants: str, grid: bool, objects: str | None, trials: int, seed: int,
    backend: str | None, device: str | None, hold_tips: int | None, out: Path | None,
    config_path: Path | None, sets: tuple[str, ...], data_dir: Path | None,
) -> None:
    """Scripted grasp trials, each classified: lifted (the task's success), dropped (rose 2 cm,
    not lifted), no grip (never rose 2 cm), pushed (never rose, knocked > 2 cm sideways first).

    All variants run the same initial states: TRIALS per object in one batch, seeded by SEED.
    Prints a table per variant; --out writes the rows (with the highest and median rise, the
    lowest thumb and index pad during the close, and the lifts held by two pads within 2 cm).
    """
    _at_least("--trials", trials, 1)
    _at_least("--seed", seed, 0)
    _device(device)
    if hold_tips is not None:
        _at_least("--hold-tips", hold_tips, 0)
    given = _sets(sets)
    from trainer.grasps import family, family_variants
    from trainer.grasps.families import merge_overrides
    from trainer.grasps.outcomes import write_rows
    from trainer.grasps.trials import run_trials

    fam = family(family_name)
    names = None if variants == "all" else [v for v in variants.split(",") if v]
    chosen = family_variants(family_name, names, grid=grid)
    if objects is None:
        objects = ",".join(fam.grid_objects or fam.objects if grid else fam.objects)
    env = {k: v for k, v in {"data_dir": data_dir, "backend": backend, "device": device,
                             "reward": None if hold_tips is None else {"hold_tips": hold_tips},
                             }.items() if v is not None}
    _one_source(given, {key: option for key, option, value in (
        ("data_dir", "--data-dir", data_dir), ("backend", "--backend", backend),
        ("device", "--device", device), ("reward.hold_tips", "--hold-tips", hold_tips),
    ) if value is not None})
    env = merge_overrides(dotted_overrides(given), env)
    rows: list[dict] = []
    for batch in run_trials([(family_name, n, v) for n, v in chosen.items()],
                            objects.split(","), trials, [seed], config_path=config_path, **env):
        rows += batch.rows
        click.echo(f"\n### {family_name} {batch.variant} ({batch.lifted}/{batch.trials} lifted, "
                   f"{batch.seconds:.0f} s)\n")
        click.echo("| object | lifted | dropped | no grip | pushed | max rise cm | held lifts |")
        click.echo("|---|---:|---:|---:|---:|---:|---:|")
        for r in batch.rows:
            click.echo(f"| {r['object']} | {r['lifted']} | {r['dropped']} | {r['no_grip']} | "
                       f"{r['pushed']} | {r['max_rise_cm']} | {r['held_lifts']} |")
        if out is not None:
            write_rows(out, rows)
    if out is not None:
        click.echo(f"\nrows: {out}")


@cli.command("grasp-search")
@click.option("--objects", required=True, help="Object names (comma-separated), one search each.")
@click.option("--population", default=24, show_default=True,
              help="Candidate grasps per iteration.")
@click.option("--trials", default=4, show_default=True,
              help="Randomized trials per candidate (fresh initial states every iteration).")
@click.option("--iterations", default=6, show_default=True, help="Cross-entropy iterations.")
@click.option("--elite", default=5, show_default=True, help="Best candidates refitted to.")
@click.option("--seed", default=0, show_default=True, help="Seed of the samples and states.")
@click.option("--spread", default=1.0, show_default=True,
              help="Scale of the initial sampling std (e.g. 2: positions +-6 cm, turns +-0.6 "
              "rad).")
@click.option("--refine", is_flag=True,
              help="Start from each object's grasp already in the file (default: from the top "
              "grasp); use with a smaller --spread.")
@click.option("--out", type=click.Path(path_type=Path, dir_okay=False), default=None,
              help="One searched-grasp file (one configuration for all its objects) to add the "
              "results to [default: the data directory's grasps/searched/<object>.json, one "
              "grasp per hand and physics, which the `searched` grasp family reads].")
@_config_options
def grasp_search(
    objects: str, population: int, trials: int, iterations: int, elite: int, seed: int,
    spread: float, refine: bool, out: Path | None, config_path: Path | None,
    sets: tuple[str, ...], data_dir: Path | None,
) -> None:
    """Search a grasp for each object (the cross-entropy method over a keyframe grasp's 19
    parameters, scored on MuJoCo rollouts of the lift task, starting from the top grasp) and
    add it to the `searched` grasp family.

    Each iteration runs POPULATION x TRIALS envs; the final candidates are re-run on fresh
    trials and the best is written with its lifts and the configuration it was searched with
    (--config: the hand and physics): into the data directory, per object and hand and physics
    (DATA_DIR/grasps/searched/<object>.json; the family runs it where the hand and physics are
    the same, the shipped grasps elsewhere), or with --out into one file, whose objects share
    one configuration.
    """
    for option, value, minimum in (("--population", population, 2), ("--trials", trials, 1),
                                   ("--iterations", iterations, 1), ("--elite", elite, 2),
                                   ("--seed", seed, 0)):
        _at_least(option, value, minimum)
    if elite > population:
        raise TrainerError(f"--elite {elite}: must be <= --population {population}")
    if not spread > 0:
        raise TrainerError(f"--spread {spread}: must be > 0")
    given = _sets(sets)
    import json

    import torch

    from geomgrasp.files import atomic_path
    from trainer.grasps import searched
    from trainer.grasps.families import merge_overrides
    from trainer.grasps.keyframes import PARAMS
    from trainer.grasps.search import PER_HAND, SearchSettings, make_entry, search_grasp
    from trainer.objects import resolve_names

    settings = SearchSettings(population, trials, iterations, elite, seed, spread)
    # The environment part of the config file, as written (read by the one TOML reader), with
    # the --set values in it.
    written = merge_overrides(read_config_toml(config_path), dotted_overrides(given))
    config = {k: v for k, v in written.items()
              if k not in ("ppo", "run", "objects", "num_envs", "data_dir")}
    data = searched.load_searched(out) if out is not None else {"config": {}, "objects": {}}
    if data["objects"] and data["config"] != config:
        raise TrainerError(
            f"{out} holds grasps searched with another configuration ({data['config']}): pass "
            f"that --config, or --out a new file"
        )
    overrides = {"data_dir": data_dir} if data_dir else {}
    cfg = load_env_config(config_path, given, task="lift", context="none",
                          representation="com", **overrides)
    check_device(cfg.device, f"device {cfg.device!r} in {config_path}", 'set device = "cpu"')
    names = resolve_names(objects, cfg.data_dir)
    key = searched.hand_key(cfg)
    if out is None:  # what the family runs with this hand and physics (data dir, else seed)
        data["objects"] = {n: e for n in names if (e := searched.grasp_for(cfg, n)) is not None}
    if refine and (missing := [n for n in names if n not in data["objects"]]):
        where = out if out is not None else (
            f"{cfg.data_dir / searched.STORE} (for this hand and physics) or "
            f"{searched.SEARCHED_PATH.name}")
        raise TrainerError(f"--refine: {where} has no grasp for {', '.join(missing)}: search "
                           f"it first without --refine")
    for name in names:
        start = None
        if refine:
            start = torch.tensor([data["objects"][name]["theta"][p] for p in PARAMS])
        click.echo(f"\n### {name}: {population} candidates x {trials} trials, "
                   f"{iterations} iterations\n")
        click.echo("| iteration | best | mean | lift rate | elite lift rate | s |")
        click.echo("|---:|---:|---:|---:|---:|---:|")
        result = search_grasp(cfg, name, settings, start, on_iteration=lambda r: click.echo(
            f"| {r['iteration']} | {r['best']} | {r['mean']} | {r['lift_rate']} "
            f"| {r['elite_lift_rate']} | {r['seconds']} |"))
        click.echo(f"\n{name}: best {result.lifted}/{result.final_trials} lifted in its final "
                   f"trials")
        data["config"] = config
        earlier = []
        if refine:  # the searches this one continued, oldest first
            previous = data["objects"][name]
            earlier = [*previous.get("earlier", []),
                       {k: previous[k] for k in ("lifted", "final_trials", "search", "history")}]
        entry = make_entry(cfg, result, settings, config, refine, earlier)
        if out is None:
            written = searched.write_entry(cfg.data_dir, name, key, entry)
            data["objects"][name] = entry
        else:  # the file's objects share its one config
            data["objects"][name] = {k: v for k, v in entry.items() if k not in PER_HAND}
            with atomic_path(out) as tmp:
                tmp.write_text(json.dumps(data, indent=1) + "\n")
            written = out
        click.echo(f"written: {written}")


@cli.command()
@click.option("--task", type=click.Choice(tuple(TASKS)), default=None,
              help="lift (one object on the table) or bin (a target out of a cluttered bin) "
              "[lift].")
@click.option("--bin-objects", type=int, default=None,
              help="Objects in the bin (bin task; the paper: 5 or 10) [5].")
@click.option("--context", type=click.Choice(CONTEXTS), default=None,
              help="bbox: the bin task also sees the other objects' boxes [none].")
@click.option("--backend", type=click.Choice(BACKENDS), default=None,
              help="Physics backend [cpu]: cpu (MuJoCo C threads) or warp (MuJoCo Warp, "
              "pip install -e '.[gpu]'; with --device cuda on a GPU).")
@click.option("--repr", "representation", type=click.Choice(REPRESENTATIONS), default=None,
              help="Object representation the policy sees [the task's: sq for lift, bbox for "
              "bin].")
@click.option("--reward", type=click.Choice(REWARDS), default=None,
              help="sdf (the paper), com (distance to the centre of mass), none (no shaping).")
@click.option("--robot", type=click.Choice(ROBOTS), default=None, help="[default: ur5e]")
@click.option("--objects", default=None, help="Object set (builtin, ycb, all) or names.")
@click.option("--num-envs", type=int, default=None, help="Parallel environments [64].")
@click.option("--steps", type=int, default=None, help="Total environment steps [10M].")
@click.option("--minutes", type=float, default=None,
              help="Stop (with a checkpoint) once training has run this long, a resumed run's "
              "earlier parts included [no limit].")
@click.option("--seed", type=int, default=None, help="[0]")
@click.option("--device", default=None, help="Torch device of the networks and tensors [cpu].")
@click.option("--run-dir", type=click.Path(path_type=Path, file_okay=False), default=None,
              help="Where the run goes [runs/REPR-REWARD-ROBOT-sSEED].")
@click.option("--resume", "resume_dir", type=click.Path(path_type=Path, file_okay=False),
              default=None, help="Continue a killed run from its last checkpoint (with --steps: "
              "extend it to that many steps; other options cannot change it).")
@click.option("--overwrite", is_flag=True,
              help="Delete the run already in the run directory and start afresh.")
@click.option("--init-agent", type=click.Path(path_type=Path), default=None,
              help="Start from the networks and normalizers of this checkpoint file or run "
              "directory (its last checkpoint); all else starts fresh [none].")
@click.option("--compile/--no-compile", "compile_env", default=None,
              help="torch.compile the per-step task computations (faster after ~1 min of "
              "compilation; needs a C++ compiler on CPU) [default: compile in the config, "
              "false].")
@_config_options
def run(
    task: str | None, bin_objects: int | None, context: str | None, backend: str | None,
    representation: str | None, reward: str | None, robot: str | None, objects: str | None,
    num_envs: int | None, steps: int | None, minutes: float | None, seed: int | None,
    device: str | None,
    run_dir: Path | None, resume_dir: Path | None, overwrite: bool, init_agent: Path | None,
    compile_env: bool | None, config_path: Path | None, sets: tuple[str, ...],
    data_dir: Path | None,
) -> None:
    """Train a grasping policy with PPO (TorchRL collector, GAE, ClipPPOLoss, Adam).

    The run directory gets config.json (everything resolved), metrics.csv and tb/ (TensorBoard),
    and checkpoints/. Options override the --config TOML ([ppo], [run] and env sections);
    --set section.key=value sets any key of it (trainer config lists them).
    """
    if resume_dir is not None:
        # A resumed run continues bit for bit with its own config.json: an option that would
        # change it is refused rather than silently ignored.
        compile_option = {True: "--compile", False: "--no-compile", None: None}[compile_env]
        given = {
            "--task": task, "--bin-objects": bin_objects, "--context": context,
            "--backend": backend, "--repr": representation, "--reward": reward, "--robot": robot,
            "--objects": objects, "--num-envs": num_envs, "--seed": seed, "--device": device,
            "--run-dir": run_dir, "--config": config_path, "--set": sets or None,
            "--data-dir": data_dir,
            "--overwrite": overwrite or None, "--init-agent": init_agent,
            compile_option: compile_env,
        }
        for option, value in given.items():
            if option is not None and value is not None:
                raise TrainerError(
                    f"{option} cannot change a resumed run (it keeps its config.json): drop "
                    f"{option}, or start a new run with another --run-dir"
                )
        _resume(resume_dir, steps, minutes)
        return
    env = {
        k: v for k, v in {
            "task": task, "context": context, "backend": backend,
            "bin": {"num_objects": bin_objects} if bin_objects is not None else None,
            "representation": representation, "objects": objects, "num_envs": num_envs,
            "device": device, "data_dir": data_dir, "compile": compile_env,
            "reward": {"kind": reward} if reward else None,
            "robot": {"kind": robot} if robot else None,
        }.items() if v is not None
    }
    run_over = {
        k: v for k, v in {
            "total_steps": steps, "seed": seed, "max_minutes": minutes,
            "init_agent": None if init_agent is None else str(init_agent),
        }.items() if v is not None
    }
    given = _sets(sets, training=True)
    chosen = {f"run.{k}": RUN_OPTIONS[k] for k in run_over}  # key as --set names it -> option
    for k, v in dotted_overrides(env).items():
        keys = [f"{k}.{f}" for f in v] if isinstance(v, dict) else [k]
        chosen.update({key: RUN_OPTIONS[key] for key in keys})
    _one_source(given, chosen)
    cfg = load_train_config(config_path, env=env, run=run_over, names=RUN_OPTIONS, sets=given)
    where = f"--device {device}" if device else f"device {cfg.env.device!r} in {config_path}"
    check_device(cfg.env.device, where, "use --device cpu")
    check_backend(cfg.env.backend)
    if run_dir is None:
        e = cfg.env
        task = "" if e.task == "lift" else f"{e.task}{e.bin.num_objects}-"
        context = "" if e.context == "none" else f"-ctx{e.context}"
        run_dir = Path("runs") / (
            f"{task}{e.representation}{context}-{e.reward.kind}-{e.robot.kind}-s{cfg.run.seed}"
        )

    from trainer.ppo import train_run

    _echo_once(f"run: {run_dir}")
    with _process_group():
        train_run(cfg, run_dir, overwrite=overwrite)


def _echo_once(line: str) -> None:
    """``line`` on stdout, once per run: by rank 0 of a run spread over processes (torchrun
    sets ``RANK``)."""
    if os.environ.get("RANK", "0") == "0":
        click.echo(line)


@contextlib.contextmanager
def _process_group() -> Iterator[None]:
    """Leave the process group a distributed run joined (``trainer.training.distributed``),
    however it ends."""
    try:
        yield
    finally:
        if "WORLD_SIZE" in os.environ:
            from trainer.training import distributed

            distributed.shutdown()


def _resume(run_dir: Path, steps: int | None, minutes: float | None) -> None:
    from trainer.ppo import train_run
    from trainer.training.run_dir import RunDir

    cfg = RunDir(run_dir).load_config()
    changes, said = {}, []
    # Neutral wording: a --steps below what the run has done is refused next, by train_run().
    if steps is not None:
        changes["total_steps"] = steps
        said.append(f"total steps {steps:,}, was {cfg.run.total_steps:,}")
    if minutes is not None:
        changes["max_minutes"] = minutes
        said.append(f"time budget {minutes:g} min, was {cfg.run.max_minutes:g}")
    if changes:
        cfg = dataclasses.replace(cfg, run=override(cfg.run, changes, RUN_OPTIONS))
    _echo_once(f"run: {run_dir} (resumed{'; ' if said else ''}{'; '.join(said)})")
    with _process_group():
        train_run(cfg, run_dir, resume=True)


@cli.command("eval")
@click.argument("run_dir", type=click.Path(path_type=Path))
@click.option("--episodes-per-object", default=10, show_default=True,
              help="Episodes with each object as the target (bin: at least that many).")
@click.option("--objects", default=None, help="Evaluate on these objects instead (bin: the "
              "bins are drawn from them).")
@click.option("--held-out", is_flag=True,
              help="Evaluate on the objects the run held out (its config's held_out), which it "
              "never trained on [out: eval-held-out].")
@click.option("--max-rounds", default=20, show_default=True,
              help="Bin task: rounds of episodes at most, however few an object has.")
@click.option("--bin-objects", type=int, default=None,
              help="Bin task: bins of this many objects, drawn by the run's seed (the paper "
              "evaluates its 5-object policy on 10; the run's own size draws the run's own "
              "bins) [the run's bins; out: eval-binN].")
@click.option("--new-bins", is_flag=True,
              help="Bin task: bins the run never trained on (its bins are its seed's [bin] "
              "layouts; these, another seed's) [out: eval-new, eval-binN-new].")
@click.option("--hold-tips", type=int, default=None,
              help="Success: lifted by h_bar with this many fingertip pads on the target (0: "
              "any rise) [the run's reward.hold_tips].")
@click.option("--h-bar", type=float, default=None,
              help="Success: lifted by this many metres [the run's reward.h_bar, 0.2].")
@click.option("--lift-clearance", type=float, default=None,
              help="Success: the target's lowest surface point risen this many metres too (a "
              "tip is not a lift) [the run's reward.lift_clearance, 0].")
@click.option("--iteration", type=int, default=None,
              help="Evaluate the checkpoint of this training iteration; 0: the agent the run "
              "started from (its init_agent), before any training [the last].")
@click.option("--sample", is_flag=True,
              help="Sample the actions from the policy's Gaussian, as in training, instead of "
              "taking its mean (seeded: repeatable).")
@click.option("--pads", is_flag=True,
              help="Also count the successes held by two or more fingertip pads within 2 cm of "
              "the target at the success step (with --hold-tips 0: which lifts were tosses).")
@click.option("--out", default=None,
              help="Folder in the run directory for the results (trainer report reads eval) "
              "[eval; with --sample: eval-sampled; with --iteration 0: eval-start].")
@click.option("--device", default=None, help="Torch device [the run's].")
def eval_cmd(
    run_dir: Path, episodes_per_object: int, objects: str | None, held_out: bool,
    max_rounds: int, hold_tips: int | None, h_bar: float | None, lift_clearance: float | None,
    iteration: int | None, sample: bool, pads: bool, out: str | None, device: str | None,
    bin_objects: int | None, new_bins: bool,
) -> None:
    """Success per target object of the deterministic policy (eval/per_object.csv,
    eval/table.md), or with --sample of the policy as it acts in training.

    Lift: EPISODES_PER_OBJECT episodes of each object. Bin: the bins the run trained on, rounds
    of new episodes with the targets balanced over the objects, until each object in the bins
    has been the target at least EPISODES_PER_OBJECT times (or MAX_ROUNDS rounds ran); with
    --bin-objects, new bins of that many objects; with --new-bins, bins it never trained on.
    """
    _at_least("--episodes-per-object", episodes_per_object, 1)
    _at_least("--max-rounds", max_rounds, 1)
    if bin_objects is not None:
        _at_least("--bin-objects", bin_objects, 1)
    _device(device)
    from trainer.evaluation import evaluate

    if iteration is not None:
        _at_least("--iteration", iteration, 0)
    if held_out:
        from trainer.training.run_dir import RunDir

        if objects is not None:
            raise TrainerError("--held-out and --objects: pass one (--held-out evaluates the "
                               "run's held-out objects)")
        objects = RunDir(_run_dir(run_dir)).load_config().env.held_out
        if not objects:
            raise TrainerError(f"{run_dir} holds out no objects (its config's held_out is "
                               "empty): evaluate other objects with --objects NAMES")
        out = out or "eval-held-out"
    result = evaluate(
        _run_dir(run_dir), episodes_per_object, objects, device=device, max_rounds=max_rounds,
        hold_tips=hold_tips, h_bar=h_bar, iteration=iteration, out=out, sample=sample,
        pads=pads, lift_clearance=lift_clearance, bin_objects=bin_objects, new_bins=new_bins,
    )
    sampled = " (actions sampled)" if sample else ""
    click.echo(f"{result.describe()}: success per target object{sampled}")
    width = max(len(n) for n in result.names)
    for k, name in enumerate(result.names):
        held = "" if result.held is None else f"  held by two pads {result.held[k]}"
        if result.face_up is not None and result.upside_down(k)[0]:  # (by_start.csv)
            (up, up_held), (down, down_held) = result.face_up[k], result.upside_down(k)
            held += f"  (started face up {up_held}/{up}, upside down {down_held}/{down})"
        if result.endings is not None and result.successes[k] < result.episodes[k]:
            ends = [f"{e} {by[k]}" for e, by in result.endings.items()
                    if e != "success" and by[k]]
            held += f"  failed: {', '.join(ends)}"
        click.echo(f"{name:<{width}}  {result.successes[k]}/{result.episodes[k]}{held}")
    click.echo(f"{'overall':<{width}}  {result.overall:.3f}")
    click.echo(f"success: the target {result.success_text}")
    if result.short:
        click.echo(
            f"note: after {result.rounds} round{'s' if result.rounds != 1 else ''} "
            f"(--max-rounds) {len(result.short)} objects have fewer than {episodes_per_object} "
            f"episodes: {', '.join(result.short)}"
        )
    if result.absent:
        click.echo(f"note: in none of the run's bins (never a target): {', '.join(result.absent)}")


@cli.command()
@click.argument("run_dirs", nargs=-1, required=True, type=click.Path(path_type=Path))
@click.option("--out", type=click.Path(path_type=Path, file_okay=False), default=Path("report"),
              show_default=True)
@click.option("--compare", default=None, help="BASE,OTHER: per-object gain plot of OTHER over "
              "BASE (representation names or group labels).")
@click.option("--eval", "eval_dir", default="eval", show_default=True,
              help="The folder in each run directory to read the evaluation from (trainer eval "
              "--out NAME), e.g. eval-it350.")
@click.option("--thresholds", default="0.9,0.95", show_default=True,
              help="Success rates for Table II's steps and minutes (the paper's 0.9,0.95; e.g. "
              "0.5,0.7 at CPU scale).")
@click.option("--allow-differ", default="",
              help="Config fields the seeds of one arm may differ in besides the seed and how "
              "they ran, comma-separated (e.g. run.max_minutes): otherwise such runs are split.")
@click.option("--worst", "worst_count", default=10, show_default=True,
              help="Objects per arm in the table of the worst objects and how their episodes "
              "ended (evaluations with endings.csv).")
def report(
    run_dirs: tuple[Path, ...], out: Path, compare: str | None, eval_dir: str, thresholds: str,
    allow_differ: str, worst_count: int,
) -> None:
    """report.md with the paper's Table I (success per object, ours beside the paper's), the
    rank correlation with its ordering, Table II (steps and minutes to THRESHOLDS, env steps per
    second) and learning curves, over runs and seeds."""
    pair = tuple(compare.split(",")) if compare else None
    if pair is not None and len(pair) != 2:
        raise TrainerError("--compare takes two labels: BASE,OTHER (e.g. com,sq)")
    try:
        rates = tuple(float(t) for t in thresholds.split(","))
    except ValueError:
        raise TrainerError(
            f"--thresholds {thresholds!r}: give comma-separated success rates, e.g. 0.5,0.7"
        ) from None
    fields = tuple(f.strip() for f in allow_differ.split(",") if f.strip())
    for path in run_dirs:
        _run_dir(path)
    from trainer.report import write_report

    for path in write_report(list(run_dirs), out, pair, eval_dir, rates, fields, worst_count):
        click.echo(str(path))


@cli.command()
@click.argument("run_dir", type=click.Path(path_type=Path))
@click.option("--object", "object_name", required=True,
              help="Object to grasp (bin run: the target, in one of the run's bins).")
@click.option("--video", type=click.Path(path_type=Path, dir_okay=False),
              default=Path("play.mp4"), show_default=True)
@click.option("--episodes", default=1, show_default=True,
              help="Episodes in the video, side by side (at most 4 are filmed).")
@click.option("--tries", default=None, type=int,
              help="Episodes to run, filming --episodes of them with the successes first: "
                   "find a policy's rare grasps [--episodes].")
@click.option("--seed", default=0, show_default=True)
@click.option("--device", default=None, help="Torch device [the run's].")
def play(
    run_dir: Path, object_name: str, video: Path, episodes: int, tries: int | None, seed: int,
    device: str | None,
) -> None:
    """Render episodes of the trained (deterministic) policy into a video.

    Lift run: OBJECT alone on the table. Bin run: episodes in the run's bins whose target is
    OBJECT (it must be in one of them). An episode that ends before the others holds its
    last commands (a lift stays lifted); the video goes on 1 s past the last filmed episode's
    end. With --tries N, N episodes run side by side (nothing rendered) and the video shows
    the successful ones first.
    """
    _at_least("--episodes", episodes, 1)
    tries = episodes if tries is None else tries
    if tries < episodes:
        raise TrainerError(f"--tries {tries}: must be >= --episodes ({episodes})")
    _at_least("--seed", seed, 0)
    _device(device)
    from trainer.session import EvalSession, successes_first
    from trainer.video import EnvRecorder, StateTape

    session = EvalSession.load(_run_dir(run_dir), device)
    cfg = session.cfg
    names = session.names(object_name)
    if len(names) != 1:
        raise TrainerError(f"--object {object_name}: names several objects: name one")
    env, ids, slots = session.play_env(names[0], tries, seed)
    tape = StateTape(env)
    success, length, _ = session.run(env, target_slots=slots, watch=ids, hold_finished=True,
                                     on_step=tape.on_step)
    filmed = successes_first(ids, success, min(episodes, 4))  # at most 4 tiles
    tape.end_at(int(length[filmed].max()))  # and 1 s more, so it does not end on the lift
    recorder = EnvRecorder(env, filmed, width=480, height=360)
    recorder.film(tape)
    recorder.save(video, fps=cfg.env.physics.control_hz)
    recorder.close()
    env.close()
    shown = int(success[filmed].sum())
    click.echo(f"{names[0]}: success {int(success[ids].sum())}/{len(ids)}, "
               f"{int(length[ids].max())} steps; video: {video} ({len(filmed)} episodes, "
               f"{shown} of them successes)")


@cli.command("config")
@click.argument("keys", nargs=-1)
@click.option("--paper", "paper_only", is_flag=True, help="Only the keys the paper states.")
@click.option("--markdown", type=click.Path(path_type=Path, dir_okay=False), default=None,
              help="Write every key as a Markdown page to this file (docs/config.md) instead.")
def config_cmd(keys: tuple[str, ...], paper_only: bool, markdown: Path | None) -> None:
    """Every config key: its default, the values it accepts, what the paper states ("ours":
    nothing, a key of this project) and what it does, section by section.

    KEYS: only the keys whose name contains one of them, or a section (reward, ppo, run).
    Set a key in a --config TOML file (in its [section]) or with --set section.key=value.
    """
    from trainer.config_keys import listing, select
    from trainer.config_keys import markdown as page

    if markdown is not None:
        if keys or paper_only:
            raise TrainerError("--markdown writes every key: drop the KEYS and --paper")
        from geomgrasp.files import atomic_path

        with atomic_path(markdown) as tmp:
            tmp.write_text(page(), encoding="utf-8")
        click.echo(f"written: {markdown}")
        return
    click.echo(listing(select(keys, paper_only)), nl=False)


def format_warning(message: Warning | str, category: type[Warning], filename: str, lineno: int,
                   line: str | None = None) -> str:
    """``warnings.formatwarning`` for the CLI: a ``TrainerWarning`` as one ``warning:`` line,
    any other warning as Python formats it."""
    if issubclass(category, TrainerWarning):
        return f"warning: {message}\n"
    return _python_format_warning(message, category, filename, lineno, line)


_python_format_warning = warnings.formatwarning


def main() -> None:
    """Entry point: TrainerError becomes a one-line message and exit status 1; a
    TrainerWarning one ``warning:`` line."""
    warnings.formatwarning = format_warning
    run_cli(cli, (TrainerError,))


if __name__ == "__main__":
    main()
