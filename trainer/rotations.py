"""Deprecated shim: the rotations live in ``geomprep.rotations``; import from there."""
from geomprep.rotations import *  # noqa: F403
from geomprep.rotations import __all__  # noqa: F401
