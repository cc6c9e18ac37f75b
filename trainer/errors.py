"""The one exception the trainer raises for bad input: its message names the problem and the fix."""

from geomgrasp.errors import UserError


class TrainerError(UserError):
    """A user-facing error; the CLI prints its message on one line and exits non-zero."""
