"""Every knob of the simulation and the task, as data (frozen dataclasses with defaults).

``load_env_config`` overrides any field from a TOML file, one section per dataclass::

    [reward]
    c3 = 0.0
    [physics]
    substeps = 12

and ``--set section.key=value`` any one from the command line (``trainer.config_keys``).

Each key declares its default and the values it accepts (``bounded``), and, for the keys of the
paper's method, what the paper states (``bounded(..., paper=...)``); a key without it is this
project's own. Its docstring says in a few lines what it does and links the results/ folders
that measured it; the longer history is in results/config-evidence.md. ``trainer config`` lists
every key and writes docs/config.md.

Physics choices (documented here because they decide whether a grasp holds): MuJoCo's
``implicitfast`` integrator, elliptic friction cones with ``condim = 4`` (torsional friction
keeps a pinched object from spinning out), sliding friction 1.0 for fingers and objects and 0.8
for the table, the arm and hand gravity-compensated (the arm's PD loop tracks targets rather than
fighting its own weight), and hand position servos limited to the real SIH's 0.75 N·m.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

from geomgrasp import materials
from geomgrasp.config_schema import (
    Checked,
    bounded,
    build_dataclass,
    field_error,
    read_toml,
    toml_value,
)
from geomgrasp.materials import ContactMaterial
from trainer.errors import TrainerError

ACTION_DIM = 11
"""6 hand-pose deltas, then 5 hand DoF targets (thumb rotation, thumb flexion, index, middle,
ring + little), each in [-1, 1]."""
REPRESENTATIONS = ("com", "sdf", "bbox", "sq", "pc32", "pc128", "pc512")
TASKS = {"lift": "sq", "bin": "bbox"}
"""The tasks (``trainer/tasks/``) and the object representation each uses by default: the paper
lifts single objects (its comparison of representations) and picks the target out of a bin seen
through its bounding box."""
BACKENDS = ("cpu", "warp")
"""Physics backends (``trainer/sim/``): ``cpu`` is MuJoCo's C ``rollout`` on a thread pool;
``warp`` is MuJoCo Warp (every env a world of one batched model; on ``--device cuda`` a GPU,
on ``cpu`` Warp's CPU device, slow but the same code), from ``pip install -e ".[gpu]"``."""
CONTEXTS = ("none", "bbox")
REWARDS = ("sdf", "com", "none", "sdf-thumb")
CONTACT_SHAPINGS = ("per-step", "difference")
GRASP_START_PHASES = ("approach", "closing", "lift")
AGENT_PARTS = ("networks", "action_std", "normalizers")
"""What ``[run] init_agent_parts`` can take from another run's agent: the policy's and value's
layers, the policy's state-independent action std, the observation and value normalizers."""
ROBOTS = ("ur5e", "floating")
INIT_AGENT_UNSEEN = ("keep", "silence")
HAND_GEOMETRIES = ("capsules", "hulls", "tip-hulls")
HAND_ACTIONS = ("absolute", "relative")
HAND_DRIVES = ("equalities", "all-joints")


class _Checked(Checked):
    """The trainer's configs refuse out-of-range values with its own error type."""

    error: ClassVar[type[Exception]] = TrainerError


@dataclass(frozen=True)
class PhysicsConfig(_Checked):
    """Simulation timing and contact parameters."""

    control_hz: float = bounded(30.0, gt=0, paper="30")
    """Actions per second (Hz): how often the policy acts and the arm and hand targets change."""
    substeps: int = bounded(10, ge=1)
    """Physics steps per action; the timestep is 1 / (control_hz * substeps) s. Fewer: faster,
    until grasps fail (results/substeps-2026-11-26/)."""
    iterations: int = bounded(20, ge=1)
    """Iterations of MuJoCo's constraint solver per physics step (``opt.iterations``)."""
    ls_iterations: int = bounded(10, ge=0)
    """Line-search iterations of each solver iteration (``opt.ls_iterations``)."""
    impratio: float = bounded(1.0, gt=0)
    """Frictional-to-normal constraint impedance ratio; above 1 makes friction stiffer (less
    creep of a held object), as MuJoCo recommends with elliptic cones
    (results/graspability-drives-2026-11-25/, results/hold-at-slip-2026-11-26/)."""
    noslip_iterations: int = bounded(5, ge=0)
    """Passes of MuJoCo's no-slip solver after the main one (0: off): removes the creep of soft
    frictional contacts that lets pinched or held objects slide out; costs ~10 % (lift) to
    ~25 % (bin) of the CPU's env steps/s (results/noslip-iterations-2026-11-26/) and 70 % of
    MuJoCo Warp's step on a GPU (results/bench-gpu-step-2026-11-29/)."""
    memory_mb: float = bounded(0.0, ge=0)
    """MB of each env's MuJoCo arena (contacts, constraints, solver scratch: ``<size memory>``);
    0: MuJoCo's estimate (15 MB for a bin of five YCB objects). An env whose constraints outgrow
    it cannot be stepped (MuJoCo C: ``mj_stackAlloc: out of memory``): it is reset and the trainer
    says so once per iteration. Address space, resident only as used."""
    sleep: bool = False
    """CPU backend: let objects at rest sleep (MuJoCo's sleeping islands): the bin up to ~2x
    faster (``bench/env_throughput.py --sleep``; results/cpu-bin5-six/); a resumed run does not
    continue bit for bit (a checkpoint restores every object awake)."""
    table_size: tuple[float, float, float] = bounded((0.4, 0.4, 0.02), gt=0)
    """Half-sizes of the table top (m); its top surface is at z = 0."""
    table_plane: bool = False
    """Objects collide with the table as the plane of its top (z = 0), the robot with its box:
    the same surface, and for MuJoCo Warp a primitive test, not GJK/EPA
    (results/bench-step-phases-2026-11-29/). An object pushed off the edge rests at z = 0."""
    # The contact materials (``materials``; defaults: ``geomgrasp.materials.DEFAULTS``).
    table_friction: tuple[float, float, float] = bounded(materials.TABLE.friction, ge=0)
    """Sliding, torsional, rolling friction of the table, the bin and the arm."""
    finger_friction: tuple[float, float, float] = bounded(materials.HAND.friction, ge=0)
    """Sliding, torsional, rolling friction of the hand."""
    condim: int = bounded(materials.HAND.condim, choices=(1, 3, 4, 6))
    """Contact dimensionality of the floor, table, bin, arm and hand (4: torsional friction
    too, which keeps a pinched object from spinning out)."""
    solref: tuple[float, float] = materials.HAND.solref
    """Contact stiffness of the hand's geoms (MuJoCo's solref: time constant, damping ratio)."""
    solimp: tuple[float, float, float, float, float] = materials.HAND.solimp
    """Contact impedance of the hand's geoms (MuJoCo's solimp). The objects' contact parameters
    are geomprep's (``[mjcf]`` in its config), written into each object's MJCF, so geomprep's
    settle check and training see the same contacts."""

    def materials(self) -> dict[str, ContactMaterial]:
        """The contact material of each group of the scene's fixtures and robot, from these
        fields (the objects' material is in their MJCF)."""
        fixture = ContactMaterial(friction=self.table_friction, condim=self.condim)
        return {
            "floor": dataclasses.replace(materials.DEFAULTS["floor"], condim=self.condim),
            "table": fixture,
            "bin": fixture,
            "arm": fixture,
            "hand": ContactMaterial(
                friction=self.finger_friction, condim=self.condim, solref=self.solref,
                solimp=self.solimp,
            ),
        }


@dataclass(frozen=True)
class RobotConfig(_Checked):
    """Arm and hand actuation, and how an action moves them."""

    kind: str = bounded("ur5e", choices=ROBOTS, paper="ur5e")
    """``ur5e`` (arm + hand, Jacobian-transpose control) or ``floating`` (hand on a 6-DoF mocap)."""
    base_pos: tuple[float, float, float] = (0.26, 0.63, -0.23)
    """UR5e base position (m; the table top centre is the origin): beside the table, below its
    top, where the authors' home configuration puts the hand above the table centre."""
    arm_kp: float = bounded(1500.0, ge=0)
    """Stiffness of the UR5e's joint position servos (N·m/rad)."""
    arm_damping: float = bounded(120.0, ge=0)
    """Damping of the UR5e's joint position servos (N·m·s/rad)."""
    arm_armature: float = bounded(0.2, ge=0)
    """Armature (rotor inertia) of the UR5e's joints (kg·m²)."""
    hand_kp: float = bounded(20.0, ge=0)
    """Stiffness of the hand's position servos (N·m/rad)."""
    hand_forcerange: float = bounded(0.75, gt=0)
    """Hand servo torque limit (N·m): the real SIH servos' 0.75 N·m (the capsule hand used 5)
    (results/graspability-drives-2026-11-25/)."""
    hand_geometry: str = bounded("hulls", choices=HAND_GEOMETRIES)
    """Collision shapes of the 11 finger and thumb links: ``capsules`` (our estimate),
    ``hulls`` (of the published link meshes, ``trainer/robots/sih_hulls.json``) or ``tip-hulls``
    (capsules on the proximal links: loses knife pinches); the palm is a box
    (results/graspability-2026-11-25/, results/bench-step-phases-2026-11-29/)."""
    hand_drive: str = bounded("all-joints", choices=HAND_DRIVES)
    """How the 5 servo commands reach the 11 joints: ``equalities`` (5 actuators, followers on
    soft 1:1 equalities) or ``all-joints`` (11 actuators, each follower given its leader's
    target: the authors' Isaac Gym scheme) (results/graspability-drives-2026-11-25/)."""
    hand_joint_damping: float = bounded(0.1, ge=0)
    """Damping of the 11 hand joints (N·m·s/rad): the authors' URDF's 0.1 (the dexterity MJCF
    has 1.0, which caps a finger's closing speed at 0.75 rad/s; issue 33)."""
    hand_action: str = bounded("absolute", choices=HAND_ACTIONS)
    """How the 5 hand actions command the servos: ``absolute`` (a target from open, -1, to
    closed, +1) or ``relative`` (targets move by ``hand_relative_step`` times the action, the
    authors' Isaac Gym task) (results/cpu-dice-hand-action-2026-11-25/)."""
    hand_relative_step: float = bounded(0.167, gt=0)
    """``relative``: target change per action at |a| = 1 (rad; +1 toward closed): 5 rad/s at
    30 Hz, the authors' a * dt * 5."""
    home_hand_height: float = bounded(0.28, gt=0)
    """Palm keypoint height above the table at reset (m); building a task warns when the open
    hand at home touches an object in some settled initial state
    (results/home-contact-2026-11-26/)."""
    home_above_objects: bool = False
    """Raise the home height per settled initial state (1 cm steps, at most 0.3 m more) to the
    lowest at which the open hand touches none of its objects at 16 yaws
    (results/home-contact-2026-11-26/, results/cpu-home-2026-11-26/)."""
    pos_step: float = bounded(0.02, ge=0)
    """Hand translation per action at |a| = 1 (m) (results/cpu-knife-arms-2026-11-26/)."""
    rot_step: float = bounded(0.1, ge=0)
    """Hand rotation per action at |a| = 1 (rad)."""
    jt_iterations: int = bounded(2, ge=1)
    """Jacobian-transpose refinements of the arm targets per action (they carry over between
    actions, so the targets keep converging while the command holds still)."""
    jt_rotation_scale: float = bounded(0.2, gt=0)
    """Metres per radian when position and rotation errors share one JT step."""
    leash: float = bounded(0.05, gt=0)
    """The commanded hand position stays within this distance of the measured one (m)."""
    weld_solref: tuple[float, float] = (0.01, 1.0)
    """Softness of the floating hand's weld to its mocap target."""


@dataclass(frozen=True)
class RewardConfig(_Checked):
    """r = c1 / (|h_bar - dh| + eps_h) + c2 · 1(success) + c3 / (d + eps_sdf) (the paper), where
    success is dh >= h_bar with the target held (``hold_tips``). The terms (lift, success,
    contact) and their weights are one table, ``trainer.tasks.terms.reward_terms``; each is
    logged as ``reward_<term>``."""

    kind: str = bounded("sdf", choices=REWARDS, paper="sdf (ablations: com, none)")
    """The contact term's d: ``sdf`` (fingertip distances to the surface), ``com`` (to the
    centre of mass), ``none`` (no term), or ours, ``sdf-thumb`` (the thumb pad's plus the
    nearest finger pad's distance: pays a pinch) (results/reward-balance-2026-11-26/)."""
    contact_shaping: str = bounded("per-step", choices=CONTACT_SHAPINGS)
    """How the contact term is paid: ``per-step`` (its value every step, the paper) or
    ``difference`` (its change since the previous step: approaching pays, resting pays 0)
    (results/cpu-contact-difference-2026-11-27/, results/config-evidence.md)."""
    h_bar: float = bounded(0.2, gt=0, paper="0.2")
    """Lift target (m): success is the target lifted this far (``dh >= h_bar``); evaluation
    always uses it."""
    c1: float = bounded(0.5, paper="0.5")
    """Weight of the lift term."""
    c2: float = bounded(5000.0, paper="5000")
    """Weight of the success term (the bonus)."""
    c3: float = bounded(1.0, paper="1 (ablation: 0)")
    """Weight of the contact term."""
    eps_h: float = bounded(0.02, gt=0, paper="0.02")
    """The lift term's epsilon (m): its largest value is c1 / eps_h, at dh = h_bar."""
    eps_sdf: float = bounded(0.025, gt=0, paper="0.025")
    """The contact term's epsilon (m): its largest value is c3 / eps_sdf, at d = 0."""
    h_bar_start: float = 0.2
    """Lift-height curriculum (training only): the lift target starts here (m) and rises by
    ``h_bar_increment`` whenever the running success at it reaches ``h_bar_promote``, up to
    ``h_bar``. Equal to ``h_bar`` (the default, the paper): no curriculum."""
    h_bar_increment: float = bounded(0.02, gt=0)
    """Curriculum: how much the lift target rises at a promotion (m)."""
    h_bar_promote: float = bounded(0.5, ge=0, le=1)
    """Curriculum: the running success at the current target that promotes it
    (results/cpu-knife-promote-2026-11-28/)."""
    curriculum_per_object: bool = False
    """One curriculum target per target object, each promoted on its own running success
    (over ``run.success_window`` / the number of objects episodes, at least 16); false: one
    target for all (results/cpu-table1-together-2026-11-26/, results/cpu-bin5-perobject/)."""
    hold_tips: int = bounded(2, ge=0, le=5)
    """Success needs the target lifted *and held*: at least this many fingertip pads within
    ``hold_distance`` of it; 0: any rise by h_bar counts (the paper's words do not say)
    (results/cpu-table1/)."""
    hold_distance: float = bounded(0.02, gt=0)
    """Fingertip pad to the target's surface (m, from its SDF) that counts as touching it for
    ``hold_tips``; the scripted grasps' lifts: 99 % have two pads within 2 cm."""
    lift_clearance: float = bounded(0.0, ge=0)
    """dh is the centre's rise only once the target's lowest surface point has risen this far
    (m), that point's rise until then, so tipping an object is no lift; 0 (the default, the
    paper): the centre's rise (results/cpu-lift-clearance-2026-11-26/)."""
    hold_from: float = bounded(0.0, ge=0)
    """Training only: ``hold_tips`` applies to curriculum targets of at least this height (m);
    below it any rise succeeds. 0: always. At most ``h_bar`` (results/cpu-table1/)."""

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.hold_from > self.h_bar:
            raise field_error(
                TrainerError, "hold_from", self.hold_from,
                f"must be at most h_bar ({self.h_bar:g}): evaluation counts held lifts only",
            )

    def success_text(self) -> str:
        """What a success is, in words (``trainer eval``'s outputs state it)."""
        lift = f"lifted by {self.h_bar:g} m"
        if self.lift_clearance > 0:
            lift += f" (its lowest point by {self.lift_clearance:g} m)"
        if self.hold_tips == 0:
            return f"{lift} (held or not)"
        return (f"{lift} while held ({self.hold_tips} or more fingertip pads within "
                f"{self.hold_distance:g} m of it)")


@dataclass(frozen=True)
class InitConfig(_Checked):
    """Initial states: objects dropped at random poses and settled, cached as a bank."""

    bank_size: int = bounded(64, ge=1)
    """Settled poses per object."""
    drop_height: tuple[float, float] = bounded((0.05, 0.15), ge=0)
    """Lowest object point above the table at release (m)."""
    xy_range: float = bounded(0.08, ge=0)
    """Drop position is uniform in a square of this half-size around the table centre (m)."""
    settle_seconds: float = bounded(1.5, ge=0)
    """Simulated time a dropped object settles before its pose is banked (s; lift task)."""
    seed: int = bounded(0, ge=0)
    """Seed of the drops (with a digest of the objects): the banks, not the run's seed."""

    def __post_init__(self) -> None:
        super().__post_init__()
        low, high = self.drop_height
        if low > high:
            raise field_error(
                TrainerError, "drop_height", self.drop_height, "must be [lowest, highest]"
            )


@dataclass(frozen=True)
class BinConfig(_Checked):
    """The bin-picking task (``trainer/tasks/bin.py``): a bin of a floor and four walls at the
    table centre, ``num_objects`` objects dropped into it, one of them the target."""

    num_objects: int = bounded(5, ge=1, paper="5 and 10")
    """Objects in the bin, drawn without replacement from the object set."""
    layouts: int = bounded(16, ge=1)
    """Distinct bins (object draws) per run, each one compiled model on the CPU backend that
    envs share round-robin (~1.5 MiB each: one per env would mean 256 at 256 envs;
    ``bench/env_throughput.py --memory``)."""
    bank_size: int = bounded(16, ge=1)
    """Settled clutter states per layout (each reset draws one, with a random quarter turn)."""
    inner_half_size: tuple[float, float] = bounded((0.2, 0.2), gt=0)
    """Half the inside length and width of the bin (m): 40 cm square holds 10 YCB objects,
    plates (26 cm) included, without most drops spilling over the walls."""
    wall_height: float = bounded(0.06, gt=0)
    """Height of the bin's walls above its floor (m)."""
    wall_thickness: float = bounded(0.01, gt=0)
    """Thickness of the bin's walls (m)."""
    drop_spacing: float = bounded(0.02, ge=0)
    """Vertical gap between the objects at release (m): they are dropped one above the other."""
    settle_seconds: float = bounded(3.0, gt=0)
    """Simulated time the dropped objects settle before a clutter state is banked (s)."""
    max_penetration: float = bounded(0.005, gt=0)
    """A settled state with two objects (or an object and the bin) interpenetrating deeper than
    this (m) is dropped again."""


@dataclass(frozen=True)
class WarpConfig(_Checked):
    """Buffer sizes of the MuJoCo Warp backend (``trainer/sim/warp.py``). A world whose
    contacts or constraints do not fit is flagged unstable and reset (counted in
    ``metrics.csv``), and the run warns naming the knob to raise."""

    contacts_per_world: int = bounded(0, ge=0)
    """Contacts per world (the pool is shared: one world may use more); 0: derived from the
    scene (4 per colliding robot geom and 8 per object, times ``buffer_margin``)."""
    constraints_per_world: int = bounded(0, ge=0)
    """Constraint rows per world (a hard per-world limit); 0: ``condim`` per contact plus the
    joint limits and equalities."""
    buffer_margin: float = bounded(1.5, ge=1.0)
    """Headroom of the derived contact count over its estimate."""


@dataclass(frozen=True)
class EnvConfig(_Checked):
    """A grasping task: the scene, the robot, the objects and how the policy sees them."""

    num_envs: int = bounded(64, ge=1, paper="16384")
    """Parallel environments (simulated side by side; each training rollout steps them all)."""
    task: str = bounded("lift", choices=tuple(TASKS), paper="lift and bin")
    """``lift``: one object on the table, lift it by h_bar. ``bin``: lift a given target out of
    a bin of ``[bin] num_objects`` objects."""
    representation: str = bounded(
        "", choices=REPRESENTATIONS, paper="each of the seven (lift); bbox (bin)"
    )
    """How the policy sees the object (the target in ``bin``); empty: the task's default
    (``TASKS``: sq for lift, bbox for bin)."""
    context: str = bounded("none", choices=CONTEXTS)
    """``bbox``: the bin task also observes every other object's bounding box (pose + extents,
    with a mask), read by a permutation-invariant encoder; ``none``: the paper (target only)."""
    observe_fingertips: bool = False
    """Append the 5 fingertip pad positions (world frame, m) to ``proprio`` (20 -> 35 values),
    as the authors' Isaac Gym task observes them; false: the paper's proprioception (palm pose
    and joint angles) (results/cpu-knife-arms-2026-11-26/)."""
    observe_hand_targets: bool = False
    """Append the hand's 5 servo targets (-1 open, +1 closed) to ``proprio``: with relative hand
    actions the targets are controller state the joint angles do not show
    (results/cpu-dice-hand-action-2026-11-25/)."""
    backend: str = bounded("cpu", choices=BACKENDS)
    """Physics backend (``BACKENDS``): ``cpu`` (MuJoCo C on a thread pool) or ``warp`` (MuJoCo
    Warp; ``pip install -e ".[gpu]"``)."""
    objects: str = bounded("builtin", paper="ycb (the 78 YCB objects)")
    """Object set: ``builtin``, ``ycb``, ``all``, or a comma list of names."""
    held_out: str = ""
    """Ours: objects of ``objects`` (names or a set) that the task never holds: a run trains on
    the rest, ``trainer eval RUN --held-out`` evaluates it on these (generalization to unseen
    objects)."""
    max_steps: int = bounded(300, ge=1, paper="300")
    """Actions per episode at most (an episode also ends on success or a fall)."""
    fall_height: float = -0.05
    """The object counts as off the table below this height (m, table top at 0)."""
    data_dir: Path = Path("data")
    """geomprep's data directory (the built objects are in its ``processed/``)."""
    device: str = "cpu"
    """Torch device of the networks and task tensors (and of MuJoCo Warp): ``cpu`` or
    ``cuda[:N]``."""
    nthread: int = bounded(0, ge=0)
    """Simulation threads; 0 = all cores."""
    sdf_dtype: str = bounded("float16", choices=("float16", "float32"))
    """Storage of the SDF grids: float16 moves a looked-up distance by <= 10 um within 2 cm of a
    surface and halves the memory (78 objects at 200^3: 2.50 GB instead of 4.99 GB)."""
    compile: bool = False
    """``torch.compile`` the per-step task computations (kinematics, observations, reward):
    about 2x less torch time per step at small env counts, after ~30-60 s of compilation per
    representation (cached on disk). Needs a C++ compiler on CPU."""
    physics: PhysicsConfig = field(default_factory=PhysicsConfig)
    robot: RobotConfig = field(default_factory=RobotConfig)
    reward: RewardConfig = field(default_factory=RewardConfig)
    init: InitConfig = field(default_factory=InitConfig)
    bin: BinConfig = field(default_factory=BinConfig)
    warp: WarpConfig = field(default_factory=WarpConfig)

    def __post_init__(self) -> None:
        if not self.representation and self.task in TASKS:
            object.__setattr__(self, "representation", TASKS[self.task])
        super().__post_init__()
        if self.context != "none" and self.task != "bin":
            raise TrainerError(
                f"context = {self.context!r}: only the bin task has other objects to see; "
                "use --task bin or drop --context"
            )

    @property
    def timestep(self) -> float:
        return 1.0 / (self.physics.control_hz * self.physics.substeps)


@dataclass(frozen=True)
class PPOConfig(_Checked):
    """PPO and the networks. The paper's schedule: 16,384 envs x 32 steps per rollout, 5 epochs,
    minibatch 32,768 (16 minibatches); with fewer envs the rollout length stays and the rollout
    is cut into at most ``minibatches`` minibatches of at least ``min_minibatch`` frames (tiny
    minibatches would make the update cost, not the simulation, the bottleneck on a CPU)."""

    frames_per_env: int = bounded(32, ge=1, paper="32")
    """Steps of every env per rollout (one PPO iteration) (results/cpu-iterations-2026-11-27/)."""
    epochs: int = bounded(5, ge=1, paper="5")
    """Passes over each rollout in the update."""
    minibatches: int = bounded(16, ge=1, paper="16 (of 32,768 frames at 16,384 envs)")
    """Minibatches per epoch at most (fewer where they would be below ``min_minibatch``)."""
    min_minibatch: int = bounded(1024, ge=1)
    """Frames per minibatch at least (at most the whole rollout)."""
    lr: float = bounded(3e-4, gt=0)
    """Initial learning rate (Adam)."""
    lr_schedule: str = bounded("adaptive", choices=("adaptive", "fixed"))
    """``adaptive``: after every epoch, divide the learning rate by 1.5 when the epoch's mean
    approximate KL to the rollout policy exceeds twice ``kl_target``, multiply it by 1.5 below
    half of it (rl_games' schedule; the paper trained with rl_games); ``fixed``: keep ``lr``."""
    kl_target: float = bounded(0.016, gt=0)
    """The KL per epoch that the adaptive schedule aims at (results/cpu-iterations-2026-11-27/)."""
    lr_bounds: tuple[float, float] = bounded((1e-6, 1e-2), gt=0)
    """Lowest and highest learning rate of the adaptive schedule."""
    gamma: float = bounded(0.99, ge=0, le=1)
    """Discount factor (results/cpu-plate-discount-2026-11-27/)."""
    lmbda: float = bounded(0.95, ge=0, le=1)
    """GAE's lambda."""
    clip_epsilon: float = bounded(0.2, gt=0)
    """PPO's clipping range of the probability ratio."""
    entropy_coef: float = 0.0
    """Weight of the entropy bonus in the loss (results/cpu-com-builtin-no-lift/)."""
    critic_coef: float = bounded(1.0, ge=0)
    """Weight of the value loss."""
    max_grad_norm: float = bounded(1.0, gt=0)
    """Gradients are clipped to this norm."""
    hidden: tuple[int, ...] = bounded((256, 128, 64), ge=1, paper="three layers (sizes not given)")
    """Layer sizes of the MLP of the policy and of the value function
    (results/cpu-knife-arms-2026-11-26/)."""
    pointnet_hidden: tuple[int, ...] = bounded((64, 128), ge=1)
    """Shared per-point MLP of the point-cloud encoder (then max pooling)."""
    shared_encoder: bool = False
    """Ours: one object (and context) encoder for the policy and the value, run once per
    minibatch, trained by both losses (the authors' public code shares its whole network);
    halves a point cloud's encoder cost (results/bench-pointnet-2026-11-29/)."""
    context_hidden: tuple[int, ...] = bounded((64, 64), ge=1)
    """Shared per-object MLP of the context encoder (bin task with context; then a masked max)."""
    stagger_episodes: bool = False
    """Start every env's first episode at a random step in [0, ``max_steps``), so that episodes
    cut at ``max_steps`` end in different rollouts (as legged_gym does); training only
    (results/cpu-table1/)."""
    init_log_std: float | tuple[float, ...] = -0.5
    """Log of the untrained policy's action std (learned from there): one number (-0.5: std
    0.61) or, ours, one per action (the 6 hand-pose actions, then the 5 hand actions)
    (results/cpu-exploration-noise-2026-11-27/)."""
    state_dependent_std: bool = False
    """Ours: log std = ``init_log_std``'s learned values plus a linear head (zero at the start)
    on the policy's last hidden features, so noise can be lower only where it costs; false:
    one learned vector, the paper's (results/cpu-state-std-2026-11-27/)."""
    init_action_mean: tuple[float, ...] = (0.0,) * ACTION_DIM
    """Mean action of the untrained policy (the output layer's bias): zero puts every hand DoF
    mid-range at the first step; ``[0, 0, 0, 0, 0, 0, 1, -1, -1, -1, -1]`` keeps the home
    posture (results/cpu-com-builtin-curriculum/)."""

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.lr_bounds[0] > self.lr_bounds[1]:
            raise field_error(
                TrainerError, "lr_bounds", self.lr_bounds, "must be [lowest, highest]"
            )
        for name in ("hidden", "pointnet_hidden", "context_hidden"):
            if not getattr(self, name):
                raise field_error(TrainerError, name, getattr(self, name), "needs a layer size")
        if len(self.init_action_mean) != ACTION_DIM:
            raise field_error(
                TrainerError, "init_action_mean", self.init_action_mean,
                f"needs {ACTION_DIM} values, one per action",
            )
        if isinstance(self.init_log_std, tuple) and len(self.init_log_std) != ACTION_DIM:
            raise field_error(
                TrainerError, "init_log_std", self.init_log_std,
                f"needs one number or {ACTION_DIM} values, one per action",
            )


@dataclass(frozen=True)
class RunConfig(_Checked):
    """The training run: length, seed, bookkeeping; and, all of them the project's own, how
    training episodes may start along scripted grasps (``grasp_start*``) and how a run may start
    from another agent (``init_agent*``, ``warmup_*``). Their history:
    results/config-evidence.md."""

    total_steps: int = bounded(10_000_000, ge=1, paper="262144000 (500 iterations)")
    """Environment steps (actions of one env count one) before the run stops."""
    seed: int = bounded(0, ge=0)
    """Seed of the run's randomness: the networks' initial weights, the sampled actions, the
    resets, the minibatch order (``trainer.randomness``); not of the initial-state banks."""
    max_minutes: float = bounded(0.0, ge=0)
    """Wall-clock budget (minutes of training, a resumed run's earlier parts included; 0: none):
    the run stops, with a checkpoint, after the first iteration that ends past it (for chunks
    within a lent device's per-command limit: ``--minutes 9``, then ``--resume``)."""
    checkpoint_every: int = bounded(10, ge=1)
    """Iterations between checkpoints (the last one is always written)."""
    success_window: int = bounded(0, ge=0)
    """Episodes in the running success rate; 0 = the number of envs."""
    torch_threads: int = bounded(1, ge=1)
    """Threads of torch's own ops (the simulation has its own pool)."""
    grasp_starts: float = bounded(0.0, ge=0, le=1)
    """The fraction of training episodes that start from a state along a scripted grasp that
    lifted the env's object (recorded when the run starts; counted in no success rate or
    curriculum); 0: all start home (results/cpu-together-starts50-2026-11-27/)."""
    fixed_drops: bool = False
    """Ours (the authors' public bin task; not the paper's): each training env keeps one
    settled state of its layout for good (``trainer.tasks.starts.FixedDrop``) instead of drawing
    one per reset; the target is still drawn per episode, and ``trainer eval`` draws its
    states."""
    grasp_start_family: str = "best"
    """The scripted grasp those starts come from: ``best`` (each object's family in
    ``trainer.grasps.families.BEST``, Table I objects only) or one ``FAMILY[:VARIANT]``."""
    grasp_start_rounds: int = bounded(2, ge=1)
    """Scripted trials per env recorded for ``grasp_starts`` (each a fresh reset)."""
    grasp_start_phase: str = bounded("approach", choices=GRASP_START_PHASES)
    """Which states of the script (every 10th action): ``approach`` (from the 10th to the end
    of the closing), ``closing`` (its closing only) or ``lift`` (closing, then lifting: a reset
    uses those below its object's lift target) (results/cpu-plate-lift-starts-2026-11-27/)."""
    init_agent: str = ""
    """A checkpoint file, or a run directory (its last readable checkpoint), whose agent this run
    starts from (networks, action std, normalizers; all else fresh); "": a fresh agent. The
    agents must match (representation, observations, network sizes); a run with context may
    start from one without (a lift policy): its context encoder new, silent at the start."""
    init_agent_parts: tuple[str, ...] = AGENT_PARTS
    """Which parts of ``init_agent``'s agent this run takes (``networks``, ``action_std``,
    ``normalizers``); the others start fresh (results/cpu-plate-agent-parts-2026-11-28/)."""
    warmup_objects: str = ""
    """Objects (as ``objects``) the run first trains on for ``warmup_steps`` env steps, in its
    ``warmup/`` folder, before it starts from that agent on its own objects (steps on top of
    ``total_steps``, minutes within ``max_minutes``) (results/cpu-warmup-2026-11-28/)."""
    warmup_steps: int = bounded(0, ge=0)
    """Env steps of the warmup on ``warmup_objects`` (0: none)."""
    init_agent_unseen: str = bounded("keep", choices=INIT_AGENT_UNSEEN)
    """What a run started from another agent does with the features that agent never saw vary
    (a lone object's extents): ``keep`` them as they are, or ``silence`` their weights (zeroed,
    ``Agent.silence_unseen_features``) (results/cpu-plate-source-2026-11-28/)."""
    world_size: int = bounded(1, ge=1)
    """Processes the run is spread over (``torchrun --nproc_per_node``, times ``--nnodes``),
    each stepping ``num_envs / world_size`` envs: recorded by the launch, not a setting; a
    resumed run needs the same number (docs/distributed.md)."""
    random_streams: bool = True
    """Every generator draws from its own stream derived from ``seed``; false: each is seeded
    with ``seed`` itself, as runs before 2026-11-25 were (their config.json lacks this key and
    reads as false) (results/structure-check-2026-11-25/)."""

    def __post_init__(self) -> None:
        super().__post_init__()
        parts = self.init_agent_parts
        if not parts or len(set(parts)) != len(parts) or not set(parts) <= set(AGENT_PARTS):
            raise field_error(
                TrainerError, "init_agent_parts", parts,
                f"must name each of {', '.join(AGENT_PARTS)} at most once, at least one",
            )
        if bool(self.warmup_objects) != (self.warmup_steps > 0):
            raise field_error(
                TrainerError, "warmup_objects" if self.warmup_objects else "warmup_steps",
                self.warmup_objects or self.warmup_steps,
                "needs the other: set warmup_objects and warmup_steps together",
            )
        if self.init_agent_unseen == "silence" and not {"networks", "normalizers"} <= set(parts):
            raise field_error(
                TrainerError, "init_agent_unseen", self.init_agent_unseen,
                "silences the agent's networks by its normalizers' statistics: keep networks "
                "and normalizers in init_agent_parts",
            )
        if self.init_agent_unseen == "silence" and not (self.init_agent or self.warmup_objects):
            raise field_error(
                TrainerError, "init_agent_unseen", self.init_agent_unseen,
                "applies to a run started from another agent: set init_agent or warmup_objects",
            )
        if self.warmup_objects and self.init_agent:
            raise field_error(
                TrainerError, "init_agent", self.init_agent,
                "a run with warmup_objects starts from its warmup's agent: drop one of the two",
            )


@dataclass(frozen=True)
class TrainConfig:
    env: EnvConfig = field(default_factory=EnvConfig)
    ppo: PPOConfig = field(default_factory=PPOConfig)
    run: RunConfig = field(default_factory=RunConfig)


def read_config_toml(path: Path | None) -> dict[str, Any]:
    """A config file's values as written ({} without one); an unreadable one is a one-line
    error."""
    return {} if path is None else read_toml(path, TrainerError)


def _build(
    cls: type, values: Mapping[str, Any], source: str | None, section: str = "", base: Any = None,
    names: Mapping[str, str] | None = None,
) -> Any:
    if (
        cls is EnvConfig and isinstance(base, EnvConfig) and "task" in values
        and "representation" not in values and base.representation == TASKS[base.task]
    ):
        # Switching the task keeps an explicitly chosen representation, but not the old task's
        # default: the new task's default applies.
        values = {**values, "representation": ""}
    return build_dataclass(
        cls, values, source, TrainerError, section=section, base=base, names=names
    )


def _toml_env(values: dict[str, Any], path: Path | None) -> EnvConfig:
    """The environment part of a TOML file: its top level and sections other than [ppo], [run]."""
    env = {k: v for k, v in values.items() if k not in ("ppo", "run")}
    return _build(EnvConfig, env, str(path)) if env else EnvConfig()


def _set_names(sets: Mapping[str, Any]) -> dict[str, str]:
    """How errors name each ``--set`` value: the assignment as given."""
    return {key: f"--set {key}={toml_value(value)}" for key, value in sets.items()}


def load_env_config(
    path: Path | None = None, sets: Mapping[str, Any] | None = None, **overrides: Any
) -> EnvConfig:
    """Defaults, then the TOML file at ``path``, then ``sets`` (``--set``: dotted keys as the
    file writes them, checked by ``trainer.config_keys.parse_sets``; as if the file said them),
    then keyword ``overrides`` (top-level fields, whole sections or dicts of section fields),
    e.g. ``load_env_config(num_envs=16)``."""
    cfg = _toml_env(read_config_toml(path), path)
    if sets:
        cfg = _build(EnvConfig, dotted_overrides(sets), None, base=cfg, names=_set_names(sets))
    return _build(EnvConfig, overrides, None, base=cfg) if overrides else cfg


def load_train_config(
    path: Path | None = None,
    env: dict[str, Any] | None = None,
    ppo: dict[str, Any] | None = None,
    run: dict[str, Any] | None = None,
    names: Mapping[str, str] | None = None,
    sets: Mapping[str, Any] | None = None,
) -> TrainConfig:
    """Defaults, then the TOML file (environment knobs as in ``load_env_config`` plus ``[ppo]``
    and ``[run]`` sections), then ``sets`` (``--set``, as in ``load_env_config``; ``ppo.`` and
    ``run.`` keys too), then the override dicts (command-line options; ``names`` maps their
    keys, dotted below the section, to the options, which errors then name)."""
    values = read_config_toml(path)
    cfg = TrainConfig(
        _toml_env(values, path),
        _build(PPOConfig, values.get("ppo", {}), str(path), "ppo"),
        _build(RunConfig, values.get("run", {}), str(path), "run"),
    )
    if sets:
        given = _set_names(sets)
        parts: dict[str, dict[str, Any]] = {"env": {}, "ppo": {}, "run": {}}
        for key, value in sets.items():
            section, _, rest = key.partition(".")
            if section in ("ppo", "run") and rest:
                parts[section][rest] = value
            else:
                parts["env"][key] = value
        cfg = TrainConfig(
            _build(EnvConfig, dotted_overrides(parts["env"]), None, base=cfg.env, names=given),
            _build(PPOConfig, parts["ppo"], None, "ppo", base=cfg.ppo, names=given),
            _build(RunConfig, parts["run"], None, "run", base=cfg.run, names=given),
        )
    return TrainConfig(
        _build(EnvConfig, env or {}, None, base=cfg.env, names=names),
        _build(PPOConfig, ppo or {}, None, base=cfg.ppo, names=names),
        _build(RunConfig, run or {}, None, base=cfg.run, names=names),
    )


def override(section: Any, values: Mapping[str, Any], names: Mapping[str, str]) -> Any:
    """A loaded config ``section`` with ``values`` (command-line options, named by ``names``
    in errors) replacing its fields, checked like the file's."""
    return _build(type(section), values, None, base=section, names=names)


def train_config_from_dict(values: Any, source: str = "config.json") -> TrainConfig:
    """The inverse of ``config_dict(train_config)`` (a run directory's config.json, named
    ``source`` in errors). Runs written before the objects' contact parameters moved to
    geomprep's MJCF carry ``physics.object_friction``: it is dropped (it equals geomprep's); runs
    written before the derived random streams get ``run.random_streams = false``."""
    if isinstance(values, dict):
        physics = values.get("env", {}).get("physics", {})
        if isinstance(physics, dict):
            physics.pop("object_friction", None)
        run = values.get("run")
        if isinstance(run, dict) and "random_streams" not in run:
            run["random_streams"] = False  # the run predates the derived random streams
    return _build(TrainConfig, values, source)


ABSENT_MEANS: dict[str, Any] = {"env.reward.hold_tips": 0}
"""Config fields added with a default that changed what a run does: a run directory whose
config.json predates the field ran with this value (success was any rise by h_bar), not with
today's default. ``trainer report`` groups such runs by it; ``--resume`` refuses them."""


NEUTRAL_DEFAULTS: dict[str, Any] = {"env.physics.table_plane": False}
"""Config fields added with a default that does what configs did before them (dotted name ->
that default). Cache keys (searched grasps, recorded grasp starts) leave such a field out while
it holds that value, so what was cached before the field existed is still found."""


UNKEYED_FIELDS = frozenset({"env.physics.memory_mb"})
"""Config fields that change no simulated result whatever their value (the arena's size only
decides whether MuJoCo has room to compute a step at all): cache keys leave them out, so that
raising one, as the trainer's warning says, keeps the cached grasps and grasp starts."""


def without_neutral(values: dict[str, Any], prefix: str = "env") -> dict[str, Any]:
    """``values`` (a config section as nested dicts, named ``prefix``) less the
    ``NEUTRAL_DEFAULTS`` fields that hold their neutral value and the ``UNKEYED_FIELDS``
    (a copy; ``values`` is kept): what a cache key is made of."""
    out = {}
    for key, value in values.items():
        dotted = f"{prefix}.{key}"
        if isinstance(value, dict):
            out[key] = without_neutral(value, dotted)
        elif dotted in UNKEYED_FIELDS:
            continue
        elif dotted not in NEUTRAL_DEFAULTS or NEUTRAL_DEFAULTS[dotted] != value:
            out[key] = value
    return out


def predated_fields(path: Path) -> dict[str, Any]:
    """The ``ABSENT_MEANS`` fields (dotted name -> the value the run ran with) that a run
    directory's config.json lacks."""
    values = json.loads(Path(path).read_text())
    missing = {}
    for dotted, value in ABSENT_MEANS.items():
        node = values
        for key in dotted.split("."):
            node = node.get(key) if isinstance(node, dict) else None
        if node is None:
            missing[dotted] = value
    return missing


def read_train_config(path: Path) -> TrainConfig:
    """A run directory's config.json; a missing or garbled file is a one-line error."""
    fix = "pass a run directory written by trainer run"
    try:
        values = json.loads(Path(path).read_text())
    except FileNotFoundError:
        raise TrainerError(
            f"{Path(path).parent} is not a run directory (no config.json): {fix}"
        ) from None
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise TrainerError(f"{path} is unreadable ({exc}): {fix}") from None
    return train_config_from_dict(values, str(path))


# --- command-line overrides (``--set``: trainer.config_keys) ---------------------------------
def dotted_overrides(values: Mapping[str, Any]) -> dict[str, Any]:
    """Dotted keys -> ``load_env_config`` keyword overrides (``section.field`` becomes a dict of
    the section's fields; a key without a dot is a top-level field)."""
    out: dict[str, Any] = {}
    for key, value in values.items():
        section, dot, name = key.partition(".")
        if dot:
            out.setdefault(section, {})[name] = value
        else:
            out[key] = value
    return out


def check_device(device: str, where: str, fix: str) -> None:
    """Refuse a device torch cannot use here: ``where`` names the setting (``--device cuda``),
    ``fix`` what to do instead. Imports torch, so only the commands that need it pay for it."""
    import torch

    try:
        parsed = torch.device(device)
    except (RuntimeError, TypeError, ValueError):
        raise TrainerError(f"{where}: not a torch device: use cpu or cuda[:N]") from None
    if parsed.type not in ("cpu", "cuda"):
        raise TrainerError(f"{where}: not supported (the trainer runs on cpu or cuda[:N]): {fix}")
    if parsed.type == "cuda":
        if not torch.cuda.is_available():
            raise TrainerError(
                f"{where}: no CUDA device is available (torch.cuda.is_available() is False): {fix}"
            )
        if parsed.index is not None and parsed.index >= torch.cuda.device_count():
            raise TrainerError(
                f"{where}: there are only {torch.cuda.device_count()} CUDA device(s): {fix}"
            )


def check_backend(backend: str) -> None:
    """Refuse a backend whose packages are not installed, naming the install command (without
    importing them: ``trainer --help`` and bad options stay fast)."""
    from importlib.util import find_spec

    if backend == "warp" and (find_spec("mujoco_warp") is None or find_spec("warp") is None):
        raise TrainerError(
            "backend warp needs MuJoCo Warp, which is not installed: pip install -e \".[gpu]\" "
            "(or use --backend cpu)"
        )


def config_dict(cfg: Any) -> dict[str, Any]:
    """A config as a JSON-able dict (paths become strings, tuples lists)."""

    def convert(value: Any) -> Any:
        if isinstance(value, Path):
            return str(value)
        if isinstance(value, tuple):
            return [convert(v) for v in value]
        if isinstance(value, dict):
            return {k: convert(v) for k, v in value.items()}
        return value

    return convert(dataclasses.asdict(cfg))
