"""The one exception type geomprep raises for problems a user can fix, and how a command line
shows such problems (``run_cli``, shared with the trainer's CLI)."""

from __future__ import annotations

import sys

import click


class GeomprepError(Exception):
    """A problem with the user's input or environment, stated in one line with its fix.

    The CLI prints ``error: <message>`` and exits with status 1, without a traceback, so the
    message must name what is wrong and what to do about it, e.g.
    ``unknown object 'knfe': run 'geomprep list' to see the available names``.
    """


def run_cli(group: click.Group, user_errors: tuple[type[Exception], ...]) -> None:
    """Run a click ``group``: a ``user_errors`` exception becomes ``error: <message>`` and exit
    status 1, Ctrl-C ``aborted`` and 130, a usage error click's own message."""
    try:
        group.main(standalone_mode=False)
    except user_errors as exc:
        click.echo(f"error: {exc}", err=True)
        sys.exit(1)
    except click.exceptions.Abort:
        click.echo("aborted", err=True)
        sys.exit(130)
    except click.ClickException as exc:
        exc.show()
        sys.exit(exc.exit_code)
