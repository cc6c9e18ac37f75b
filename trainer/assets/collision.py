"""Collision bitmasks of the scene's parts.

A pair of geoms collides when (contype_a & conaffinity_b) | (contype_b & conaffinity_a). The
arm does not collide with the robot itself (its DH capsules overlap at the joints); the hand
collides with itself except for the published exclusions (``trainer.robots.sih``).
"""

from __future__ import annotations

BIT_STATIC, BIT_OBJECT, BIT_ARM, BIT_HAND = 1, 2, 4, 8
