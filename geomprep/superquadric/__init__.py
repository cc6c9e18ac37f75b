"""Superquadric representation of an object: geometry, EMS fit, fit quality, the ``sq`` stage.

- :mod:`.geometry`: the (11,) parameter contract, inside-outside function, radial distance,
  surface sampling.
- :mod:`.fit`: robust recovery from surface points (EMS + the paper's surface term).
- :mod:`.quality`: mesh queries, two-sided distances and volume IoU of a fit against a mesh.
- :mod:`.stage`: ``fit_mesh``, what the pipeline's ``sq`` stage runs.
"""

from __future__ import annotations

from geomprep.superquadric.fit import MIN_POINTS, fit_superquadric
from geomprep.superquadric.geometry import (
    EPS_MAX,
    EPS_MIN,
    implicit,
    make_params,
    radial_distance,
    rotation_matrix,
    sample_surface,
    sample_surface_dense,
    to_canonical,
)
from geomprep.superquadric.quality import MeshOracle, fit_quality, volume_iou
from geomprep.superquadric.stage import fit_mesh

# Bump when the output for the same input changes (the pipeline's cache key uses it).
VERSION = 2

__all__ = [
    "EPS_MAX",
    "EPS_MIN",
    "MIN_POINTS",
    "VERSION",
    "MeshOracle",
    "fit_mesh",
    "fit_quality",
    "fit_superquadric",
    "implicit",
    "make_params",
    "radial_distance",
    "rotation_matrix",
    "sample_surface",
    "sample_surface_dense",
    "to_canonical",
    "volume_iou",
]
