"""Every knob of the simulation and the task, as data (frozen dataclasses with defaults).

``load_env_config`` overrides any field from a TOML file, one section per dataclass::

    [reward]
    c3 = 0.0
    [physics]
    substeps = 12

Physics choices (documented here because they decide whether a grasp holds): MuJoCo's
``implicitfast`` integrator, elliptic friction cones with ``condim = 4`` (torsional friction
keeps a pinched object from spinning out), sliding friction 1.0 for fingers and objects and 0.8
for the table, the arm and hand gravity-compensated (the arm's PD loop tracks targets rather than
fighting its own weight), and hand position servos stronger than the real SIH's 0.75 N·m.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from geomprep.config import read_toml
from trainer.errors import TrainerError

ACTION_DIM = 11
"""6 hand-pose deltas, then 5 hand DoF targets (thumb rotation, thumb flexion, index, middle,
ring + little), each in [-1, 1]."""
REPRESENTATIONS = ("com", "sdf", "bbox", "sq", "pc32", "pc128", "pc512")
REWARDS = ("sdf", "com", "none")
ROBOTS = ("ur5e", "floating")


@dataclass(frozen=True)
class PhysicsConfig:
    """Simulation timing and contact parameters."""

    control_hz: float = 30.0
    substeps: int = 10
    """Physics steps per action; the timestep is 1 / (control_hz * substeps) s."""
    iterations: int = 20
    ls_iterations: int = 10
    impratio: float = 1.0
    """Frictional-to-normal constraint impedance ratio; above 1 makes friction stiffer (less
    creep of a held object), as MuJoCo recommends with elliptic cones."""
    noslip_iterations: int = 0
    table_size: tuple[float, float, float] = (0.4, 0.4, 0.02)
    """Half-sizes of the table top (m); its top surface is at z = 0."""
    table_friction: tuple[float, float, float] = (0.8, 0.005, 0.0001)
    finger_friction: tuple[float, float, float] = (1.0, 0.01, 0.0001)
    object_friction: tuple[float, float, float] = (1.0, 0.01, 0.0001)
    condim: int = 4
    solref: tuple[float, float] = (0.01, 1.0)
    solimp: tuple[float, float, float, float, float] = (0.9, 0.95, 0.001, 0.5, 2.0)


@dataclass(frozen=True)
class RobotConfig:
    """Arm and hand actuation, and how an action moves them."""

    kind: str = "ur5e"
    """``ur5e`` (arm + hand, Jacobian-transpose control) or ``floating`` (hand on a 6-DoF mocap)."""
    base_pos: tuple[float, float, float] = (0.26, 0.63, -0.23)
    """UR5e base position (m; the table top centre is the origin): beside the table, below its
    top, where the authors' home configuration puts the hand above the table centre."""
    arm_kp: float = 1500.0
    arm_damping: float = 120.0
    arm_armature: float = 0.2
    hand_kp: float = 20.0
    hand_forcerange: float = 5.0
    """Hand servo torque limit (N·m); the real SIH servos give about 0.75 N·m."""
    home_hand_height: float = 0.28
    """Palm keypoint height above the table at reset (m)."""
    pos_step: float = 0.02
    """Hand translation per action at |a| = 1 (m)."""
    rot_step: float = 0.1
    """Hand rotation per action at |a| = 1 (rad)."""
    jt_iterations: int = 2
    """Jacobian-transpose refinements of the arm targets per action (they carry over between
    actions, so the targets keep converging while the command holds still)."""
    jt_rotation_scale: float = 0.2
    """Metres per radian when position and rotation errors share one JT step."""
    leash: float = 0.05
    """The commanded hand position stays within this distance of the measured one (m)."""
    weld_solref: tuple[float, float] = (0.01, 1.0)
    """Softness of the floating hand's weld to its mocap target."""


@dataclass(frozen=True)
class RewardConfig:
    """r = c1 / (|h_bar - dh| + eps_h) + c2 · 1(dh >= h_bar) + c3 / (d + eps_sdf) (the paper)."""

    kind: str = "sdf"
    """``sdf`` (d: fingertip distances to the surface), ``com`` (to the centre of mass) or
    ``none`` (c3 = 0)."""
    h_bar: float = 0.2
    c1: float = 0.5
    c2: float = 5000.0
    c3: float = 1.0
    eps_h: float = 0.02
    eps_sdf: float = 0.025
    h_bar_start: float = 0.2
    """Lift-height curriculum (training only): the target h_bar of the reward and of episode
    success starts here (m) and rises by ``h_bar_increment`` whenever the running training
    success at the current target reaches ``h_bar_promote``, until it is ``h_bar``. Equal to
    ``h_bar`` (the default, the paper): no curriculum. Evaluation always uses ``h_bar``."""
    h_bar_increment: float = 0.02
    h_bar_promote: float = 0.5


@dataclass(frozen=True)
class InitConfig:
    """Initial states: objects dropped at random poses and settled, cached as a bank."""

    bank_size: int = 64
    """Settled poses per object."""
    drop_height: tuple[float, float] = (0.05, 0.15)
    """Lowest object point above the table at release (m)."""
    xy_range: float = 0.08
    """Drop position is uniform in a square of this half-size around the table centre (m)."""
    settle_seconds: float = 1.5
    seed: int = 0


@dataclass(frozen=True)
class EnvConfig:
    """The lifting task."""

    num_envs: int = 64
    representation: str = "sq"
    objects: str = "builtin"
    """Object set: ``builtin``, ``ycb``, ``all``, or a comma list of names."""
    max_steps: int = 300
    fall_height: float = -0.05
    """The object counts as off the table below this height (m, table top at 0)."""
    data_dir: Path = Path("data")
    device: str = "cpu"
    nthread: int = 0
    """Simulation threads; 0 = all cores."""
    sdf_dtype: str = "float16"
    """Storage of the SDF grids (``float16`` or ``float32``): float16 moves a looked-up distance
    by <= 10 um within 2 cm of a surface and halves the memory (78 objects at 200^3: 2.50 GB
    instead of 4.99 GB) and the lookup's memory traffic."""
    compile: bool = False
    """Compile the per-step task computations (kinematics, observations, reward) with
    ``torch.compile``: about 2x less torch time per step at small env counts, after a
    one-off compilation of ~30-60 s per representation (cached on disk). Needs a C++ compiler
    on CPU."""
    physics: PhysicsConfig = field(default_factory=PhysicsConfig)
    robot: RobotConfig = field(default_factory=RobotConfig)
    reward: RewardConfig = field(default_factory=RewardConfig)
    init: InitConfig = field(default_factory=InitConfig)

    def __post_init__(self) -> None:
        if self.representation not in REPRESENTATIONS:
            raise TrainerError(
                f"unknown representation {self.representation!r}: "
                f"choose one of {', '.join(REPRESENTATIONS)}"
            )
        if self.reward.kind not in REWARDS:
            raise TrainerError(
                f"unknown reward {self.reward.kind!r}: choose one of {', '.join(REWARDS)}"
            )
        if self.robot.kind not in ROBOTS:
            raise TrainerError(
                f"unknown robot {self.robot.kind!r}: choose one of {', '.join(ROBOTS)}"
            )
        if self.sdf_dtype not in ("float16", "float32"):
            raise TrainerError(f"unknown sdf_dtype {self.sdf_dtype!r}: choose float16 or float32")
        if self.num_envs < 1:
            raise TrainerError(f"num_envs must be at least 1, got {self.num_envs}")

    @property
    def timestep(self) -> float:
        return 1.0 / (self.physics.control_hz * self.physics.substeps)


@dataclass(frozen=True)
class PPOConfig:
    """PPO and the networks. The paper's schedule: 16,384 envs x 32 steps per rollout, 5 epochs,
    minibatch 32,768 (16 minibatches); with fewer envs the rollout length stays and the rollout
    is cut into at most ``minibatches`` minibatches of at least ``min_minibatch`` frames (tiny
    minibatches would make the update cost, not the simulation, the bottleneck on a CPU)."""

    frames_per_env: int = 32
    """Steps of every env per rollout (one PPO iteration)."""
    epochs: int = 5
    minibatches: int = 16
    min_minibatch: int = 1024
    lr: float = 3e-4
    """Initial learning rate (Adam)."""
    lr_schedule: str = "adaptive"
    """``adaptive``: after every epoch, divide the learning rate by 1.5 when the epoch's mean
    approximate KL to the rollout policy exceeds twice ``kl_target`` and multiply it by 1.5 when
    it is below half of it (rl_games' schedule; the paper trained with rl_games); ``fixed``:
    keep ``lr``."""
    kl_target: float = 0.016
    lr_bounds: tuple[float, float] = (1e-6, 1e-2)
    gamma: float = 0.99
    lmbda: float = 0.95
    clip_epsilon: float = 0.2
    entropy_coef: float = 0.0
    critic_coef: float = 1.0
    max_grad_norm: float = 1.0
    hidden: tuple[int, ...] = (256, 128, 64)
    """The 3-layer MLP of the policy and of the value function."""
    pointnet_hidden: tuple[int, ...] = (64, 128)
    """Shared per-point MLP of the point-cloud encoder (then max pooling)."""
    init_log_std: float = -0.5
    init_action_mean: tuple[float, ...] = (0.0,) * ACTION_DIM
    """Mean action of the untrained policy (the output layer's bias). Zero (the usual choice)
    puts every hand DoF mid-range at the first step; ``[0, 0, 0, 0, 0, 0, 1, -1, -1, -1, -1]``
    keeps the home posture instead (thumb opposed, fingers open), as in the CPU learning run
    of results/cpu-com-builtin-curriculum/."""

    def __post_init__(self) -> None:
        if self.lr_schedule not in ("adaptive", "fixed"):
            raise TrainerError(
                f"unknown lr_schedule {self.lr_schedule!r}: choose adaptive or fixed"
            )


@dataclass(frozen=True)
class RunConfig:
    """The training run: length, seed, bookkeeping."""

    total_steps: int = 10_000_000
    """Environment steps (actions of one env count one) before the run stops."""
    seed: int = 0
    checkpoint_every: int = 10
    """Iterations between checkpoints (the last one is always written)."""
    success_window: int = 0
    """Episodes in the running success rate; 0 = the number of envs."""
    torch_threads: int = 1
    """Threads of torch's own ops (the simulation has its own pool)."""


@dataclass(frozen=True)
class TrainConfig:
    env: EnvConfig = field(default_factory=EnvConfig)
    ppo: PPOConfig = field(default_factory=PPOConfig)
    run: RunConfig = field(default_factory=RunConfig)


def _build(cls: type, values: dict[str, Any], where: str) -> Any:
    fields = {f.name: f for f in dataclasses.fields(cls)}
    kwargs: dict[str, Any] = {}
    for key, value in values.items():
        if key not in fields:
            raise TrainerError(f"{where}: unknown key {key!r}: valid keys are {', '.join(fields)}")
        factory = fields[key].default_factory
        nested = isinstance(factory, type) and dataclasses.is_dataclass(factory)
        if isinstance(value, dict) and nested:
            kwargs[key] = _build(factory, value, f"{where} [{key}]")
        elif isinstance(value, list):
            kwargs[key] = tuple(value)
        elif key == "data_dir":
            kwargs[key] = Path(value)
        else:
            kwargs[key] = value
    return cls(**kwargs)


def _read_toml(path: Path | None) -> dict[str, Any]:
    return {} if path is None else read_toml(path, TrainerError)


def _env_config(values: dict[str, Any], where: str, overrides: dict[str, Any]) -> EnvConfig:
    values = {k: v for k, v in values.items() if k not in ("ppo", "run")}
    cfg = _build(EnvConfig, values, where)
    return dataclasses.replace(cfg, **overrides) if overrides else cfg


def load_env_config(path: Path | None = None, **overrides: Any) -> EnvConfig:
    """Defaults, then the TOML file at ``path``, then keyword ``overrides`` (top-level fields or
    whole sections), e.g. ``load_env_config(representation="sdf", num_envs=16)``."""
    return _env_config(_read_toml(path), str(path or "config"), overrides)


def load_train_config(
    path: Path | None = None,
    env: dict[str, Any] | None = None,
    ppo: dict[str, Any] | None = None,
    run: dict[str, Any] | None = None,
) -> TrainConfig:
    """Defaults, then the TOML file (environment knobs as in ``load_env_config`` plus ``[ppo]``
    and ``[run]`` sections), then the override dicts (command-line options)."""
    values = _read_toml(path)
    where = str(path or "config")
    return TrainConfig(
        _env_config(values, where, env or {}),
        _build(PPOConfig, {**values.get("ppo", {}), **(ppo or {})}, f"{where} [ppo]"),
        _build(RunConfig, {**values.get("run", {}), **(run or {})}, f"{where} [run]"),
    )


def train_config_from_dict(values: dict[str, Any]) -> TrainConfig:
    """The inverse of ``config_dict(train_config)`` (a run directory's config.json)."""
    return TrainConfig(
        _build(EnvConfig, values["env"], "config.json [env]"),
        _build(PPOConfig, values["ppo"], "config.json [ppo]"),
        _build(RunConfig, values["run"], "config.json [run]"),
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
