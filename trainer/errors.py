"""The one exception the trainer raises for bad input (its message names the problem and the fix),
and its one warning category for a setup that runs but is probably not what was meant."""

from geomgrasp.errors import UserError


class TrainerError(UserError):
    """A user-facing error; the CLI prints its message on one line and exits non-zero."""


class TrainerWarning(UserWarning):
    """A setup that runs but is probably not what was meant; the CLI prints its message on one
    ``warning:`` line (no source location: the message names the setting to change)."""

