"""The one exception the trainer raises for bad input: its message names the problem and the fix."""


class TrainerError(Exception):
    """A user-facing error; the CLI prints its message on one line and exits non-zero."""
