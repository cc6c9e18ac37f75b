"""Download YCB google_16k scans into the raw store: fetch each archive, extract it safely,
install the object."""

from __future__ import annotations

import os
import shutil
import tarfile
import zlib
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path, PurePosixPath

from geomprep import ycb
from geomprep.download import download_file
from geomprep.errors import GeomprepError
from geomprep.masses import check_density, mass_fields, read_masses
from geomprep.rawstore import complete_objects, install_object

DOWNLOADS_DIR = ".downloads"


def _check_members(archive: Path, members: Iterable[tarfile.TarInfo]) -> None:
    """Reject archive members that are links, devices or paths outside the extraction dir."""
    for member in members:
        path = PurePosixPath(member.name)
        if path.is_absolute() or ".." in path.parts or member.name.startswith("\\"):
            raise GeomprepError(
                f"unsafe path {member.name!r} in {archive}: refusing to extract; "
                "check the download source (--url)"
            )
        if not (member.isfile() or member.isdir()):
            raise GeomprepError(
                f"archive member {member.name!r} in {archive} is a link or special file: "
                "refusing to extract; check the download source (--url)"
            )


def _populate_from_archive(archive: Path, name: str) -> Callable[[Path], str]:
    """Populate step extracting a YCB ``*_google_16k.tgz`` and keeping ``google_16k/``."""

    def populate(stage: Path) -> str:
        unpack = stage / ".unpack"
        try:
            with tarfile.open(archive, "r:gz") as tar:
                members = tar.getmembers()
                _check_members(archive, members)
                # filter="data" is a second guard (absolute paths, links, device files, modes).
                tar.extractall(unpack, members=members, filter="data")
        except (tarfile.TarError, EOFError, zlib.error, OSError) as exc:
            raise GeomprepError(
                f"cannot extract {archive} ({exc}): check free disk space and rerun "
                "(the archive is downloaded again)"
            ) from None
        ycb_dir = unpack / name / "google_16k"
        if not (ycb_dir / "textured.obj").is_file():
            raise GeomprepError(
                f"{archive} does not hold {name}/google_16k/textured.obj: "
                "check the download source (--url)"
            )
        os.rename(ycb_dir, stage / "google_16k")
        shutil.rmtree(unpack)
        return ycb.MESH

    return populate


def fetch_ycb(
    raw_dir: Path,
    names: Sequence[str] | None = None,
    *,
    base_url: str = ycb.BASE_URL,
    masses_csv: Path | None = None,
    density_kg_m3: float = 500.0,
    retries: int = 3,
    timeout_s: float = 60.0,
    force: bool = False,
    progress: bool = True,
) -> list[str]:
    """Download YCB google_16k scans into the raw store; returns the sorted names now present.

    Each ``{base_url}{name}_google_16k.tgz`` goes to ``raw_dir/.downloads`` (resumable ``.part``,
    checked against Content-Length and an MD5 ETag), is extracted safely and moved into
    ``raw_dir/<name>/google_16k/``. ``retries`` is the number of extra attempts per file after
    the first; ``timeout_s`` the socket timeout in seconds. Masses (kg) come from
    ``masses_csv`` where listed, otherwise ``density_kg_m3`` (kg/m^3) is recorded. Complete
    objects are skipped unless ``force``. ``names`` None or empty means all ycb.OBJECTS.
    """
    raw_dir = Path(raw_dir)
    density = check_density(density_kg_m3)
    if retries < 0:
        raise GeomprepError(f"invalid retries {retries}: pass 0 or more")
    if isinstance(names, str):
        names = [names]  # one name, not a sequence of characters
    if not names:
        selected = list(ycb.OBJECTS)
    else:
        selected = sorted(set(names))
        unknown = [name for name in selected if name not in ycb.OBJECTS]
        if unknown:
            raise GeomprepError(
                f"unknown YCB object(s) {', '.join(map(repr, unknown))}: "
                "run 'geomprep list --available' to see the valid names"
            )
    masses = read_masses(Path(masses_csv)) if masses_csv is not None else None
    if not base_url.endswith("/"):
        base_url += "/"
    downloads = raw_dir / DOWNLOADS_DIR
    done = set(complete_objects(raw_dir))
    for name in selected:
        if name in done and not force:
            continue
        file_name = ycb.archive_name(name)
        url = f"{base_url}{file_name}"
        archive = downloads / file_name
        # A leftover verified archive may predate a changed server copy; only trust fresh ones.
        archive.unlink(missing_ok=True)
        download_file(
            url, archive, retries=retries, timeout_s=timeout_s, progress=progress, desc=name
        )
        mass_kg, density_field = mass_fields(name, masses, density)
        try:
            install_object(
                raw_dir,
                name,
                _populate_from_archive(archive, name),
                mass_kg=mass_kg,
                density_kg_m3=density_field,
                origin=f"ycb-server: {url}",
            )
        finally:
            # Installed objects do not need their archive; a bad one must be downloaded again.
            archive.unlink(missing_ok=True)
    return sorted(selected)
