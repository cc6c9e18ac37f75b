"""Short names of a task as the policy sees it, shared by ``trainer eval``'s tables and the
report: ``sq`` (lift), ``bin5-bbox``, ``bin5-bbox+ctx``."""

from __future__ import annotations


def task_name(task: str, bin_objects: int | None = None) -> str:
    """``lift``, or ``binN`` for the bin task with N objects per bin."""
    return f"{task}{bin_objects}" if task == "bin" and bin_objects is not None else task


def view_name(representation: str, context: str = "none") -> str:
    """What the policy sees: the representation, ``+ctx`` when it also sees the context."""
    return representation if context == "none" else f"{representation}+ctx"


def task_label(
    task: str, representation: str, bin_objects: int | None = None, context: str = "none"
) -> str:
    """A short label of a task as the policy sees it: ``sq`` (lift), ``bin5-bbox``,
    ``bin5-bbox+ctx``."""
    view = view_name(representation, context)
    return view if task == "lift" else f"{task_name(task, bin_objects)}-{view}"
