"""How an imported object's mass is given: a ``masses.csv`` row (kg), else a density (kg/m^3)."""

from __future__ import annotations

import csv
import math
from pathlib import Path

from geomprep.errors import GeomprepError
from geomprep.rawstore import name_problem

HEADER = ["object", "mass_kg"]


def read_masses(csv_path: Path) -> dict[str, float]:
    """Read a CSV with header ``object,mass_kg`` into {object name: mass in kg}.

    Blank lines are ignored; a malformed row, an invalid or duplicate name or a mass that is
    not a finite positive number raises GeomprepError naming the file and line.
    """
    csv_path = Path(csv_path)
    fix = "expected a CSV with header 'object,mass_kg' and one 'name,mass' row per object"
    try:
        text = csv_path.read_text(encoding="utf-8-sig")  # tolerate a BOM from spreadsheets
    except (OSError, UnicodeDecodeError) as exc:
        reason = exc.strerror if isinstance(exc, OSError) else "not UTF-8 text"
        raise GeomprepError(f"cannot read masses file {csv_path}: {reason}: {fix}") from None
    rows = [
        (lineno, row)
        for lineno, row in enumerate(csv.reader(text.splitlines()), start=1)
        if any(cell.strip() for cell in row)
    ]
    if not rows or [cell.strip() for cell in rows[0][1]] != HEADER:
        raise GeomprepError(f"{csv_path}: missing header 'object,mass_kg': {fix}")
    masses: dict[str, float] = {}
    for lineno, row in rows[1:]:
        where = f"{csv_path}:{lineno}"
        if len(row) != 2:
            raise GeomprepError(f"{where}: expected 2 columns, got {len(row)}: {fix}")
        name, mass_text = row[0].strip(), row[1].strip()
        problem = name_problem(name)
        if problem is not None:
            raise GeomprepError(
                f"{where}: invalid object name {name!r}: it {problem}: "
                "use the object's file or folder name"
            )
        try:
            mass = float(mass_text)
        except ValueError:
            mass = math.nan
        if not math.isfinite(mass) or mass <= 0:
            raise GeomprepError(
                f"{where}: mass of '{name}' is {mass_text!r}: give a positive number of kg"
            )
        if name in masses:
            raise GeomprepError(f"{where}: '{name}' is listed twice: keep one row per object")
        masses[name] = mass
    return masses


def check_density(density_kg_m3: float) -> float:
    """Return the density (kg/m^3) if it is a finite positive number, else raise."""
    try:
        value = float(density_kg_m3)
    except (TypeError, ValueError):
        value = math.nan
    if not math.isfinite(value) or value <= 0:
        raise GeomprepError(
            f"invalid density {density_kg_m3!r} kg/m^3: pass a positive number (e.g. 500)"
        )
    return value


def mass_fields(
    name: str, masses: dict[str, float] | None, density_kg_m3: float
) -> tuple[float | None, float | None]:
    """(mass_kg, density_kg_m3) for source.json: the listed mass if any, else the density."""
    if masses is not None and name in masses:
        return masses[name], None
    return None, density_kg_m3
