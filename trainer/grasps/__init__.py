"""Scripted grasp families: open-loop scripts that show what the hand and the physics can
lift, each trial's outcome told from its recorded trajectory.

* ``top`` (``TopGrasp``): palm down, close across the target's narrowest width, lift; the demo
  behind ``trainer demo``.
* ``pinch`` (``Pinch``): thumb tip against index tip at table height, for small and flat
  objects.
* ``slide`` (``SlideGrasp``): palm up, fingers slid to a flat object's rim and curled under
  it; tips the plate, lifts nothing yet.
* ``searched`` (``keyframes.KeyframeGrasp``): per object, a keyframe grasp found by the
  cross-entropy search of ``search.py`` (``trainer grasp-search``), stored per object and hand
  in the data directory, the shipped ones in ``searched.json`` (``searched.py``).

``FAMILIES`` names them with their measured variants (``families.py``); ``run_scripted_grasp``
/ ``record_grasp`` run any of them (``runner.py``); ``outcomes.classify`` tells lifted / dropped
/ no_grip / pushed; ``measure`` runs N trials per object and gives one row per object;
``trials.run_trials`` runs them over variants, seeds and configurations (``trainer grasp`` and
``bench/graspability.py`` print and write them).
"""

from trainer.grasps.families import FAMILIES, TABLE1_OBJECTS, Family, Variant, family, measure
from trainer.grasps.families import variants as family_variants
from trainer.grasps.outcomes import OUTCOMES, classify, outcome_rows
from trainer.grasps.pinch import Pinch
from trainer.grasps.runner import (
    GraspScript,
    GraspTrajectory,
    TrajectoryRecorder,
    keypoint_distances,
    record_grasp,
    run_scripted_grasp,
)
from trainer.grasps.slide import SlideGrasp
from trainer.grasps.top import TopGrasp, grasp_frame

__all__ = [
    "FAMILIES", "OUTCOMES", "TABLE1_OBJECTS", "Family", "GraspScript", "GraspTrajectory",
    "Pinch", "SlideGrasp", "TopGrasp", "TrajectoryRecorder", "Variant", "classify", "family",
    "family_variants", "grasp_frame", "keypoint_distances", "measure", "outcome_rows",
    "record_grasp", "run_scripted_grasp",
]
