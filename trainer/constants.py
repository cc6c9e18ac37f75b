"""Kinematic facts of the robot, in metres and radians (sources in each block).

Everything here is a published number; everything we chose (gains, friction, geometry sizes
that are estimates) lives in ``trainer/config.py`` instead.
"""

from __future__ import annotations

import math

# --- UR5e: standard DH parameters published by Universal Robots -----------------------------
# T_i = RotZ(q_i) · TransZ(d_i) · TransX(a_i) · RotX(alpha_i); joint i turns about z_{i-1}.
UR5E_DH_D = (0.1625, 0.0, 0.0, 0.1333, 0.0997, 0.0996)
UR5E_DH_A = (0.0, -0.425, -0.3922, 0.0, 0.0, 0.0)
UR5E_DH_ALPHA = (math.pi / 2, 0.0, 0.0, math.pi / 2, -math.pi / 2, 0.0)
UR5E_JOINT_RANGE = ((-2 * math.pi, 2 * math.pi),) * 2 + ((-math.pi, math.pi),) + (
    (-2 * math.pi, 2 * math.pi),
) * 3
UR5E_JOINTS = (
    "shoulder_pan",
    "shoulder_lift",
    "elbow",
    "wrist_1",
    "wrist_2",
    "wrist_3",
)
# Link masses (kg) of the UR5e URDF, shoulder .. wrist_3 (the base is fixed).
UR5E_LINK_MASS = (3.761, 8.058, 2.846, 1.37, 1.3, 0.365)
# The authors' UR5+SIH start configuration (thumb opposed, hand above the table).
UR5E_HOME = (0.6985, -1.4106, 1.2932, 0.1174, 0.6983, 1.5708)

# Flange (tool0) -> SIH palm frame, from the authors' URDF: tool0 -> optoforce z -0.0065,
# optoforce -> palm z +0.04875 with yaw +pi/2.
FLANGE_TO_PALM_POS = (0.0, 0.0, -0.0065 + 0.04875)
FLANGE_TO_PALM_YAW = math.pi / 2

# --- Schunk SIH right hand (sih_hand.md), palm frame: fingers +z, palmar side +y -------------
# Fingers: name -> (physical x of the finger, MCP z, proximal length, distal length).
# The published XML writes the finger bodies at x = -(physical x) and mirrors the sites; the
# hinge axes are parallel to x so only the physical x (where the meshes are) matters.
SIH_FINGERS = {
    "if": (-0.0435, 0.141, 0.048, 0.041),
    "mf": (-0.0187, 0.141, 0.0525, 0.049),
    "rf": (0.0069, 0.134, 0.048, 0.041),
    "lf": (0.032, 0.1254, 0.0401, 0.034),
}
SIH_FINGER_RANGE = (-1.571, 0.0)  # flexion is negative about +x and curls toward +y
SIH_PAD_Y = 0.0175  # the fingertip sites sit on the palmar pad

# Thumb: base (rotation about z) -> inter (flexion about y) -> distal (flexion about y).
SIH_THUMB_BASE_POS = (-0.034, 0.019, 0.08)
SIH_THUMB_INTER_POS = (-0.024, 0.005, 0.001)
SIH_THUMB_DISTAL_POS = (-0.0391, 0.0, 0.0)
SIH_THUMB_TIP_POS = (-0.023, 0.0, 0.015)
SIH_THUMB_ROT_RANGE = (-1.571, 0.0)  # -1.571: opposed (thumb points toward +y)
SIH_THUMB_FLEX_RANGE = (0.0, 1.571)

SIH_PALM_KEYPOINT = (0.0, 0.018, 0.09)
SIH_JOINT_DAMPING = 1.0
SIH_JOINT_ARMATURE = 0.01

# Joint names in qpos order (the builder adds them in this order).
SIH_JOINTS = (
    "th_rot",
    "th_flex",
    "th_distal",
    "if_proximal",
    "if_distal",
    "mf_proximal",
    "mf_distal",
    "rf_proximal",
    "rf_distal",
    "lf_proximal",
    "lf_distal",
)
# The 1:1 couplings: follower joint = leader joint.
SIH_COUPLINGS = (
    ("th_distal", "th_flex"),
    ("if_distal", "if_proximal"),
    ("mf_distal", "mf_proximal"),
    ("rf_distal", "rf_proximal"),
    ("lf_proximal", "rf_proximal"),
    ("lf_distal", "rf_proximal"),
)
# The 5 actuators: name, driven joint, value when "open" (action -1), when "closed" (action +1).
SIH_ACTUATORS = (
    ("a_th_rot", "th_rot", 0.0, -1.571),
    ("a_th_flex", "th_flex", 0.0, 1.571),
    ("a_if", "if_proximal", 0.0, -1.571),
    ("a_mf", "mf_proximal", 0.0, -1.571),
    ("a_rf_lf", "rf_proximal", 0.0, -1.571),
)
# Fingertip sites in observation order (thumb, index, middle, ring, little).
FINGERTIPS = ("tip_th", "tip_if", "tip_mf", "tip_rf", "tip_lf")

# Collision bitmasks: a pair collides when (contype_a & conaffinity_b) | (contype_b &
# conaffinity_a). The arm does not collide with the robot itself (its DH capsules overlap at
# the joints); the hand collides with itself except for the published exclusions.
BIT_STATIC, BIT_OBJECT, BIT_ARM, BIT_HAND = 1, 2, 4, 8
