"""The one exception type geomprep raises for problems a user can fix (a command line shows it
with ``geomgrasp.cli.run_cli``)."""

from __future__ import annotations

from geomgrasp.errors import UserError


class GeomprepError(UserError):
    """A problem with the user's input or environment, stated in one line with its fix.

    The CLI prints ``error: <message>`` and exits with status 1, without a traceback, so the
    message must name what is wrong and what to do about it, e.g.
    ``unknown object 'knfe': run 'geomprep list' to see the available names``.
    """
