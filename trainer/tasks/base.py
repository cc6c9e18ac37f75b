"""The base of every task: a robot (``trainer.robots``: UR5e + SIH hand, or the floating hand)
grasping a *target* object in a scene of object slots, as a batched TorchRL environment.

A task module (``lift.py``, ``bin.py``) subclasses ``GraspTask`` and decides the scene (its
fixtures and slots), which objects fill the slots in each env (``_layouts``), which slot is the
target of an episode (``_choose_targets``) and what else the policy sees (``_get_obs``). The
base owns everything the tasks share: the backend (``trainer.sim.make_backend``), the settled
initial states, the robot (``self.robot``, which turns actions into commands), the paper's
reward and success applied to the target, resets, and checkpoints.

Reading order: ``__init__``, ``_reset`` / ``_reset_envs``, ``_step``, ``_task_outputs_eager``
and the task hooks ``_get_obs``, ``_get_reward``, ``_get_termination``.

Output keys (batch E; see ``trainer.tasks.observation_spec``):
- ``proprio`` (E, 20): palm keypoint position (3, m), palm orientation (6-d), hand joints (11, rad)
  (E, 35) with ``observe_fingertips``: then the 5 fingertip pads' positions (15, m, world);
  with ``observe_hand_targets`` then (last) the 5 servo targets (-1 open, +1 closed)
- ``object``: the target's representation (``trainer.representations``), (E, D) or (E, N, 3)
- ``context`` (E, K-1, 10) and ``context_mask`` (E, K-1): the other objects' boxes (bin task
  with ``context = "bbox"`` only)
- ``reward`` (E, 1) and its terms ``reward_<name>`` (E, 1): ``reward_lift``,
  ``reward_success``, ``reward_contact`` (the table in ``trainer.tasks.terms``)
- ``success`` (E, 1) bool, ``lift_height`` (E, 1) m (the target's), ``object_id`` (E, 1) long
  (the target's object id), ``unstable`` (E, 1) bool: the simulation blew up and the episode
  was cut (never a crash)
- ``done`` / ``terminated`` (success or target off the table) / ``truncated`` (max_steps)

Per-env task state lives in one ``TensorDict`` (``self.state``): resets write its masked rows,
checkpoints clone it, so no task keeps state anywhere else.
"""

from __future__ import annotations

import warnings
from typing import TYPE_CHECKING, ClassVar

import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.envs import EnvBase

from geomgrasp.rotations import axis_angle_to_matrix, matrix_to_quat, quat_to_matrix, rotation_6d
from trainer.assets.collision import BIT_HAND
from trainer.assets.scene import Scene, slot_qpos_addresses, slot_qvel_addresses
from trainer.config import EnvConfig
from trainer.errors import TrainerError, TrainerWarning
from trainer.init_states import hand_touches, load_or_build_bank
from trainer.kinematics import SiteKinematics
from trainer.objects import ObjectSet, load_objects, resolve_names
from trainer.randomness import RandomStreams
from trainer.representations import object_representation
from trainer.robots import Robot, make_robot
from trainer.sim import make_backend
from trainer.tasks.spec import observation_spec
from trainer.tasks.terms import (
    StepQuantities,
    evaluate_terms,
    reward_output_key,
    reward_terms,
    total_reward,
)

if TYPE_CHECKING:
    from trainer.training.grasp_starts import GraspStarts

ESCAPE_DISTANCE = 2.0
"""An object higher than this above the table top, or farther than this from its centre (m), is
out of the UR5e's reach (0.85 m from its base): only a blown-up contact puts it there."""
LAUNCH_SPEED = 10.0
"""An object moving faster than this (m/s) was launched by a blown-up contact: the arm moves the
hand at ~1 m/s and an object falling off the table reaches ~1 m/s before it is reset."""
HOME_RAISE = 0.01
"""``[robot] home_above_objects``: the home height rises in steps of this (m) ..."""
HOME_RAISE_STEPS = 30
"""... at most this many (0.3 m); a state still touched there starts touched, with a warning."""
HOME_CHECK_YAWS = 16
"""The home-contact check turns each settled state to this many yaws (every 22.5 degrees)."""


def turned(pose: torch.Tensor, yaw: torch.Tensor) -> torch.Tensor:
    """Slot poses ``pose`` (n, K, 7) (position, quaternion) turned by ``yaw`` (n,) rad about the
    vertical axis through the origin."""
    spin = axis_angle_to_matrix(torch.stack([torch.zeros_like(yaw)] * 2 + [yaw], -1))
    pos = (spin[:, None] @ pose[..., :3, None])[..., 0]
    quat = matrix_to_quat(spin[:, None] @ quat_to_matrix(pose[..., 3:]))
    return torch.cat([pos, quat], dim=-1)


def _compiled_or_eager(function):  # noqa: ANN001, ANN202
    """``torch.compile(function)``, or ``function`` itself (with one warning) if compiling fails,
    e.g. on a machine without a C++ compiler or Python headers: slower, never broken."""
    current = torch.compile(function, dynamic=False)

    def call(*args):  # noqa: ANN002, ANN202
        nonlocal current
        try:
            return current(*args)
        except torch._dynamo.exc.BackendCompilerFailed as err:
            warnings.warn(
                f"torch.compile failed ({str(err).splitlines()[0][:200]}); the env runs eagerly "
                "(install g++ and the Python headers, or pass --no-compile)",
                TrainerWarning,
                stacklevel=2,
            )
            current = function
            return function(*args)

    return call


class GraspTask(EnvBase):
    """Grasp the target object of every env with the robot ``cfg.robot.kind`` names."""

    name: ClassVar[str] = ""

    def __init__(self, cfg: EnvConfig, seed: int | RandomStreams = 0) -> None:
        super().__init__(device=torch.device(cfg.device), batch_size=torch.Size([cfg.num_envs]))
        self.cfg = cfg
        E = cfg.num_envs
        names = resolve_names(cfg.objects, cfg.data_dir)
        # The SDF: for the representation, the reward's fingertip distances, or to tell a held
        # lift from a toss (reward.hold_tips).
        need_sdf = (
            cfg.representation == "sdf" or cfg.reward.kind.startswith("sdf")
            or cfg.reward.hold_tips > 0
        )
        sdf_dtype = torch.float16 if cfg.sdf_dtype == "float16" else torch.float32
        self.objects: ObjectSet = load_objects(
            names, cfg.data_dir, need_sdf, self.device, sdf_dtype
        )
        # One source of randomness (trainer.randomness): the layouts and the episodes' resets
        # draw from their own streams of the run's seed.
        self.streams = seed if isinstance(seed, RandomStreams) else RandomStreams(seed)
        self.scene, layouts, env_layout = self._layouts(
            len(names), self.streams.numpy("layouts")
        )
        K = self.scene.num_slots
        # Layout l fills slot k with object layouts[l, k]; env i simulates layout env_layout[i]
        # (sorted, so that the CPU backend steps each layout's model on a contiguous block).
        xmls = [[self.objects.xml_paths[k] for k in row] for row in layouts]
        self.backend = make_backend(cfg, self.scene, xmls, env_layout, self.device)
        self.model = self.backend.model
        self.layouts = torch.as_tensor(layouts, device=self.device)
        self.env_layout = torch.as_tensor(env_layout, device=self.device)
        self.assignment = self.layouts[self.env_layout]  # (E, K) object id in each slot
        bank_size = self._bank_size()
        banks = np.stack([
            load_or_build_bank(
                cfg, self.scene, [names[k] for k in row], xmls[i],
                [self.objects.mjcf_keys[k] for k in row], bank_size,
            )
            for i, row in enumerate(layouts)
        ])
        self.banks = torch.as_tensor(banks, dtype=torch.float32, device=self.device)  # (L,B,K,7)
        address = torch.as_tensor(slot_qpos_addresses(self.model, K), device=self.device)
        self.slot_qpos = address[:, None] + torch.arange(7, device=self.device)  # (K, 7)
        address = torch.as_tensor(slot_qvel_addresses(self.model, K), device=self.device)
        self.slot_linvel = address[:, None] + torch.arange(3, device=self.device)  # (K, 3)

        self.robot: Robot = make_robot(cfg.robot)
        self.robot.index(self.model, self.device)
        self.hand_qpos = self.robot.hand_qpos  # (11,) qpos addresses of the hand's joints
        self.kinematics = SiteKinematics(self.model, self.robot.sites, self.device)
        # The robot's states at reset (home_qpos (H, nq) etc.) and which one each settled state
        # of each layout starts from (home_index (L, B)).
        self._set_homes()
        self._rng = self.streams.torch("resets", self.device)
        self.state = TensorDict(
            {
                "step_count": torch.zeros(E, dtype=torch.long),
                "start_height": torch.zeros(E),
                "target_slot": torch.zeros(E, dtype=torch.long),
                "target_pos": self.home_keypoint[0].repeat(E, 1),
                "target_rot": self.home_rot.repeat(E, 1, 1),
                "ctrl": self.home_ctrl[0].repeat(E, 1),
                "palm_pos": self.home_keypoint[0].repeat(E, 1),
            },
            batch_size=[E],
            device=self.device,
        )
        if cfg.reward.contact_shaping == "difference":
            # The contact term's value at the previous step (E,); NaN right after a reset (the
            # next observation sets it): only with this shaping, as start_low below.
            self.state["contact_prev"] = torch.full((E,), float("nan"), device=self.device)
        if cfg.reward.lift_clearance > 0:
            # The target's lowest surface point at the episode's start (E,), m: only with
            # ``reward.lift_clearance``, so that runs without it keep their saved task state.
            self.state["start_low"] = torch.zeros(E, device=self.device)
        # The lift target per object id (O,), m: cfg.reward.h_bar unless a curriculum lowers it.
        self.h_bar = torch.full(
            (len(self.objects.names),), cfg.reward.h_bar, device=self.device
        )
        self._pending_restore: dict | None = None
        self._stagger_next_reset = False
        # Training only (``set_grasp_starts``): scripted-grasp states some resets start from.
        self._grasp_starts: GraspStarts | None = None
        self._grasp_fraction = 0.0
        self._grasp_rng: torch.Generator | None = None
        self._task_outputs = self._task_outputs_eager
        self._commands = self.robot.commands
        if cfg.compile:
            # Fuses the hundreds of small per-step tensor ops into a few C++ loops (graphs are
            # compiled on first use, then cached on disk by torch). Every env instance (each
            # representation, env count, robot) is one more specialization of the same code, and
            # past torch's default limit of 8 it would silently fall back to eager.
            torch._dynamo.config.recompile_limit = max(torch._dynamo.config.recompile_limit, 64)
            self._task_outputs = _compiled_or_eager(self._task_outputs_eager)
            self._commands = _compiled_or_eager(self.robot.commands)
        spec = observation_spec(cfg, E, self.device)
        self.observation_spec = spec["observation"]
        self.action_spec = spec["action"]
        self.reward_spec = spec["reward"]
        self.done_spec = spec["done"]

    def _set_homes(self) -> None:
        """The robot's reset states: ``home_qpos`` (H, nq), ``home_ctrl`` (H, nu),
        ``home_keypoint`` (H, 3) m and ``home_height`` (H,) m for H home heights, the first
        ``home_hand_height``, each next 1 cm higher; ``home_rot`` (3, 3), the same for all; and
        ``home_index`` (L, B): the home each settled state of each layout starts from. Without
        ``home_above_objects`` that is the first (H = 1); with it, the lowest at which the
        hand touches none of the state's objects. Then one warning if the hand at home still
        touches some object (``_warn_home_contact``)."""
        base = self.cfg.robot.home_hand_height
        steps = HOME_RAISE_STEPS if self.cfg.robot.home_above_objects else 0
        L, B = self.banks.shape[:2]
        index = np.zeros((L, B), dtype=np.int64)
        touched = np.zeros((L, B, self.banks.shape[2]), dtype=bool)
        pending = np.ones((L, B), dtype=bool)  # states the hand still touches at this height
        homes = []
        for step in range(steps + 1):
            homes.append(self.robot.home(self.model, base + HOME_RAISE * step))
            for layout in np.flatnonzero(pending.any(1)):
                states = np.flatnonzero(pending[layout])
                hit = self._hand_touches(layout, homes[-1].qpos, states)
                index[layout, states] = step
                touched[layout, states] = hit
                pending[layout, states] = hit.any(1)
            if not pending.any():
                break
        self.home_qpos = torch.stack([h.qpos for h in homes])
        self.home_ctrl = torch.stack([h.ctrl for h in homes])
        self.home_keypoint = torch.stack([h.keypoint for h in homes])
        self.home_rot = homes[0].rot
        self.home_index = torch.as_tensor(index, device=self.device)
        self._warn_home_contact(touched)

    @property
    def home_height(self) -> torch.Tensor:
        """(H,) the palm's height above the table in each home (m)."""
        return self.home_keypoint[:, 2]

    def _hand_touches(
        self, layout: int, home_qpos: torch.Tensor, states: np.ndarray
    ) -> np.ndarray:
        """(len(states), K) bool: in which of the settled ``states`` (indices into the bank) of
        ``layout`` the robot at ``home_qpos`` (nq,) touches slot k's object, at any of
        ``HOME_CHECK_YAWS`` turns of the state about the vertical axis (a reset turns it by a
        random one): MuJoCo's collision detection on the layout's model."""
        poses = self.banks[layout, torch.as_tensor(states, device=self.device)]  # (S, K, 7)
        yaws = torch.arange(HOME_CHECK_YAWS, device=self.device) * (2 * torch.pi / HOME_CHECK_YAWS)
        poses = turned(poses.repeat_interleave(HOME_CHECK_YAWS, 0), yaws.repeat(len(states)))
        hits = hand_touches(
            self.backend.models[layout], home_qpos.cpu().numpy(), poses.cpu().numpy(),
            self.slot_qpos.cpu().numpy(), BIT_HAND,
        )
        return hits.reshape(len(states), HOME_CHECK_YAWS, -1).any(1)

    def _warn_home_contact(self, touched: np.ndarray) -> None:
        """One warning if the hand at its home pose touches some object in its settled states
        (``touched`` (L, B, K) bool): those episodes start with the hand already on (or in) the
        object, whose first steps then push it around (a lift may even count) without any
        action."""
        ids = self.layouts.cpu().numpy()[:, None, :].repeat(touched.shape[1], 1)
        clash = [(int(touched[ids == k].sum()), int((ids == k).sum()), name)
                 for k, name in enumerate(self.objects.names) if touched[ids == k].any()]
        if clash:
            clash.sort(key=lambda c: -c[0] / c[1])
            names = ", ".join(f"{n} ({a} of {b})" for a, b, n in clash[:10])
            more = f" and {len(clash) - 10} more" if len(clash) > 10 else ""
            height = float(self.home_height[-1])
            fix = ("raise [robot] home_hand_height" if self.cfg.robot.home_above_objects else
                   "set [robot] home_above_objects = true, raise home_hand_height")
            warnings.warn(
                f"the hand at its home pose touches settled states of {names}{more}: those "
                f"episodes start with the hand on the object; {fix} (now {height:.2f} m) or "
                "leave them out",
                TrainerWarning,
                stacklevel=4,
            )

    # --- task hooks --------------------------------------------------------------------------
    def _layouts(
        self, num_objects: int, rng: np.random.Generator
    ) -> tuple[Scene, np.ndarray, np.ndarray]:
        """(scene, layouts (L, K) object ids per slot, env_layout (E,) non-decreasing)."""
        raise NotImplementedError

    def _bank_size(self) -> int:
        """Settled states per layout."""
        raise NotImplementedError

    def _choose_targets(self, n: int) -> torch.Tensor:
        """(n,) target slot of each new episode."""
        raise NotImplementedError

    def _reset_yaw(self, n: int) -> torch.Tensor:
        """(n,) rotation (rad) of a settled state about the vertical axis through the origin."""
        raise NotImplementedError

    # --- setup ------------------------------------------------------------------------------
    def set_lift_target(self, h_bar: float | list[float]) -> None:
        """Lift height (m) that earns the success bonus and ends an episode: ``cfg.reward.h_bar``
        unless a training curriculum lowers it; one value for every object, or one per object
        id (a list of ``len(objects.names)``)."""
        if isinstance(h_bar, (int, float)):
            self.h_bar.fill_(h_bar)
            return
        if len(h_bar) != len(self.h_bar):
            raise TrainerError(
                f"lift targets: {len(h_bar)} given for {len(self.h_bar)} objects"
            )
        self.h_bar.copy_(torch.tensor(h_bar, dtype=self.h_bar.dtype))

    def _set_seed(self, seed: int | None) -> None:
        # TorchRL's ``set_seed``: evaluation and videos seed their episodes with it.
        streams = RandomStreams(0 if seed is None else seed, legacy=self.streams.legacy)
        self._rng.manual_seed(streams.seed_of("resets"))

    @property
    def num_envs(self) -> int:
        return self.cfg.num_envs

    # --- what the target is --------------------------------------------------------------------
    def slot_poses(self, qpos: torch.Tensor) -> torch.Tensor:
        """(E, K, 7) every slot's object pose: position (m) and quaternion (w, x, y, z)."""
        return qpos[:, self.slot_qpos]

    def target_objects(self, target_slot: torch.Tensor | None = None) -> torch.Tensor:
        """(E,) object id of each env's target."""
        slot = self.state["target_slot"] if target_slot is None else target_slot
        return self.assignment.gather(1, slot[:, None])[:, 0]

    def lowest_point(
        self, obj_pos: torch.Tensor, obj_quat: torch.Tensor, object_id: torch.Tensor
    ) -> torch.Tensor:
        """(n,) m: the height of the lowest of each object's 512 surface samples, the object at
        obj_pos (n, 3) with quaternion obj_quat (n, 4) (w, x, y, z); object_id (n,)."""
        vertical = quat_to_matrix(obj_quat)[:, 2, :]  # (n, 3) the world z axis in the object frame
        heights = torch.einsum("npk,nk->np", self.objects.points[object_id], vertical)
        return heights.amin(-1) + obj_pos[:, 2]

    def _episode_start(
        self, poses: torch.Tensor, target_slot: torch.Tensor, object_id: torch.Tensor
    ) -> dict[str, torch.Tensor]:
        """What the lift is measured from, (n,) m each, for slot poses (n, K, 7), the target's
        slot (n,) and object id (n,): ``start_height`` (its centre) and, with
        ``reward.lift_clearance``, ``start_low`` (its lowest surface point)."""
        pose = poses.gather(1, target_slot[:, None, None].expand(-1, 1, 7))[:, 0]
        start = {"start_height": pose[:, 2]}
        if self.cfg.reward.lift_clearance > 0:
            start["start_low"] = self.lowest_point(pose[:, :3], pose[:, 3:], object_id)
        if self.cfg.reward.contact_shaping == "difference":
            start["contact_prev"] = torch.full_like(start["start_height"], float("nan"))
        return start

    def target_pose(self, qpos: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """The target's position (E, 3) and quaternion (E, 4) in the world."""
        poses = self.slot_poses(self.backend.qpos if qpos is None else qpos)
        index = self.state["target_slot"][:, None, None].expand(-1, 1, 7)
        pose = poses.gather(1, index)[:, 0]
        return pose[:, :3], pose[:, 3:]

    def set_targets(self, slots: torch.Tensor) -> TensorDictBase:
        """Right after a reset: make slot ``slots[i]`` (E,) the target of env i's episode
        (``slots[i] < 0`` keeps the drawn one); its lift is measured from its height now.
        Returns the reset observation of the new targets (evaluation balances targets with it)."""
        slots = slots.to(self.device)
        keep = slots < 0
        target = torch.where(keep, self.state["target_slot"], slots)
        start = self._episode_start(self.slot_poses(self.backend.qpos), target,
                                    self.target_objects(target))
        for key, value in start.items():
            self.state[key] = torch.where(keep, self.state[key], value)
        self.state["target_slot"] = target
        return self._observe(reset=True)

    # --- TorchRL interface -------------------------------------------------------------------
    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDictBase:  # noqa: ANN003
        E = self.cfg.num_envs
        mask = None if tensordict is None else tensordict.get("_reset", None)
        if self._pending_restore is not None and (mask is None or bool(mask.all())):
            self._restore(self._pending_restore)
            self._pending_restore = None
            return self._observe(reset=True)
        if mask is None:
            ids = torch.arange(E, device=self.device)
        else:
            ids = mask.reshape(E).nonzero()[:, 0]
        if len(ids):
            self._reset_envs(ids)
        if self._stagger_next_reset and mask is None:
            self._stagger_next_reset = False
            self.state["step_count"] = torch.randint(
                self.cfg.max_steps, (E,), generator=self._rng, device=self.device
            )
        return self._observe(reset=True)

    def _reset_envs(self, ids: torch.Tensor) -> None:
        """Put the robot home and the objects in a settled state of the env's layout, turned
        about the vertical axis; choose the episode's target."""
        n = len(ids)
        pick = torch.randint(self.banks.shape[1], (n,), generator=self._rng, device=self.device)
        pose = self.banks[self.env_layout[ids], pick]  # (n, K, 7)
        pose = turned(pose, self._reset_yaw(n))
        home = self.home_index[self.env_layout[ids], pick]
        qpos = self.home_qpos[home]
        qpos[:, self.slot_qpos] = pose
        target_slot = self._choose_targets(n)
        fresh = TensorDict(
            {
                "step_count": torch.zeros(n, dtype=torch.long, device=self.device),
                **self._episode_start(
                    pose, target_slot, self.assignment[ids].gather(1, target_slot[:, None])[:, 0]
                ),
                "target_slot": target_slot,
                "target_pos": self.home_keypoint[home],
                "target_rot": self.home_rot.expand(n, 3, 3),
                "ctrl": self.home_ctrl[home],
                "palm_pos": self.home_keypoint[home],
            },
            batch_size=[n],
            device=self.device,
        )
        if self._grasp_starts is not None:
            fresh["grasp_start"] = torch.zeros(n, dtype=torch.bool, device=self.device)
        self.state[ids] = fresh
        mocap = self.robot.mocap(fresh["target_pos"], fresh["target_rot"])
        self.backend.set_state(
            ids, qpos, torch.zeros(n, self.backend.nv, device=self.device), fresh["ctrl"], *mocap
        )
        if self._grasp_starts is not None:
            self._start_from_grasps(ids)

    def stagger_next_reset(self) -> None:
        """Make the next full reset start each env's episode at a random step in
        [0, ``max_steps``) (``ppo.stagger_episodes``): the episodes then reach ``max_steps``
        spread over the following rollouts instead of all in the same step."""
        self._stagger_next_reset = True

    def use_reset_generator(self, generator: torch.Generator) -> None:
        """Draw the episodes' initial states from ``generator`` instead of the ``resets``
        stream (the scripted trials of ``trainer.training.grasp_starts``)."""
        self._rng = generator

    def set_grasp_starts(
        self, starts: GraspStarts, fraction: float, generator: torch.Generator
    ) -> None:
        """Training only: from now on each reset of env i starts, with probability
        ``fraction``, from one of ``starts``' valid states of env i (drawn with ``generator``)
        instead of a settled state with the hand home; the output ``grasp_start`` flags those
        episodes. ``starts`` must be recorded on this task's envs (the same config and
        ``num_envs``: ``trainer.training.grasp_starts.record_grasp_starts``)."""
        if starts.qpos.shape[0] != self.cfg.num_envs or starts.qpos.shape[2] != self.backend.nq:
            raise ValueError("the grasp starts were recorded on another task or number of envs")
        self._grasp_starts = starts.to(self.device)
        self._grasp_fraction = fraction
        self._grasp_rng = generator
        self.state["grasp_start"] = torch.zeros(
            self.cfg.num_envs, dtype=torch.bool, device=self.device
        )

    def _start_from_grasps(self, ids: torch.Tensor) -> None:
        """Put a ``fraction`` of the just-reset envs ``ids`` (those with a valid grasp start)
        into one of their recorded scripted-grasp states, drawn uniformly among those whose
        target had not yet risen to its object's current lift target (``self.h_bar``): a
        state past it would start an episode that has already succeeded."""
        starts = self._grasp_starts
        assert starts is not None
        valid = starts.valid[ids]  # (n, S)
        if starts.lift is not None:
            below = self.h_bar[self.target_objects()[ids]]  # (n,) m
            valid = valid & (starts.lift[ids] < below[:, None])
        draw = torch.rand(len(ids), generator=self._grasp_rng, device=self.device)
        chosen = (draw < self._grasp_fraction) & valid.any(1)
        pick = torch.multinomial(valid.float() + 1e-12, 1, generator=self._grasp_rng)[:, 0]
        ids, pick = ids[chosen], pick[chosen]
        if len(ids) == 0:
            return
        task = starts.task[ids, pick]
        for key in task.keys():  # noqa: SIM118 (a TensorDict)
            self.state[key][ids] = task[key]
        self.state["grasp_start"][ids] = True
        qpos, qvel = starts.qpos[ids, pick], starts.qvel[ids, pick]
        mocap = self.robot.mocap(task["target_pos"], task["target_rot"])
        self.backend.set_state(ids, qpos, qvel, task["ctrl"], *mocap)

    # --- checkpoints -------------------------------------------------------------------------
    def snapshot(self) -> dict:
        """The whole state of every env (simulation, task state, random generator): with
        ``restore_on_next_reset`` a resumed run continues exactly where this one stood."""
        return {
            "backend": self.backend.state_dict(),
            "state": self.state.clone().to("cpu"),
            "rng": self._rng.get_state(),
            **({} if self._grasp_rng is None else {"grasp_rng": self._grasp_rng.get_state()}),
        }

    def restore_on_next_reset(self, snapshot: dict) -> None:
        """Make the next full reset (the one a collector does when it starts) put every env back
        into ``snapshot`` instead of drawing new initial states."""
        self._pending_restore = snapshot

    def _restore(self, snapshot: dict) -> None:
        self.backend.load_state_dict(snapshot["backend"])
        state = snapshot["state"]
        if set(state.keys()) != set(self.state.keys()) or state.batch_size != self.state.batch_size:  # noqa: E501
            raise ValueError("the saved task state is for another task or number of envs")
        self.state.update_(state.to(self.device))
        self._rng.set_state(snapshot["rng"])
        if self._grasp_rng is not None and "grasp_rng" in snapshot:
            self._grasp_rng.set_state(snapshot["grasp_rng"])

    def mocap_targets(self) -> tuple[torch.Tensor | None, torch.Tensor | None]:
        """The robot's current mocap targets (the floating hand's: (E, 1, 3) and (E, 1, 4)), or
        Nones."""
        return self.robot.mocap(self.state["target_pos"], self.state["target_rot"])

    def hold(self) -> None:
        """One control period holding the current commands, with nothing else updated (videos
        keep rolling after the episodes end)."""
        self.backend.step(self.state["ctrl"], *self.mocap_targets())

    def hold_action(self) -> torch.Tensor:
        """(E, action_dim) the action that keeps the current commands: no palm motion and the
        hand's current actuator targets (``trainer play`` holds a finished episode's grasp with
        it while the other episodes go on, instead of letting the policy act past its end)."""
        return self.robot.hold_action(self.state["ctrl"])

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        action = tensordict.get("action").clamp(-1.0, 1.0)
        s = self.state
        target_pos, target_rot, ctrl = self._commands(
            action, s["palm_pos"], s["target_pos"], s["target_rot"], s["ctrl"], self.backend.qpos
        )
        s["target_pos"], s["target_rot"], s["ctrl"] = target_pos, target_rot, ctrl
        self.backend.step(ctrl, *self.robot.mocap(target_pos, target_rot))
        s["step_count"] += 1
        return self._observe(reset=False)

    # --- observation, reward, termination ----------------------------------------------------
    def _observe(self, reset: bool) -> TensorDictBase:
        qpos = self.backend.qpos
        s = self.state
        obs, terms, flags, palm_pos = self._task_outputs(
            qpos, s["start_height"], s.get("start_low", s["start_height"]), s["step_count"],
            s["target_slot"], self.h_bar,
        )
        s["palm_pos"] = palm_pos
        if self.cfg.observe_hand_targets:
            # Controller state, not simulated state: joined here, outside the pure function.
            targets = self.robot.hand.targets(s["ctrl"])
            obs = {**obs, "proprio": torch.cat([obs["proprio"], targets], dim=-1)}
        lift = terms.pop("lift_height")
        if self.cfg.reward.contact_shaping == "difference":
            terms = self._contact_difference(terms)
        success, terminated, truncated = flags
        unstable = self.backend.unstable() | self._thrown(qpos)
        # A blown-up step neither succeeds nor terminates (it truncates) and earns nothing.
        success = success & ~unstable
        terminated = terminated & ~unstable
        truncated = truncated | unstable
        terms["reward"] = terms["reward"].masked_fill(unstable, 0.0)
        if reset:
            terms = {k: torch.zeros_like(v) for k, v in terms.items()}
            success = terminated = truncated = unstable = torch.zeros_like(success)
        out = TensorDict(
            {
                **obs,
                **{
                    reward_output_key(name): terms[name][:, None]
                    for name in reward_terms(self.cfg.reward)
                },
                "success": success[:, None],
                "unstable": unstable[:, None],
                # A copy: a collector keeps each step's outputs until the rollout ends, and
                # the state's flags change at every reset.
                "grasp_start": (
                    s["grasp_start"].clone() if self._grasp_starts is not None
                    else torch.zeros_like(success)
                )[:, None],
                "lift_height": lift[:, None],
                "object_id": self.target_objects()[:, None],
                "terminated": terminated[:, None],
                "truncated": truncated[:, None],
                "done": (terminated | truncated)[:, None],
            },
            batch_size=self.batch_size,
            device=self.device,
        )
        if not reset:
            out["reward"] = terms["reward"][:, None]
        return out

    def _contact_difference(self, terms: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        """``reward.contact_shaping = "difference"``: the contact term (E,) becomes its change
        since the previous observation, and the reward is summed again. An env just reset
        (``contact_prev`` NaN) starts from its value now, and earns 0 on its reset observation,
        which carries no reward anyway."""
        now = terms["contact"]
        prev = self.state["contact_prev"]
        prev = torch.where(prev.isnan(), now, prev)
        self.state["contact_prev"] = now
        terms = {**terms, "contact": now - prev}
        names = reward_terms(self.cfg.reward)
        terms["reward"] = total_reward({name: terms[name] for name in names})
        return terms

    def _task_outputs_eager(
        self,
        qpos: torch.Tensor,
        start_height: torch.Tensor,
        start_low: torch.Tensor,
        step_count: torch.Tensor,
        target_slot: torch.Tensor,
        h_bars: torch.Tensor,
    ) -> tuple[dict, dict, tuple, torch.Tensor]:
        """Everything the task computes from the simulated state, as a pure tensor function
        (``torch.compile`` fuses it when ``cfg.compile``): (observations, reward terms with
        their sum ``reward`` and ``lift_height``, (success, terminated, truncated), palm
        position (E, 3)). start_height, start_low (E,): the target's centre and lowest surface
        point at the episode's start (start_low read only with ``reward.lift_clearance``), m;
        h_bars: the lift target per object id (O,), m."""
        poses = self.kinematics.forward(qpos)
        slots = self.slot_poses(qpos)  # (E, K, 7)
        target = slots.gather(1, target_slot[:, None, None].expand(-1, 1, 7))[:, 0]
        target_id = self.assignment.gather(1, target_slot[:, None])[:, 0]
        h_bar = h_bars[target_id]  # (E,)
        obj_pos, obj_quat = target[:, :3], target[:, 3:]
        tips = poses.site_pos[:, 1:]
        palm_pos, palm_rot = poses.site_pos[:, 0], poses.site_rot[:, 0]
        obs = self._get_obs(qpos, palm_pos, palm_rot, target_id, obj_pos, obj_quat, tips, slots,
                            target_slot)
        # A blown-up env (flagged unstable, truncated, reset next) must not feed NaN to the
        # networks or to the value targets.
        obs = {
            k: v if v.dtype == torch.bool else torch.nan_to_num(v, nan=0.0, posinf=0.0, neginf=0.0)
            for k, v in obs.items()
        }
        lift = self._lift(obj_pos, obj_quat, target_id, start_height, start_low)
        if self.cfg.representation == "sdf":
            tip_distance = obs["object"]  # the same query: the fingertips' signed distances
        elif self.objects.sdf is not None:
            tip_distance = self.objects.sdf.query(tips, obj_pos, obj_quat, target_id)
        else:  # no SDF is needed: the com reward and no hold condition (hold_tips = 0)
            tip_distance = torch.zeros_like(tips[..., 0])
        flags = self._get_termination(lift, h_bar, tip_distance, obj_pos, step_count)
        terms = self._get_reward(lift, h_bar, flags[0], tips, tip_distance, obj_pos)
        terms["reward"] = total_reward(terms)
        terms["lift_height"] = lift
        return obs, terms, flags, palm_pos

    def _thrown(self, qpos: torch.Tensor) -> torch.Tensor:
        """(E,) bool: some object was launched by a blown-up contact: it is out of the robot's
        reach (``ESCAPE_DISTANCE``) or faster than ``LAUNCH_SPEED``. The backend's ``unstable``
        misses this: rises of hundreds of metres were seen with impratio 10, every speed finite
        and below its MAX_SPEED, and the object counted as lifted on its way up."""
        pos = qpos[:, self.slot_qpos[:, :3]]  # (E, K, 3)
        speed = self.backend.qvel[:, self.slot_linvel].norm(dim=-1)  # (E, K)
        far = (pos[..., 2] > ESCAPE_DISTANCE) | (pos[..., :2].norm(dim=-1) > ESCAPE_DISTANCE)
        return (far | (speed > LAUNCH_SPEED)).any(1)

    def _lift(
        self, obj_pos: torch.Tensor, obj_quat: torch.Tensor, target_id: torch.Tensor,
        start_height: torch.Tensor, start_low: torch.Tensor,
    ) -> torch.Tensor:
        """(E,) m: the target's lift, the rise of its centre once it is clear of where it rested
        (obj_pos (E, 3), obj_quat (E, 4), target_id (E,); start_height, start_low (E,) as
        ``_task_outputs_eager``'s)."""
        lift = obj_pos[:, 2] - start_height
        if self.cfg.reward.lift_clearance > 0:
            # Until the target is clear of where it rested, its lift is its lowest point's rise:
            # a tipped object's centre rises, its lowest point does not.
            low_rise = self.lowest_point(obj_pos, obj_quat, target_id) - start_low
            lift = torch.where(low_rise >= self.cfg.reward.lift_clearance, lift, low_rise)
        return lift

    def lift_height(self) -> torch.Tensor:
        """(E,) m: the target's lift in the current state, as the reward and success read it."""
        pos, quat = self.target_pose()
        s = self.state
        return self._lift(pos, quat, self.target_objects(), s["start_height"],
                          s.get("start_low", s["start_height"]))

    def _get_obs(
        self,
        qpos: torch.Tensor,
        palm_pos: torch.Tensor,
        palm_rot: torch.Tensor,
        target_id: torch.Tensor,
        obj_pos: torch.Tensor,
        obj_quat: torch.Tensor,
        tips: torch.Tensor,
        slots: torch.Tensor,
        target_slot: torch.Tensor,
    ) -> dict[str, torch.Tensor]:
        """The robot's proprioception and the target's representation, then what the task adds
        (``_extra_obs``)."""
        parts = [palm_pos, rotation_6d(palm_rot), qpos[:, self.hand_qpos]]
        if self.cfg.observe_fingertips:
            parts.append(tips.reshape(tips.shape[0], -1))
        proprio = torch.cat(parts, dim=-1)
        obj = object_representation(
            self.cfg.representation, self.objects, target_id, obj_pos, obj_quat, tips
        )
        return {"proprio": proprio, "object": obj, **self._extra_obs(slots, target_slot)}

    def _extra_obs(
        self, slots: torch.Tensor, target_slot: torch.Tensor
    ) -> dict[str, torch.Tensor]:
        """Task-specific observations from every slot's pose (E, K, 7) and the target slot
        (E,): none here."""
        return {}

    def _get_reward(
        self,
        lift: torch.Tensor,
        h_bar: torch.Tensor,
        success: torch.Tensor,
        tips: torch.Tensor,
        tip_distance: torch.Tensor,
        obj_pos: torch.Tensor,
    ) -> dict[str, torch.Tensor]:
        """The reward's weighted terms on the target (E,) each, by name in summation order
        (``trainer.tasks.terms.reward_terms``: the paper's, or an ablation, per ``[reward]``).
        lift (E,) m; h_bar (E,) m; success (E,) bool (``_get_termination``); tips (E, 5, 3)
        fingertip pads; tip_distance (E, 5) their signed distances to the target's surface (m);
        obj_pos (E, 3) m."""
        r = self.cfg.reward
        quantities = StepQuantities(lift, h_bar, success, tips, tip_distance, obj_pos)
        return evaluate_terms(reward_terms(r), quantities, r)

    def _get_termination(
        self, lift: torch.Tensor, h_bar: torch.Tensor, tip_distance: torch.Tensor,
        obj_pos: torch.Tensor, step_count: torch.Tensor,
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(success, terminated, truncated), each (E,) bool: success is the target lifted by
        h_bar while held, ``reward.hold_tips`` fingertip pads within ``reward.hold_distance`` of
        its surface (tip_distance (E, 5), m): a toss through h_bar is not a lift (below a
        training target of ``reward.hold_from`` it is). A blown-up simulation also truncates;
        ``_observe`` adds that from the backend's ``unstable``."""
        r = self.cfg.reward
        held = (tip_distance < r.hold_distance).sum(-1) >= r.hold_tips
        held = held | (h_bar < r.hold_from)
        success = (lift >= h_bar) & held
        fell = obj_pos[:, 2] < self.cfg.fall_height
        return success, success | fell, step_count >= self.cfg.max_steps

    def close(self, *, raise_if_closed: bool = True) -> None:  # noqa: D102
        self.backend.close()
        super().close(raise_if_closed=raise_if_closed)
