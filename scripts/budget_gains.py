"""The comparison at two budgets, run by run: each extended run against its run at the budget.

    python scripts/budget_gains.py results/cpu-comparison-2026-11-29/runs \
        --base bbox-sdf-s0=results/cpu-together-starts50-2026-11-27/run \
        --objects 029_plate,032_knife,062_dice,072-a_toy_airplane

For every evaluated ``ext-ARM`` folder in RUNS (made by ``EXTEND_TO=STEPS
scripts/comparison_runs.sh``: ``cmp-ARM`` continued with nothing else changed and evaluated on
the same episodes) prints one markdown row: the held rate of ``cmp-ARM`` and of ``ext-ARM``,
the gain by object ± its standard error (scripts/paired_evals.py's measure, "noise" within two
standard errors), and each of the named objects' successes at both. ``--base ARM=RUN`` names a
run at the budget kept elsewhere (bbox seed 0's is the run that set the budget). Extensions
not yet evaluated are listed after the table as still running.
"""

from __future__ import annotations

import sys
from pathlib import Path

import click

sys.path.insert(0, str(Path(__file__).resolve().parent))
from paired_evals import gain, held_rate, is_noise, read_eval  # noqa: E402  (a script beside this one)


def rows(runs: Path, bases: dict[str, Path], objects: list[str]) -> tuple[list[str], list[str]]:
    """(the table's lines, the arms extended but not yet evaluated)."""
    lines = ["| run | at the budget | extended | by object (paired) | "
             + " | ".join(objects) + " |",
             "|---|---:|---:|---|" + "---:|" * len(objects)]
    running = []
    for folder in sorted(runs.glob("ext-*")):
        if folder.name.endswith(".partial"):  # a copy interrupted before its rename
            continue
        arm = folder.name.removeprefix("ext-")
        if not (folder / "eval" / "per_object.csv").is_file():
            running.append(arm)
            continue
        base_run = bases.get(arm, runs / f"cmp-{arm}")
        if not (base_run / "eval" / "per_object.csv").is_file():
            raise click.ClickException(
                f"{arm}: {base_run} has no evaluation at the budget; name the run with "
                f"--base {arm}=RUN")
        base, _ = read_eval(base_run / "eval")
        other, _ = read_eval(folder / "eval")
        mean, error, up, down, _ = gain(base, other)
        noise = "; noise" if is_noise(mean, error) else ""
        cells = [f"{base.get(o, (0, 0))[1]} -> {other.get(o, (0, 0))[1]}" for o in objects]
        lines.append(f"| {arm} | {held_rate(base):.3f} | **{held_rate(other):.3f}** | "
                     f"{mean:+.3f} ± {error:.3f} ({up} up, {down} down{noise}) | "
                     + " | ".join(cells) + " |")
    return lines, running


@click.command(context_settings={"help_option_names": ["-h", "--help"]})
@click.argument("runs", type=click.Path(path_type=Path, file_okay=False, exists=True))
@click.option("--base", "bases", multiple=True, metavar="ARM=RUN",
              help="The run at the budget of ARM where it is not RUNS/cmp-ARM.")
@click.option("--objects", default="", help="Comma-separated objects to show one by one.")
def main(runs: Path, bases: tuple[str, ...], objects: str) -> None:
    """Each evaluated RUNS/ext-ARM against its run at the budget."""
    named = {}
    for entry in bases:
        arm, sep, path = entry.partition("=")
        if not sep or not arm or not path:
            raise click.UsageError(f"--base {entry}: write ARM=RUN, e.g. "
                                   f"bbox-sdf-s0=results/cpu-together-starts50-2026-11-27/run")
        named[arm] = Path(path)
    lines, running = rows(runs, named, [o for o in objects.split(",") if o])
    if len(lines) == 2:
        raise click.ClickException(f"{runs}: no evaluated ext-* run")
    click.echo("\n".join(lines))
    if running:
        click.echo(f"\nnot evaluated yet: {', '.join(running)}")


if __name__ == "__main__":
    sys.exit(main())
