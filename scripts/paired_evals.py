"""Two evaluations of the same episodes, compared (the paired arms of results/cpu-bin-*/).

    python scripts/paired_evals.py BASE_EVAL OTHER_EVAL [OTHER_EVAL...]

Each EVAL is a ``trainer eval`` folder (``per_object.csv``, and ``endings.csv`` where the
evaluation wrote one). Runs evaluated with the same seed, episodes per object and bins play the
same episodes (the same bins, targets and drops), so their difference by object is a paired
measurement. Prints, per evaluation, the held rate over all episodes and how the episodes
ended; per OTHER, its gain over BASE by object: the mean of the per-object differences ± their
standard error, and how many objects went up and down. A difference within two standard
errors is noise at this sample size.
"""

from __future__ import annotations

import csv
import math
import sys
from pathlib import Path

import click

from trainer.evaluation import ENDINGS
from trainer.report import comparable_endings


def read_eval(folder: Path) -> tuple[dict[str, tuple[int, int]], dict[str, int]]:
    """(object -> (episodes, successes) of the objects with episodes, ending -> episodes
    summed over objects; empty where the folder has no endings.csv)."""
    path = folder / "per_object.csv"
    if not path.is_file():
        raise click.ClickException(f"{folder}: no per_object.csv: pass a trainer eval folder")
    rates = {}
    for row in csv.DictReader(path.open()):
        if int(row["episodes"]):
            rates[row["object"]] = (int(row["episodes"]), int(row["successes"]))
    endings: dict[str, int] = {}
    if (folder / "endings.csv").is_file():
        for row in csv.DictReader((folder / "endings.csv").open()):
            for ending in ENDINGS:
                column = ending.replace(" ", "_")  # (endings.csv's column names)
                if column in row:  # never_reached: recorded since 2026-11-30
                    endings[ending] = endings.get(ending, 0) + int(row[column])
    return rates, endings


def gain(base: dict[str, tuple[int, int]],
         other: dict[str, tuple[int, int]]) -> tuple[float, float, int, int, int]:
    """(mean per-object difference of ``other``'s held rate over ``base``'s, its standard
    error, objects up, objects down, objects compared) over the objects both evaluated with
    the same number of episodes (a different count: not the same episodes, refused)."""
    shared = sorted(set(base) & set(other))
    for name in shared:
        if base[name][0] != other[name][0]:
            raise click.ClickException(
                f"{name}: {base[name][0]} episodes against {other[name][0]}: not the same "
                f"episodes; evaluate both with the same --episodes-per-object and seed")
    diffs = [other[n][1] / other[n][0] - base[n][1] / base[n][0] for n in shared]
    if not diffs:
        raise click.ClickException("no object was evaluated in both")
    mean = sum(diffs) / len(diffs)
    spread = (math.sqrt(sum((d - mean) ** 2 for d in diffs) / (len(diffs) - 1) / len(diffs))
              if len(diffs) > 1 else float("nan"))
    return (mean, spread, sum(d > 0 for d in diffs), sum(d < 0 for d in diffs), len(diffs))


def held_rate(rates: dict[str, tuple[int, int]]) -> float:
    """The held rate over all the episodes of one evaluation (``read_eval``'s rates)."""
    return sum(s for _, s in rates.values()) / sum(n for n, _ in rates.values())


def is_noise(mean: float, error: float) -> bool:
    """A gain within two standard errors: noise at this sample size."""
    return abs(mean) <= 2 * error


@click.command(context_settings={"help_option_names": ["-h", "--help"]})
@click.argument("evals", nargs=-1, required=True,
                type=click.Path(path_type=Path, file_okay=False))
def main(evals: tuple[Path, ...]) -> None:
    """Compare OTHER_EVALs with BASE_EVAL (the first), episode for episode."""
    if len(evals) < 2:
        raise click.UsageError("pass BASE_EVAL and at least one OTHER_EVAL")
    read = [read_eval(folder) for folder in evals]
    if all(endings for _, endings in read):  # (one without endings.csv: no column kept)
        read = [(rates, dict(endings)) for (rates, _), endings
                in zip(read, comparable_endings([e for _, e in read]), strict=True)]
    kept = [e for e in ENDINGS if all(e in endings for _, endings in read)]
    click.echo("| evaluation | episodes | held | " + " | ".join(kept[1:]) + " |")
    click.echo("|---|---:|---:|" + "---:|" * len(kept[1:]))
    for folder, (rates, endings) in zip(evals, read, strict=True):
        episodes = sum(n for n, _ in rates.values())
        held = held_rate(rates)
        cells = [f"{endings[e] / episodes:.3f}" for e in kept[1:]]
        click.echo(f"| {folder} | {episodes} | {held:.3f} | " + " | ".join(cells) + " |")
    base = read[0][0]
    for folder, (rates, _) in zip(evals[1:], read[1:], strict=True):
        mean, error, up, down, count = gain(base, rates)
        verdict = "inside the noise" if is_noise(mean, error) else "beyond two standard errors"
        click.echo(f"{folder} over {evals[0]}: {mean:+.3f} ± {error:.3f} by object ({count} "
                   f"objects: {up} up, {down} down): {verdict}")


if __name__ == "__main__":
    sys.exit(main())
