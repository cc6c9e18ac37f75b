"""How both command lines (``geomprep``, ``trainer``) show problems: one line, never a traceback."""

from __future__ import annotations

import sys

import click


def run_cli(group: click.Group, user_errors: tuple[type[Exception], ...]) -> None:
    """Run a click ``group``: a ``user_errors`` exception becomes ``error: <message>`` and exit
    status 1, Ctrl-C ``aborted`` and 130, a usage error click's own message, a file system
    error (OSError: unwritable path, full disk) one ``error:`` line and 1, never a traceback."""
    try:
        group.main(standalone_mode=False)
    except user_errors as exc:
        click.echo(f"error: {exc}", err=True)
        sys.exit(1)
    except click.exceptions.Abort:
        click.echo("aborted", err=True)
        sys.exit(130)
    except OSError as exc:  # the data directory or an output path is not writable, the disk full
        click.echo(
            f"error: {_os_error_text(exc)}: check the path, its permissions and free disk space",
            err=True,
        )
        sys.exit(1)
    except click.ClickException as exc:
        exc.show()
        sys.exit(exc.exit_code)


def _os_error_text(exc: OSError) -> str:
    """``No such file or directory: /x/y`` rather than ``[Errno 2] ...: '/x/y'``."""
    if exc.filename is None:
        return str(exc)
    target = f"{exc.filename} -> {exc.filename2}" if exc.filename2 else str(exc.filename)
    return f"{exc.strerror or exc}: {target}"
