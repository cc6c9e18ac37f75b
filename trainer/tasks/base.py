"""The base of every task: a robot (``trainer.robots``: UR5e + SIH hand, or the floating hand)
grasping a *target* object in a scene of object slots, as a batched TorchRL environment.

A task module (``lift.py``, ``bin.py``) subclasses ``GraspTask`` and decides the scene (its
fixtures and slots), which objects fill the slots in each env (``_layouts``), which slot is the
target of an episode (``_choose_targets``) and what else the policy sees (``_extra_obs``). The
base keeps reset and step over the task's state; its parts: the backend
(``trainer.sim.make_backend``), the settled states and the robot's homes above them
(``trainer.init_states``), how episodes start (``trainer.tasks.starts``), the per-step outputs
(``trainer.tasks.outputs``) and the reward's terms (``trainer.tasks.terms``).

Reading order: ``__init__``, ``_reset`` / ``_reset_envs``, ``_step``, ``_observe``.

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

import dataclasses
from typing import ClassVar

import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.envs import EnvBase

from trainer.assets.scene import Scene, slot_qpos_addresses, slot_qvel_addresses
from trainer.config import EnvConfig
from trainer.errors import TrainerError
from trainer.init_states import layout_banks, robot_homes, warn_home_contact
from trainer.kinematics import SiteKinematics
from trainer.objects import ObjectSet, task_names, task_objects
from trainer.randomness import RandomStreams
from trainer.robots import Robot, make_robot
from trainer.sim import make_backend
from trainer.tasks.outputs import StepOutputs, compiled_or_eager, lowest_point, thrown
from trainer.tasks.spec import observation_spec
from trainer.tasks.starts import (
    FixedDrop,
    GraspStart,
    GraspStarts,
    SettledStart,
    StaggeredStart,
    StartStrategy,
    initial_state,
)
from trainer.tasks.terms import (
    paid_terms,
    previous_key,
    reward_output_key,
    reward_terms,
    total_reward,
)


def _slice_layouts(layouts: np.ndarray, env_layout: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(the layouts (L', K) that the envs of ``env_layout`` (E,) (a slice of a run's) use, each
    env's index into them (E,), still non-decreasing)."""
    used, index = np.unique(env_layout, return_inverse=True)
    return layouts[used], index.reshape(-1)


class GraspTask(EnvBase):
    """Grasp the target object of every env with the robot ``cfg.robot.kind`` names."""

    name: ClassVar[str] = ""

    def __init__(
        self, cfg: EnvConfig, seed: int | RandomStreams = 0, shard: tuple[int, int] = (0, 1)
    ) -> None:
        # shard (rank, world): this task steps the rank-th of ``world`` equal slices of the
        # ``cfg.num_envs`` envs of a run spread over processes; its own ``cfg`` counts its slice.
        rank, world = shard
        run_envs = cfg.num_envs
        if world > 1:
            cfg = dataclasses.replace(cfg, num_envs=run_envs // world)
        super().__init__(device=torch.device(cfg.device), batch_size=torch.Size([cfg.num_envs]))
        self.cfg = cfg
        self.run_envs = run_envs  # (the whole run's envs, every process's together)
        E = cfg.num_envs
        names = task_names(cfg)
        self.objects: ObjectSet = task_objects(cfg, names, self.device)
        # One source of randomness (trainer.randomness): the layouts and the episodes' resets
        # draw from their own streams of the run's seed.
        self.streams = seed if isinstance(seed, RandomStreams) else RandomStreams(seed)
        self.scene, layouts, env_layout = self._layouts(len(names), self.streams.numpy("layouts"))
        if world > 1:  # the run's layouts, then this slice's envs and the layouts they use
            layouts, env_layout = _slice_layouts(layouts, env_layout[rank * E:(rank + 1) * E])
        K = self.scene.num_slots
        # Layout l fills slot k with object layouts[l, k]; env i simulates layout env_layout[i]
        # (sorted, so that the CPU backend steps each layout's model on a contiguous block).
        xmls = [[self.objects.xml_paths[k] for k in row] for row in layouts]
        self.backend = make_backend(cfg, self.scene, xmls, env_layout, self.device)
        self.model = self.backend.model
        self.layouts = torch.as_tensor(layouts, device=self.device)
        self.env_layout = torch.as_tensor(env_layout, device=self.device)
        self.assignment = self.layouts[self.env_layout]  # (E, K) object id in each slot
        self.banks = layout_banks(cfg, self.scene, layouts, names, xmls, self.objects.mjcf_keys,
                                  self._bank_size(), self.device)  # (L, B, K, 7)
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
        homes = robot_homes(self.robot, self.model, self.backend.models, self.banks,
                            self.slot_qpos, cfg.robot)
        self.home_qpos, self.home_ctrl, self.home_keypoint = homes.qpos, homes.ctrl, homes.keypoint
        self.home_rot, self.home_index = homes.rot, homes.index
        warn_home_contact(homes, layouts, self.objects.names, cfg.robot)
        self._rng = self.streams.torch("resets", self.device)
        self.terms = reward_terms(cfg.reward)
        self.state = initial_state(cfg, self.terms, homes, self.device)
        # The lift target per object id (O,), m: cfg.reward.h_bar unless a curriculum lowers it.
        self.h_bar = torch.full((len(self.objects.names),), cfg.reward.h_bar, device=self.device)
        self._pending_restore: dict | None = None
        # How reset envs start (trainer.tasks.starts), applied in order: a settled state, then
        # what training adds (``set_grasp_starts``, ``stagger_next_reset``).
        self.starts: list[StartStrategy] = [SettledStart()]
        self.outputs = StepOutputs(cfg, self.objects, self.kinematics, self.slot_qpos,
                                   self.assignment, self.hand_qpos, self.terms, self._extra_obs)
        self._task_outputs, self._commands = self.outputs, self.robot.commands
        if cfg.compile:
            # Fuses the hundreds of small per-step tensor ops into a few C++ loops (graphs are
            # compiled on first use, then cached on disk by torch).
            self._task_outputs = compiled_or_eager(self.outputs)
            self._commands = compiled_or_eager(self.robot.commands)
        spec = observation_spec(cfg, E, self.device)
        self.observation_spec = spec["observation"]
        self.action_spec = spec["action"]
        self.reward_spec = spec["reward"]
        self.done_spec = spec["done"]

    @property
    def home_height(self) -> torch.Tensor:
        """(H,) the palm's height above the table in each home (m)."""
        return self.home_keypoint[:, 2]

    # --- task hooks --------------------------------------------------------------------------
    def _layouts(
        self, num_objects: int, rng: np.random.Generator
    ) -> tuple[Scene, np.ndarray, np.ndarray]:
        """(scene, layouts (L, K) object ids per slot, env_layout (``run_envs``,)
        non-decreasing): for every env of the run (a process of a distributed run keeps its
        slice)."""
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
            raise TrainerError(f"lift targets: {len(h_bar)} given for {len(self.h_bar)} objects")
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
        return lowest_point(self.objects.points[object_id], obj_pos, obj_quat)

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
        for name, term in self.terms.items():
            if term.difference:
                start[previous_key(name)] = torch.full_like(start["start_height"], float("nan"))
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
        self._reset_envs(ids, full=mask is None)
        return self._observe(reset=True)

    def _reset_envs(self, ids: torch.Tensor, full: bool = False) -> None:
        """Start new episodes in envs ``ids`` (n,): each start strategy in turn
        (``self.starts``); ``full``: every env is reset (a collector's first reset)."""
        for start in self.starts:
            start.apply(self, ids, full)

    def stagger_next_reset(self) -> None:
        """Make the next full reset start each env's episode at a random step in
        [0, ``max_steps``) (``ppo.stagger_episodes``; ``StaggeredStart``)."""
        self._use_start(StaggeredStart())

    def _use_start(self, strategy: StartStrategy) -> None:
        """Apply ``strategy`` after the others from now on, in place of one of its kind."""
        self.starts = [s for s in self.starts if type(s) is not type(strategy)] + [strategy]

    def use_fixed_drops(self) -> None:
        """Training only: each env keeps one settled state for good (``FixedDrop`` in place of
        ``SettledStart``, ``[run] fixed_drops``)."""
        self.starts = [FixedDrop() if type(s) is SettledStart else s for s in self.starts]

    def use_reset_generator(self, generator: torch.Generator) -> None:
        """Draw the episodes' initial states from ``generator`` instead of the ``resets``
        stream (the scripted trials of ``trainer.training.grasp_starts``)."""
        self._rng = generator

    def set_grasp_starts(
        self, starts: GraspStarts, fraction: float, generator: torch.Generator
    ) -> None:
        """Training only: a ``fraction`` of the reset envs start from ``starts`` (recorded on
        this task's envs; ``GraspStart``, drawn with ``generator``), flagged ``grasp_start``."""
        if starts.qpos.shape[0] != self.cfg.num_envs or starts.qpos.shape[2] != self.backend.nq:
            raise ValueError("the grasp starts were recorded on another task or number of envs")
        self._use_start(GraspStart(starts.to(self.device), fraction, generator))
        self.state["grasp_start"] = torch.zeros(
            self.cfg.num_envs, dtype=torch.bool, device=self.device
        )

    # --- checkpoints -------------------------------------------------------------------------
    def snapshot(self) -> dict:
        """The whole state of every env (simulation, task state, random generator): with
        ``restore_on_next_reset`` a resumed run continues exactly where this one stood."""
        return {
            "backend": self.backend.state_dict(),
            "state": self.state.clone().to("cpu"),
            "rng": self._rng.get_state(),
            **{k: v for start in self.starts for k, v in start.state_dict().items()},
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
        for start in self.starts:
            start.load_state_dict(snapshot)

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
        terms, previous = paid_terms(self.terms, terms, s)
        s.update(previous)
        terms["reward"] = total_reward(terms)
        success, terminated, truncated = flags
        speed = self.backend.qvel[:, self.slot_linvel].norm(dim=-1)  # (E, K)
        unstable = self.backend.unstable() | thrown(qpos[:, self.slot_qpos[:, :3]], speed)
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
                **{reward_output_key(name): terms[name][:, None] for name in self.terms},
                "success": success[:, None],
                "unstable": unstable[:, None],
                # A copy: a collector keeps each step's outputs until the rollout ends, and
                # the state's flags change at every reset.
                "grasp_start": (
                    s["grasp_start"].clone() if "grasp_start" in s.keys()  # noqa: SIM118
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

    def lift_height(self) -> torch.Tensor:
        """(E,) m: the target's lift in the current state, as the reward and success read it."""
        pos, quat = self.target_pose()
        s = self.state
        return self.outputs.lift(pos, quat, self.target_objects(), s["start_height"],
                                 s.get("start_low", s["start_height"]))

    def _extra_obs(self, slots: torch.Tensor, target_slot: torch.Tensor) -> dict[str, torch.Tensor]:
        """Task-specific observations from every slot's pose (E, K, 7) and the target slot
        (E,): none here."""
        return {}

    def close(self, *, raise_if_closed: bool = True) -> None:  # noqa: D102
        self.backend.close()
        super().close(raise_if_closed=raise_if_closed)
