"""The base of the user-facing errors of both packages (``GeomprepError``, ``TrainerError``)."""

from __future__ import annotations


class UserError(Exception):
    """A problem with the user's input or environment, stated in one line with its fix: a
    command line prints ``error: <message>`` and exits with status 1, without a traceback."""
