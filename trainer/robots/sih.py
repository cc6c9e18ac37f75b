"""The Schunk SIH right hand, one part that every robot carrying it uses: its kinematics
(``sih_hand.md``), its MJCF built in code, and its drives (how the hand's share of an action
becomes actuator targets).

Collision geometry (``[robot] hand_geometry``): ``hulls`` (the default): each finger and thumb
link the convex hull of its published visual mesh (``sih_hulls.json`` beside this module; its
``source`` and ``about`` say where from and how), or ``capsules`` of the real link sizes (the
project's first hand, kept as a measured comparison), or ``tip-hulls``: hulls on the links that
touch (``TIP_LINKS``), capsules on the others.
The palm is a box either way (no palm mesh was readable). Every collision geom is tagged with the
``hand`` contact material (``geomgrasp.materials``). Frames: the palm body's frame is the SIH
palm frame, fingers along +z, palmar side +y. Fingers sit at their physical x (see the x-mirror
note below).

Drives (``[robot] hand_drive``): ``all-joints`` (the default, the authors' Isaac Gym scheme):
5 position actuators (``ACTUATORS``) on the leading joints plus one per follower joint
(``FOLLOWER_ACTUATORS``), each given its leader's target; or ``equalities``: the 5 actuators
only, the other joints following by 1:1 equality couplings (``COUPLINGS``). Action value -1
commands a DoF open, +1 closed.
"""

from __future__ import annotations

import functools
import json
from pathlib import Path

import mujoco
import numpy as np
import torch

from geomgrasp import materials
from trainer.assets.collision import BIT_HAND, BIT_OBJECT, BIT_STATIC
from trainer.config import RobotConfig

# --- Published kinematics (metres, radians), palm frame: fingers +z, palmar side +y ----------
# Fingers: name -> (physical x of the finger, MCP z, proximal length, distal length).
# The published XML writes the finger bodies at x = -(physical x) and mirrors the sites; the
# hinge axes are parallel to x so only the physical x (where the meshes are) matters.
FINGERS = {
    "if": (-0.0435, 0.141, 0.048, 0.041),
    "mf": (-0.0187, 0.141, 0.0525, 0.049),
    "rf": (0.0069, 0.134, 0.048, 0.041),
    "lf": (0.032, 0.1254, 0.0401, 0.034),
}
FINGER_RANGE = (-1.571, 0.0)  # flexion is negative about +x and curls toward +y
PAD_Y = 0.0175  # the fingertip sites sit on the palmar pad

# Thumb: base (rotation about z) -> inter (flexion about y) -> distal (flexion about y).
THUMB_BASE_POS = (-0.034, 0.019, 0.08)
THUMB_INTER_POS = (-0.024, 0.005, 0.001)
THUMB_DISTAL_POS = (-0.0391, 0.0, 0.0)
THUMB_TIP_POS = (-0.023, 0.0, 0.015)
THUMB_ROT_RANGE = (-1.571, 0.0)  # -1.571: opposed (thumb points toward +y)
THUMB_FLEX_RANGE = (0.0, 1.571)

PALM_KEYPOINT = (0.0, 0.018, 0.09)
"""The ``palm`` site (palm frame, m): the point a robot's hand-pose command moves."""
JOINT_DAMPING = 0.1
"""The authors' URDF's joint damping (N·m·s/rad; the dexterity MJCF's class default is 1.0);
``[robot] hand_joint_damping`` sets it."""
JOINT_ARMATURE = 0.01

JOINTS = (
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
"""Joint names in qpos order (the builder adds them in this order)."""
COUPLINGS = (
    ("th_distal", "th_flex"),
    ("if_distal", "if_proximal"),
    ("mf_distal", "mf_proximal"),
    ("rf_distal", "rf_proximal"),
    ("lf_proximal", "rf_proximal"),
    ("lf_distal", "rf_proximal"),
)
"""The 1:1 couplings: follower joint = leader joint."""
ACTUATORS = (
    ("a_th_rot", "th_rot", 0.0, -1.571),
    ("a_th_flex", "th_flex", 0.0, 1.571),
    ("a_if", "if_proximal", 0.0, -1.571),
    ("a_mf", "mf_proximal", 0.0, -1.571),
    ("a_rf_lf", "rf_proximal", 0.0, -1.571),
)
"""The 5 actuators: name, driven joint, value when "open" (action -1), when "closed" (+1)."""
FOLLOWER_ACTUATORS = tuple(
    (f"a_{follower}", follower, [a[1] for a in ACTUATORS].index(leader))
    for follower, leader in COUPLINGS
)
"""``all-joints`` only: name, driven follower joint, index into ``ACTUATORS`` of its leader."""
FINGERTIPS = ("tip_th", "tip_if", "tip_mf", "tip_rf", "tip_lf")
"""Fingertip sites in observation order (thumb, index, middle, ring, little)."""

# --- Collision geometry (our estimates of the link sizes) -----------------------------------
FINGER_RADIUS = 0.0105
FINGER_AXIS_Y = 0.006
"""Finger capsules run along z at this y, so their pad reaches y = 0.0165, next to the sites."""
THUMB_RADIUS = 0.0095
PALM_HALF = (0.048, 0.018, 0.0625)
PALM_CENTER = (-0.006, 0.008, 0.0625)
HAND_RGBA = (0.25, 0.25, 0.28, 1.0)

HULLS_FILE = Path(__file__).with_name("sih_hulls.json")
"""The link hulls (package data): vertices (m) in each link body's frame, the body at its
physical x, so they go into the bodies built here unchanged (no ``xml_frame_shift_m``)."""
HULL_OF = {
    **{f"{f}_{part}": f"{f}_{part}" for f in FINGERS for part in ("proximal", "distal")},
    "th_proximal": "th_proximal_without_shaft",
    "th_inter": "th_inter",
    "th_distal": "th_distal",
}
"""Body -> hull entry. The thumb base uses the hull without its rotation shaft: the shaft turns
inside the palm, and the full hull spans a wedge of air between the housing and the shaft's end,
partly outside the palm box (sih_hand.md section 10, "Thumb shaft")."""

TIP_LINKS = ("if_distal", "mf_distal", "rf_distal", "lf_distal", "th_inter", "th_distal")
"""The links that take ~97 % of the hand's contacts with objects and fixtures in a trained
policy's grasps (the proximal links: < 0.1 per env, results/bench-step-phases-2026-11-29/): the
hulls of ``hand_geometry = "tip-hulls"``; the other links are capsules."""


@functools.cache
def hull_vertices() -> dict[str, np.ndarray]:
    """Body name -> (V, 3) hull vertices (m) in that body's frame, for the 11 hand links."""
    data = json.loads(HULLS_FILE.read_text())
    entries = {**data["links"], **data["alternatives"]}
    return {body: np.asarray(entries[hull]["vertices"], dtype=np.float64)
            for body, hull in HULL_OF.items()}


def _capsule(
    spec: mujoco.MjSpec,
    body: mujoco.MjsBody,
    start: tuple[float, ...],
    end: tuple[float, ...],
    radius: float,
    mass: float,
) -> None:
    geom = body.add_geom()
    geom.type = mujoco.mjtGeom.mjGEOM_CAPSULE
    geom.fromto = np.concatenate([start, end])
    geom.size = [radius, 0, 0]
    geom.mass = mass
    _hand_contact(spec, geom)


def _hull(spec: mujoco.MjSpec, body: mujoco.MjsBody, mass: float) -> None:
    """The link's hull (``hull_vertices``) as a mesh geom of ``mass`` (kg) at the body origin."""
    mesh = spec.add_mesh()
    mesh.name = f"hull_{body.name}"
    mesh.uservert = hull_vertices()[body.name].ravel()
    geom = body.add_geom()
    geom.type = mujoco.mjtGeom.mjGEOM_MESH
    geom.meshname = mesh.name
    geom.mass = mass
    _hand_contact(spec, geom)


def _hand_contact(spec: mujoco.MjSpec, geom: mujoco.MjsGeom) -> None:
    geom.contype = BIT_HAND
    geom.conaffinity = BIT_STATIC | BIT_OBJECT | BIT_HAND
    materials.tag(spec, geom, "hand")
    geom.rgba = HAND_RGBA


def _hinge(
    body: mujoco.MjsBody,
    name: str,
    axis: tuple[float, float, float],
    limits: tuple[float, float],
    damping: float,
) -> None:
    joint = body.add_joint()
    joint.name = name
    joint.type = mujoco.mjtJoint.mjJNT_HINGE
    joint.axis = axis
    joint.range = limits
    joint.limited = mujoco.mjtLimited.mjLIMITED_TRUE
    joint.damping = (damping, 0.0, 0.0)
    joint.armature = JOINT_ARMATURE


def _site(body: mujoco.MjsBody, name: str, pos: tuple[float, ...]) -> None:
    site = body.add_site()
    site.name = name
    site.pos = pos
    site.size = [0.004, 0, 0]
    site.rgba = (1.0, 0.3, 0.1, 1.0)
    site.group = 4


def add_sih_hand(
    spec: mujoco.MjSpec,
    parent: mujoco.MjsBody,
    pos: tuple[float, float, float],
    quat: tuple[float, float, float, float],
    robot: RobotConfig,
) -> mujoco.MjsBody:
    """Add the hand's palm as a child of ``parent`` at ``pos``/``quat`` (wxyz); return the palm.

    Adds 11 hinge joints (``JOINTS``), 5 position actuators (``ACTUATORS``) and either 6
    coupling equalities or (``robot.hand_drive = "all-joints"``) 6 more position actuators
    (``FOLLOWER_ACTUATORS``, after the 5), the fingertip sites (``FINGERTIPS``), a ``palm`` site
    at the palm keypoint, and the published self-collision exclusions. Its collision geoms are
    tagged ``hand``: the scene applies the hand's contact material
    (``geomgrasp.materials.apply_materials``). ``robot.hand_geometry`` picks capsules, hulls or
    both (``TIP_LINKS``) for the links, ``robot.hand_joint_damping`` the joints' damping.
    """
    hull_links = {"hulls": set(HULL_OF), "tip-hulls": set(TIP_LINKS)}.get(robot.hand_geometry,
                                                                            set())
    damping = robot.hand_joint_damping

    def link(
        parent: mujoco.MjsBody,
        name: str,
        pos: tuple[float, ...],
        joint: str,
        axis: tuple[float, float, float],
        limits: tuple[float, float],
        mass: float,
        capsule: tuple[tuple[float, ...], tuple[float, ...], float],
    ) -> mujoco.MjsBody:
        """A gravity-compensated child body turning on one hinge at its origin, with its
        collision geom: its hull, or the capsule (start, end, radius)."""
        body = parent.add_body()
        body.name = name
        body.pos = pos
        body.gravcomp = 1.0
        _hinge(body, joint, axis, limits, damping)
        if name in hull_links:
            _hull(spec, body, mass)
        else:
            _capsule(spec, body, *capsule, mass)
        return body

    palm = parent.add_body()
    palm.name = "palm"
    palm.pos = pos
    palm.quat = quat
    palm.gravcomp = 1.0
    box = palm.add_geom()
    box.type = mujoco.mjtGeom.mjGEOM_BOX
    box.size = PALM_HALF
    box.pos = PALM_CENTER
    box.mass = 0.35
    _hand_contact(spec, box)
    _site(palm, "palm", PALM_KEYPOINT)

    th_base = link(
        palm, "th_proximal", THUMB_BASE_POS, "th_rot", (0.0, 0.0, 1.0), THUMB_ROT_RANGE, 0.02,
        ((0.0, 0.0, 0.0), THUMB_INTER_POS, THUMB_RADIUS),
    )
    th_inter = link(
        th_base, "th_inter", THUMB_INTER_POS, "th_flex", (0.0, 1.0, 0.0), THUMB_FLEX_RANGE, 0.02,
        ((0.0, 0.0, 0.0), THUMB_DISTAL_POS, THUMB_RADIUS),
    )
    th_distal = link(
        th_inter, "th_distal", THUMB_DISTAL_POS, "th_distal", (0.0, 1.0, 0.0), THUMB_FLEX_RANGE,
        0.015, ((0.0, 0.0, 0.003), (-0.02, 0.0, 0.006), THUMB_RADIUS),
    )
    _site(th_distal, "tip_th", THUMB_TIP_POS)
    # The published list, plus palm <-> th_inter: our palm box is coarser than the palm mesh
    # and touches the thumb's middle link when the thumb is abducted.
    excluded = [("palm", "th_proximal"), ("th_proximal", "th_distal"), ("palm", "th_inter")]

    for finger, (x, z_mcp, proximal_len, distal_len) in FINGERS.items():
        name = f"{finger}_proximal"
        proximal = link(
            palm, name, (x, 0.0, z_mcp), name, (1.0, 0.0, 0.0), FINGER_RANGE, 0.02,
            ((0.0, FINGER_AXIS_Y, 0.0), (0.0, FINGER_AXIS_Y, proximal_len), FINGER_RADIUS),
        )
        name = f"{finger}_distal"
        distal = link(
            proximal, name, (0.0, 0.0, proximal_len), name, (1.0, 0.0, 0.0), FINGER_RANGE, 0.015,
            ((0.0, FINGER_AXIS_Y, 0.0), (0.0, FINGER_AXIS_Y, distal_len - 0.008), FINGER_RADIUS),
        )
        _site(distal, f"tip_{finger}", (0.0, PAD_Y, distal_len))
        excluded += [("palm", proximal.name), (proximal.name, distal.name)]

    for body1, body2 in excluded:
        exclude = spec.add_exclude()
        exclude.bodyname1 = body1
        exclude.bodyname2 = body2
    all_joints = robot.hand_drive == "all-joints"
    if not all_joints:
        for follower, leader in COUPLINGS:
            eq = spec.add_equality()
            eq.name = f"couple_{follower}"
            eq.type = mujoco.mjtEq.mjEQ_JOINT
            eq.name1 = follower
            eq.name2 = leader
            eq.data[:5] = [0.0, 1.0, 0.0, 0.0, 0.0]
    drives = [(name, joint, (open_value, closed_value))
              for name, joint, open_value, closed_value in ACTUATORS]
    if all_joints:
        drives += [(name, joint, ACTUATORS[leader][2:])
                   for name, joint, leader in FOLLOWER_ACTUATORS]
    for name, joint, ends in drives:
        act = spec.add_actuator()
        act.name = name
        act.target = joint
        act.trntype = mujoco.mjtTrn.mjTRN_JOINT
        act.ctrlrange = tuple(sorted(ends))
        act.ctrllimited = mujoco.mjtLimited.mjLIMITED_TRUE
        act.forcerange = (-robot.hand_forcerange, robot.hand_forcerange)
        act.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE
        act.set_to_position(kp=robot.hand_kp)
    return palm


class SIHHand:
    """The hand's drives in a compiled model, batched in torch: which qpos entries are its
    joints, which actuators drive it, and how the hand's share of an action (E, 5) in [-1, 1]
    becomes actuator targets (and back, for holding a grasp).

    After ``index``: ``qpos`` (11,) qpos addresses of ``JOINTS``; ``actuators`` (5,) actuator
    ids of ``ACTUATORS``; ``open`` and ``closed`` (5,) their targets (rad) at action -1 and +1;
    ``followers`` (F,) the ids of ``FOLLOWER_ACTUATORS`` (F = 6 with ``all-joints``, else 0)
    and ``follower_leader`` (F,) the index into the 5 whose target each copies.
    """

    action_dim = len(ACTUATORS)

    def __init__(self, robot: RobotConfig) -> None:
        self.cfg = robot

    def build(
        self,
        spec: mujoco.MjSpec,
        parent: mujoco.MjsBody,
        pos: tuple[float, float, float],
        quat: tuple[float, float, float, float],
    ) -> mujoco.MjsBody:
        """``add_sih_hand`` with this robot's servo settings."""
        return add_sih_hand(spec, parent, pos, quat, self.cfg)

    def index(self, model: mujoco.MjModel, device: torch.device) -> None:
        """Find the hand's joints and actuators in ``model`` (the same in every env's model)."""
        self.qpos = torch.tensor(
            [int(model.joint(n).qposadr[0]) for n in JOINTS], device=device
        )
        self.actuators = torch.tensor([model.actuator(a[0]).id for a in ACTUATORS], device=device)
        self.open = torch.tensor([a[2] for a in ACTUATORS], device=device)
        self.closed = torch.tensor([a[3] for a in ACTUATORS], device=device)
        followers = FOLLOWER_ACTUATORS if self.cfg.hand_drive == "all-joints" else ()
        self.followers = torch.tensor([model.actuator(f[0]).id for f in followers],
                                      dtype=torch.long, device=device)
        self.follower_leader = torch.tensor([f[2] for f in followers], dtype=torch.long,
                                            device=device)

    def _write(self, ctrl: torch.Tensor, hand: torch.Tensor) -> None:
        """Set the 5 servo targets ``hand`` (..., 5) in ``ctrl`` (..., nu), in place, and each
        follower actuator's target to its leader's."""
        ctrl[..., self.actuators] = hand
        ctrl[..., self.followers] = hand[..., self.follower_leader]

    def home(self, qpos: torch.Tensor, ctrl: torch.Tensor) -> None:
        """Write the home hand into one state's qpos (nq,) and ctrl (nu,): open, with the
        thumb opposed (its rotation closed, joint and target)."""
        hand = self.open.clone()
        hand[0] = self.closed[0]  # thumb rotation: opposed
        self._write(ctrl, hand)
        qpos[self.qpos[0]] = hand[0]

    @property
    def low(self) -> torch.Tensor:
        """(5,) the lower end of each actuator's target range (rad)."""
        return torch.minimum(self.open, self.closed)

    @property
    def high(self) -> torch.Tensor:
        """(5,) the upper end of each actuator's target range (rad)."""
        return torch.maximum(self.open, self.closed)

    def command(self, action: torch.Tensor, ctrl: torch.Tensor) -> torch.Tensor:
        """A copy of ``ctrl`` (E, nu) with the hand's targets set from its actions (E, 5) in
        [-1, 1]: ``absolute``, the target between open (-1) and closed (+1); ``relative``, the
        last target moved toward closed by ``hand_relative_step`` * action (toward open for a
        negative action), kept within the range."""
        if self.cfg.hand_action == "relative":
            # +1 moves toward closed, -1 toward open, as in the absolute mode.
            step = self.cfg.hand_relative_step * action * torch.sign(self.closed - self.open)
            hand = (ctrl[:, self.actuators] + step).clamp(self.low, self.high)
        else:
            hand = self.open + 0.5 * (action + 1.0) * (self.closed - self.open)
        ctrl = ctrl.clone()
        self._write(ctrl, hand)
        return ctrl

    def targets(self, ctrl: torch.Tensor) -> torch.Tensor:
        """(E, 5) the servo targets in ``ctrl`` (E, nu) on the absolute actions' scale: -1 open,
        +1 closed."""
        span = self.closed - self.open
        return 2.0 * (ctrl[:, self.actuators] - self.open) / span - 1.0

    def action(self, ctrl: torch.Tensor) -> torch.Tensor:
        """(E, 5) the hand actions that keep the targets in ``ctrl`` (E, nu): those targets'
        values (``absolute``), or no change (``relative``)."""
        if self.cfg.hand_action == "relative":
            return torch.zeros_like(ctrl[:, self.actuators])
        return self.targets(ctrl)
