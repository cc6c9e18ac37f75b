"""The ``geomprep`` command line: fetch objects, build their assets, inspect them.

The stages (open3d, trimesh, CoACD, MuJoCo, torch) are imported inside the commands that run
them, through ``pipeline``: ``geomprep --help`` and ``geomprep fetch`` start in a fraction of a
second instead of three.
"""

from __future__ import annotations

import logging
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

import click

from geomgrasp.cli import run_cli
from geomprep import importer, ycb, ycb_download
from geomprep.config import Config, load_config
from geomprep.errors import GeomprepError

if TYPE_CHECKING:
    from geomprep import pipeline

STAGE_HELP = {
    "mesh": "Load, clean, check units, centre at the centre of mass, attach the mass.",
    "decompose": "Convex decomposition (CoACD) into small collision hulls.",
    "mjcf": "Write the MuJoCo model and check that it settles on a plane.",
    "sdf": "Signed-distance grid (200^3 over [-0.5, 0.5]^3 m by default).",
    "bbox": "Oriented bounding box along the principal axes.",
    "sq": "Superquadric fit (EMS + surface term) with two-sided errors and volume IoU.",
    "pc": "32/128/512 well-spread surface points with normals.",
}


class Context:
    def __init__(
        self, config_path: Path | None, data_dir: Path | None, sets: tuple[str, ...] = ()
    ) -> None:
        self.config_path = config_path
        self.data_dir = data_dir
        self.sets = sets

    @property
    def cfg(self) -> Config:
        return load_config(self.config_path, self.data_dir, self.sets)


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.option(
    "--data-dir",
    type=click.Path(path_type=Path, file_okay=False),
    envvar="GEOMPREP_DATA_DIR",
    help="Data directory (raw/, interim/, processed/). Default: ./data, or data_dir in the config.",
)
@click.option(
    "--config",
    "config_path",
    type=click.Path(path_type=Path, dir_okay=False),
    help="TOML file overriding stage parameters. Default: ./geomprep.toml if present.",
)
@click.option(
    "--set", "sets", multiple=True, metavar="SECTION.KEY=VALUE",
    help="Override one stage parameter after the config file (repeatable), e.g. "
         "--set sdf.resolution=64.",
)
@click.option("-v", "--verbose", is_flag=True, help="Log every stage as it finishes.")
@click.pass_context
def cli(
    ctx: click.Context, data_dir: Path | None, config_path: Path | None,
    sets: tuple[str, ...], verbose: bool,
) -> None:
    """Turn object meshes into simulation-ready, geometry-annotated assets.

    \b
    Typical use:
      geomprep build-all                       # the built-in object set, no download
      geomprep fetch --from ~/ycb && geomprep build-all --objects ycb
      geomprep sdf 032_knife                   # one stage of one object
      geomprep show 032_knife                  # summary + PNG preview

    Every stage caches on a hash of its inputs and parameters: rerunning is cheap and a killed
    build resumes where it stopped.
    """
    logging.basicConfig(
        level=logging.INFO if verbose else logging.WARNING, format="%(levelname)s %(message)s"
    )
    logging.getLogger("trimesh").setLevel(logging.ERROR)
    ctx.obj = Context(config_path, data_dir, sets)


@cli.command()
@click.option(
    "--from",
    "source_dir",
    type=click.Path(path_type=Path, file_okay=False),
    help="Import a local directory (YCB layout NAME/google_16k/textured.obj, or NAME.obj|.ply|.stl "
    "files) instead of downloading.",
)
@click.option("--objects", default=None, help="Comma-separated names (default: all available).")
@click.option(
    "--masses",
    type=click.Path(path_type=Path, dir_okay=False, exists=True),
    help="CSV 'object,mass_kg'. Default: masses.csv inside --from, if any.",
)
@click.option("--density", type=float, default=None, help="kg/m^3 for objects with no mass listed.")
@click.option("--force", is_flag=True, help="Re-import objects that are already complete.")
@click.option("--url", default=ycb.BASE_URL, show_default=True, help="YCB archive server.")
@click.pass_obj
def fetch_cmd(
    obj: Context,
    source_dir: Path | None,
    objects: str | None,
    masses: Path | None,
    density: float | None,
    force: bool,
    url: str,
) -> None:
    """Download the YCB google_16k models (resumable, verified) or import a local directory.

    With no --from, downloads from the YCB server (all 78 objects unless --objects). Built-in
    object names (builtin_box, ...) in --objects are written from code instead.
    """
    cfg = obj.cfg
    names = [n.strip() for n in objects.split(",") if n.strip()] if objects else None
    density = density if density is not None else cfg.mesh.density_kg_m3
    done: list[str] = []
    if names is not None:  # built-in objects are written, not fetched
        from geomprep import builtin, pipeline

        builtin_names = [n for n in names if n in builtin.NAMES]
        pipeline.ensure_builtin(cfg, builtin_names)
        done += builtin_names
        names = [n for n in names if n not in builtin.NAMES]
        if not names and source_dir is None:
            click.echo(f"{len(done)} objects ready in {cfg.raw_dir}")
            return
    if source_dir is not None:
        done += importer.import_directory(
            source_dir, cfg.raw_dir, names, density_kg_m3=density, masses_csv=masses, force=force
        )
    else:
        done += ycb_download.fetch_ycb(
            cfg.raw_dir, names, base_url=url, masses_csv=masses, density_kg_m3=density, force=force
        )
    click.echo(f"{len(done)} objects ready in {cfg.raw_dir}")


@cli.command("list")
@click.option("--available", is_flag=True, help="List the YCB objects that 'fetch' can download.")
@click.pass_obj
def list_cmd(obj: Context, available: bool) -> None:
    """Show the objects and the status of each stage.

    \b
    done     up to date, its recorded outputs intact
    stale    made from other inputs or parameters (or not recorded): rebuilt by build-all
    invalid  an output changed or vanished since it was written: rebuilt by build-all
    -        not built
    """
    from geomprep import pipeline

    if available:
        for name in ycb.OBJECTS:
            click.echo(name)
        return
    cfg = obj.cfg
    names = pipeline.resolve_objects(cfg, "all")
    stages = [*pipeline.STAGES, "pack"]
    width = max(len(n) for n in names)
    click.echo(f"{'object':<{width}}  " + " ".join(f"{s:<9}" for s in stages))
    marks = {"done": "done", "stale": "stale", "invalid": "invalid", "missing": "-"}
    for name in names:
        status = pipeline.stage_status(cfg, name)
        click.echo(f"{name:<{width}}  " + " ".join(f"{marks[status[s]]:<9}" for s in stages))


def _report(report: pipeline.BuildReport, elapsed: float) -> None:
    computed = len(report.seconds)
    click.echo(
        f"{computed} stages computed, {len(report.skipped)} cached, "
        f"{len(report.failed)} objects failed, in {elapsed:.1f} s"
    )
    for name, error in sorted(report.failed.items()):
        click.echo(f"error: {name}: {error}", err=True)
    if report.failed:
        sys.exit(1)


@cli.command("build-all")
@click.option(
    "--objects",
    default="all",
    show_default=True,
    help="Comma-separated names or sets: all, builtin, ycb (imported YCB objects).",
)
@click.option(
    "--jobs",
    "-j",
    type=click.IntRange(min=0),
    default=None,
    help="Parallel processes (default: all cores).",
)
@click.option("--force", is_flag=True, help="Recompute even stages whose cache is current.")
@click.option("--no-progress", is_flag=True, help="No progress bar (for logs).")
@click.pass_obj
def build_all(obj: Context, objects: str, jobs: int | None, force: bool, no_progress: bool) -> None:
    """Run every stage for every object, then pack data/processed/<name>.h5."""
    from geomprep import pipeline

    cfg = obj.cfg
    start = time.perf_counter()
    names = pipeline.resolve_objects(cfg, objects)
    report = pipeline.build(cfg, names, jobs=jobs, force=force, progress=not no_progress)
    _report(report, time.perf_counter() - start)


def _stage_command(stage: str) -> click.Command:
    @click.command(stage, help=f"{STAGE_HELP[stage]} Runs missing inputs first; repacks if it can.")
    @click.argument("names", nargs=-1, required=True)
    @click.option("--force", is_flag=True, help="Recompute even if the cache is current.")
    @click.pass_obj
    def command(obj: Context, names: tuple[str, ...], force: bool) -> None:
        from geomprep import pipeline

        cfg = obj.cfg
        start = time.perf_counter()
        resolved = pipeline.resolve_objects(cfg, list(names))
        report = pipeline.build(cfg, resolved, stages=[stage], jobs=1, force=force, progress=False)
        # Keep processed/<name>.h5 in step when every other stage is already there.
        packable = [
            n
            for n in resolved
            if n not in report.failed
            and all(v == "done" for s, v in pipeline.stage_status(cfg, n).items() if s != "pack")
        ]
        if packable:
            packed = pipeline.build(cfg, packable, stages=["pack"], jobs=1, progress=False)
            report.seconds.update(packed.seconds)
        for name in resolved:
            if name not in report.failed:  # a failed object's error follows; it has no output
                click.echo(f"{name}: {pipeline.stage_path(cfg, name, stage)}")
        _report(report, time.perf_counter() - start)

    return command


for _stage in STAGE_HELP:  # pipeline.STAGES, without importing the stages (a test checks)
    cli.add_command(_stage_command(_stage))
cli.add_command(fetch_cmd, "fetch")


@cli.command()
@click.argument("name")
@click.option(
    "--out",
    type=click.Path(path_type=Path, dir_okay=False),
    help="PNG path. Default: data/previews/<name>.png.",
)
@click.pass_obj
def show(obj: Context, name: str, out: Path | None) -> None:
    """Print a summary of an object's artifacts and write a PNG preview.

    A partly built object shows the stages that are done and names the others."""
    from geomprep import pipeline, preview, store

    cfg = obj.cfg
    pipeline.resolve_objects(cfg, [name])
    status = pipeline.stage_status(cfg, name)
    if status["pack"] == "done":  # every group, from the one verified file
        sources = {group: pipeline.stage_path(cfg, name, "pack") for group in preview.GROUPS}
    else:  # only verified stage files: a stale or damaged one is not shown as the object
        sources = {
            store.STAGE_GROUPS[stage]: pipeline.stage_path(cfg, name, stage)
            for stage in pipeline.STAGES
            if status[stage] == "done"
        }
    click.echo(f"object      {name}")
    by_status: dict[str, list[str]] = {}
    for stage, state in status.items():
        by_status.setdefault(state, []).append(stage)
    click.echo(
        "stages      "
        + "; ".join(f"{state} {', '.join(by_status[state])}" for state in sorted(by_status))
    )
    if set(by_status) != {"done"}:
        click.echo(f"            to build the rest: geomprep build-all --objects {name}")
    if "mesh" not in sources:
        click.echo("preview     none: nothing can be drawn before the mesh stage is done")
        return
    why = {"missing": "not built", "stale": "stale: not shown", "invalid": "damaged: not shown"}
    absent = {store.STAGE_GROUPS[s]: why.get(status[s], status[s]) for s in pipeline.STAGES}
    click.echo(preview.summary(sources, absent))
    out = out or cfg.data_dir / "previews" / f"{name}.png"
    try:
        preview.render(sources, out, title=name)
    except OSError as exc:
        raise GeomprepError(
            f"cannot write the preview {out} ({exc.strerror}): pass --out with a writable path"
        ) from None
    click.echo(f"preview: {out}")


def main() -> None:
    """Entry point: run the CLI, turning GeomprepError into a one-line message and exit 1."""
    run_cli(cli, (GeomprepError,))


if __name__ == "__main__":
    main()
