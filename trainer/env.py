"""The lifting task as a batched TorchRL environment (one object per environment).

Reading order: ``__init__`` (assets, backend, specs), ``_reset``, ``_step``, then the small
task methods ``_apply_action``, ``_get_obs``, ``_get_reward``, ``_get_termination``.

Output keys (batch E):
- ``proprio`` (E, 20): palm keypoint position (3, m), palm orientation (6-d), hand joints (11, rad)
- ``object``: the representation (``trainer.representations``), (E, D) or (E, N, 3)
- ``reward`` (E, 1) and its terms ``reward_lift``, ``reward_success``, ``reward_contact``
- ``success`` (E, 1) bool, ``lift_height`` (E, 1) m, ``object_id`` (E, 1) long,
  ``unstable`` (E, 1) bool: the simulation blew up and the episode was cut (never a crash)
- ``done`` / ``terminated`` (success or object off the table) / ``truncated`` (300 actions)
"""

from __future__ import annotations

import warnings

import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Bounded, Categorical, Composite, Unbounded
from torchrl.envs import EnvBase

from trainer import constants as C
from trainer.assets.scene import build_scene, home_hand_pose, ur5e_home_joints
from trainer.config import ACTION_DIM, EnvConfig
from trainer.init_states import load_or_build_bank
from trainer.kinematics import SiteKinematics, jacobian_transpose_step
from trainer.objects import load_objects, resolve_names
from trainer.representations import object_representation, representation_shape
from trainer.rotations import axis_angle_to_matrix, matrix_to_quat, quat_to_matrix, rotation_6d
from trainer.sim.cpu import MujocoCPUBackend

PROPRIO_DIM = 20


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
                stacklevel=2,
            )
            current = function
            return function(*args)

    return call


class GraspEnv(EnvBase):
    """Lift one object per environment with the UR5e + SIH hand (or the floating hand)."""

    def __init__(self, cfg: EnvConfig, seed: int = 0) -> None:
        super().__init__(device=torch.device(cfg.device), batch_size=torch.Size([cfg.num_envs]))
        self.cfg = cfg
        E = cfg.num_envs
        names = resolve_names(cfg.objects, cfg.data_dir)
        need_sdf = cfg.representation == "sdf" or cfg.reward.kind == "sdf"
        sdf_dtype = torch.float16 if cfg.sdf_dtype == "float16" else torch.float32
        self.objects = load_objects(names, cfg.data_dir, need_sdf, self.device, sdf_dtype)
        # Environment i simulates object env_object[i]; envs are grouped by object so the CPU
        # backend steps each object's model on a contiguous block.
        rng = np.random.default_rng(seed)
        if len(names) <= E:
            env_object = np.arange(E) % len(names)
        else:
            env_object = rng.choice(len(names), size=E, replace=False)
        env_object = np.sort(env_object)
        used = np.unique(env_object)
        models = [build_scene(cfg, self.objects.xml_paths[k]).compile() for k in used]
        self.model = models[0]
        self.backend = MujocoCPUBackend(
            models, np.searchsorted(used, env_object), cfg.physics.substeps, cfg.nthread,
            self.device,
        )
        self.env_object = torch.as_tensor(env_object, device=self.device)
        banks = np.zeros((len(names), cfg.init.bank_size, 7))
        for k in used:
            banks[k] = load_or_build_bank(
                cfg, names[k], self.objects.xml_paths[k], self.objects.mjcf_keys[k]
            )
        self.banks = torch.as_tensor(banks, dtype=torch.float32, device=self.device)

        self._index_model(self.model)
        self.kinematics = SiteKinematics(self.model, ["palm", *C.FINGERTIPS], self.device)
        self.palm_kinematics = SiteKinematics(self.model, ["palm"], self.device)
        self._home_state()

        self._rng = torch.Generator(device=self.device)
        self._rng.manual_seed(seed)
        self.step_count = torch.zeros(E, dtype=torch.long, device=self.device)
        self.start_height = torch.zeros(E, device=self.device)
        self.target_pos = torch.zeros(E, 3, device=self.device)
        self.target_rot = torch.eye(3, device=self.device).repeat(E, 1, 1)
        self.ctrl = self.home_ctrl.repeat(E, 1)
        self.palm_pos = self.home_keypoint.repeat(E, 1)
        self.h_bar = torch.tensor(cfg.reward.h_bar, device=self.device)
        self._pending_restore: dict | None = None
        self._task_outputs = self._task_outputs_eager
        self._commands = self._commands_eager
        if cfg.compile:
            # Fuses the hundreds of small per-step tensor ops into a few C++ loops (graphs are
            # compiled on first use, then cached on disk by torch). Every env instance (each
            # representation, env count, robot) is one more specialization of the same code, and
            # past torch's default limit of 8 it would silently fall back to eager.
            torch._dynamo.config.recompile_limit = max(torch._dynamo.config.recompile_limit, 64)
            self._task_outputs = _compiled_or_eager(self._task_outputs_eager)
            self._commands = _compiled_or_eager(self._commands_eager)
        self._make_specs()

    # --- setup ------------------------------------------------------------------------------
    def _index_model(self, model) -> None:  # noqa: ANN001
        """qpos / actuator indices of the robot and the object (same in every model)."""
        joint = lambda name: int(model.joint(name).qposadr[0])  # noqa: E731
        self.hand_qpos = torch.tensor([joint(n) for n in C.SIH_JOINTS], device=self.device)
        self.hand_act = torch.tensor(
            [model.actuator(a[0]).id for a in C.SIH_ACTUATORS], device=self.device
        )
        self.hand_open = torch.tensor([a[2] for a in C.SIH_ACTUATORS], device=self.device)
        self.hand_closed = torch.tensor([a[3] for a in C.SIH_ACTUATORS], device=self.device)
        object_joint = model.body_jntadr[model.nbody - 1]
        self.obj_qpos = int(model.jnt_qposadr[object_joint])
        self.floating = self.cfg.robot.kind == "floating"
        if self.floating:
            self.base_qpos = joint("hand_free")
        else:
            self.arm_qpos = torch.tensor([joint(n) for n in C.UR5E_JOINTS], device=self.device)
            self.arm_act = torch.tensor(
                [model.actuator(f"a_{n}").id for n in C.UR5E_JOINTS], device=self.device
            )

    def _home_state(self) -> None:
        """Robot qpos and ctrl at reset: hand open, thumb opposed, palm down above the table."""
        qpos = torch.as_tensor(self.model.qpos0, dtype=torch.float32, device=self.device).clone()
        ctrl = torch.zeros(self.model.nu, device=self.device)
        hand = self.hand_open.clone()
        hand[0] = self.hand_closed[0]  # thumb rotation: opposed
        ctrl[self.hand_act] = hand
        qpos[self.hand_qpos[0]] = hand[0]
        keypoint, palm_rot = home_hand_pose(self.cfg)
        self.home_keypoint = torch.as_tensor(keypoint, dtype=torch.float32, device=self.device)
        self.home_rot = torch.as_tensor(palm_rot, dtype=torch.float32, device=self.device)
        if self.floating:
            qpos[self.base_qpos : self.base_qpos + 3] = self.home_keypoint
            qpos[self.base_qpos + 3 : self.base_qpos + 7] = matrix_to_quat(self.home_rot)
        else:
            arm = torch.as_tensor(ur5e_home_joints(self.cfg), dtype=torch.float32)
            qpos[self.arm_qpos] = arm.to(self.device)
            ctrl[self.arm_act] = arm.to(self.device)
        self.home_qpos = qpos
        self.home_ctrl = ctrl

    def _make_specs(self) -> None:
        E = self.cfg.num_envs
        shape = (E, *representation_shape(self.cfg.representation))
        flag = lambda: Categorical(2, shape=(E, 1), dtype=torch.bool, device=self.device)  # noqa: E731
        scalar = lambda: Unbounded(shape=(E, 1), device=self.device)  # noqa: E731
        self.observation_spec = Composite(
            proprio=Unbounded(shape=(E, PROPRIO_DIM), device=self.device),
            object=Unbounded(shape=shape, device=self.device),
            success=flag(),
            unstable=flag(),
            lift_height=scalar(),
            reward_lift=scalar(),
            reward_success=scalar(),
            reward_contact=scalar(),
            object_id=Unbounded(shape=(E, 1), dtype=torch.long, device=self.device),
            shape=(E,),
            device=self.device,
        )
        self.action_spec = Bounded(-1.0, 1.0, shape=(E, ACTION_DIM), device=self.device)
        self.reward_spec = Unbounded(shape=(E, 1), device=self.device)
        self.done_spec = Composite(
            done=flag(), terminated=flag(), truncated=flag(), shape=(E,), device=self.device
        )

    def set_lift_target(self, h_bar: float) -> None:
        """Lift height (m) that earns the success bonus and ends an episode: ``cfg.reward.h_bar``
        unless a training curriculum lowers it."""
        self.h_bar.fill_(h_bar)

    def _set_seed(self, seed: int | None) -> None:
        self._rng.manual_seed(0 if seed is None else seed)

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
        return self._observe(reset=True)

    def _reset_envs(self, ids: torch.Tensor) -> None:
        """Put the robot home and an object from its settled bank (with a random yaw)."""
        n = len(ids)
        pick = torch.randint(self.cfg.init.bank_size, (n,), generator=self._rng, device=self.device)
        pose = self.banks[self.env_object[ids], pick]
        yaw = (torch.rand(n, generator=self._rng, device=self.device) * 2 - 1) * torch.pi
        spin = axis_angle_to_matrix(torch.stack([torch.zeros_like(yaw)] * 2 + [yaw], -1))
        pos = pose[:, :3].clone()
        pos[:, :2] = (spin[:, :2, :2] @ pos[:, :2, None])[..., 0]
        quat = matrix_to_quat(spin @ quat_to_matrix(pose[:, 3:]))
        qpos = self.home_qpos.repeat(n, 1)
        qpos[:, self.obj_qpos : self.obj_qpos + 3] = pos
        qpos[:, self.obj_qpos + 3 : self.obj_qpos + 7] = quat
        self.ctrl[ids] = self.home_ctrl
        mocap = self._mocap(n, self.home_keypoint.expand(n, 3), self.home_rot.expand(n, 3, 3))
        self.backend.set_state(
            ids, qpos, torch.zeros(n, self.backend.nv, device=self.device), self.ctrl[ids], *mocap
        )
        self.step_count[ids] = 0
        self.start_height[ids] = pos[:, 2]
        self.target_pos[ids] = self.home_keypoint
        self.target_rot[ids] = self.home_rot

    # --- checkpoints -------------------------------------------------------------------------
    def snapshot(self) -> dict:
        """The whole state of every env (simulation, commands, counters, random generator): with
        ``restore_on_next_reset`` a resumed run continues exactly where this one stood."""
        return {
            "backend": self.backend.state_dict(),
            "tensors": {
                name: getattr(self, name).clone()
                for name in ("step_count", "start_height", "target_pos", "target_rot", "ctrl")
            },
            "rng": self._rng.get_state(),
        }

    def restore_on_next_reset(self, snapshot: dict) -> None:
        """Make the next full reset (the one a collector does when it starts) put every env back
        into ``snapshot`` instead of drawing new initial states."""
        self._pending_restore = snapshot

    def _restore(self, snapshot: dict) -> None:
        self.backend.load_state_dict(snapshot["backend"])
        for name, value in snapshot["tensors"].items():
            setattr(self, name, value.clone().to(self.device))
        self._rng.set_state(snapshot["rng"])

    def _mocap(
        self, n: int, pos: torch.Tensor, rot: torch.Tensor
    ) -> tuple[torch.Tensor | None, torch.Tensor | None]:
        if not self.floating:
            return None, None
        return pos.reshape(n, 1, 3), matrix_to_quat(rot).reshape(n, 1, 4)

    def mocap_targets(self) -> tuple[torch.Tensor | None, torch.Tensor | None]:
        """The floating hand's current mocap target: (E, 1, 3) and (E, 1, 4), or Nones."""
        return self._mocap(self.num_envs, self.target_pos, self.target_rot)

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        action = tensordict.get("action").clamp(-1.0, 1.0)
        mocap = self._apply_action(action)
        self.backend.step(self.ctrl, *mocap)
        self.step_count += 1
        return self._observe(reset=False)

    # --- task --------------------------------------------------------------------------------
    def _apply_action(self, action: torch.Tensor) -> tuple[torch.Tensor | None, torch.Tensor | None]:  # noqa: E501
        """Move the commanded hand pose by the action and turn it into actuator targets."""
        self.target_pos, self.target_rot, self.ctrl = self._commands(
            action, self.palm_pos, self.target_pos, self.target_rot, self.ctrl, self.backend.qpos
        )
        return self._mocap(self.num_envs, self.target_pos, self.target_rot)

    def _commands_eager(
        self,
        action: torch.Tensor,
        palm_pos: torch.Tensor,
        target_pos: torch.Tensor,
        target_rot: torch.Tensor,
        ctrl: torch.Tensor,
        qpos: torch.Tensor,
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """The new commanded palm pose (E, 3), (E, 3, 3) and actuator targets (E, nu), a pure
        tensor function (``torch.compile`` fuses it when ``cfg.compile``).

        palm_pos: measured at the last observation (the current state); qpos (E, nq)."""
        robot = self.cfg.robot
        # The command accumulates, so small tracking errors do not drift; a leash keeps it near
        # the measured hand when the hand is blocked (by the table or the object).
        lag = (target_pos - palm_pos).clamp(-robot.leash, robot.leash)
        target_pos = palm_pos + lag + action[:, :3] * robot.pos_step
        target_rot = axis_angle_to_matrix(action[:, 3:6] * robot.rot_step) @ target_rot
        hand = self.hand_open + 0.5 * (action[:, 6:] + 1.0) * (self.hand_closed - self.hand_open)
        ctrl = ctrl.clone()
        ctrl[:, self.hand_act] = hand
        if not self.floating:
            # UR5e joint targets by the Jacobian transpose, refining the previous targets.
            qpos = qpos.clone()
            qpos[:, self.arm_qpos] = ctrl[:, self.arm_act]
            ctrl[:, self.arm_act] = jacobian_transpose_step(
                self.palm_kinematics, qpos, self.arm_qpos, C.UR5E_JOINTS, "palm",
                target_pos, target_rot, robot.jt_iterations, robot.jt_rotation_scale,
            )
        return target_pos, target_rot, ctrl

    @property
    def num_envs(self) -> int:
        return self.cfg.num_envs

    def _observe(self, reset: bool) -> TensorDictBase:
        qpos = self.backend.qpos
        obs, terms, flags, palm_pos = self._task_outputs(
            qpos, self.start_height, self.step_count, self.h_bar
        )
        self.palm_pos = palm_pos
        lift = terms.pop("lift_height")
        success, terminated, truncated = flags
        unstable = self.backend.unstable()
        truncated = truncated | unstable
        if reset:
            terms = {k: torch.zeros_like(v) for k, v in terms.items()}
            success = terminated = truncated = unstable = torch.zeros_like(success)
        out = TensorDict(
            {
                **obs,
                "reward_lift": terms["lift"][:, None],
                "reward_success": terms["success"][:, None],
                "reward_contact": terms["contact"][:, None],
                "success": success[:, None],
                "unstable": unstable[:, None],
                "lift_height": lift[:, None],
                "object_id": self.env_object[:, None],
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

    def _task_outputs_eager(
        self,
        qpos: torch.Tensor,
        start_height: torch.Tensor,
        step_count: torch.Tensor,
        h_bar: torch.Tensor,
    ) -> tuple[dict, dict, tuple, torch.Tensor]:
        """Everything the task computes from the simulated state, as a pure tensor function
        (``torch.compile`` fuses it when ``cfg.compile``): (observations, reward terms with
        their sum ``reward`` and ``lift_height``, (success, terminated, truncated), palm
        position (E, 3)). h_bar: the lift target (0-d tensor, m)."""
        poses = self.kinematics.forward(qpos)
        obj_pos = qpos[:, self.obj_qpos : self.obj_qpos + 3]
        obj_quat = qpos[:, self.obj_qpos + 3 : self.obj_qpos + 7]
        tips = poses.site_pos[:, 1:]
        palm_pos, palm_rot = poses.site_pos[:, 0], poses.site_rot[:, 0]
        obs = self._get_obs(qpos, palm_pos, palm_rot, obj_pos, obj_quat, tips)
        # A blown-up env (flagged unstable, truncated, reset next) must not feed NaN to the
        # networks or to the value targets.
        obs = {k: torch.nan_to_num(v, nan=0.0, posinf=0.0, neginf=0.0) for k, v in obs.items()}
        lift = obj_pos[:, 2] - start_height
        terms = self._get_reward(lift, h_bar, tips, obj_pos, obj_quat, obs)
        reward = terms["lift"] + terms["success"] + terms["contact"]
        terms["reward"] = torch.nan_to_num(reward, nan=0.0, posinf=0.0, neginf=0.0)
        terms["lift_height"] = lift
        flags = self._get_termination(lift, h_bar, obj_pos, step_count)
        return obs, terms, flags, palm_pos

    def _get_obs(
        self,
        qpos: torch.Tensor,
        palm_pos: torch.Tensor,
        palm_rot: torch.Tensor,
        obj_pos: torch.Tensor,
        obj_quat: torch.Tensor,
        tips: torch.Tensor,
    ) -> dict[str, torch.Tensor]:
        proprio = torch.cat([palm_pos, rotation_6d(palm_rot), qpos[:, self.hand_qpos]], dim=-1)
        obj = object_representation(
            self.cfg.representation, self.objects, self.env_object, obj_pos, obj_quat, tips
        )
        return {"proprio": proprio, "object": obj}

    def _get_reward(
        self,
        lift: torch.Tensor,
        h_bar: torch.Tensor,
        tips: torch.Tensor,
        obj_pos: torch.Tensor,
        obj_quat: torch.Tensor,
        obs: dict[str, torch.Tensor],
    ) -> dict[str, torch.Tensor]:
        """The paper's reward, term by term (E,) each."""
        r = self.cfg.reward
        terms = {
            "lift": r.c1 / ((h_bar - lift).abs() + r.eps_h),
            "success": r.c2 * (lift >= h_bar).float(),
        }
        if r.kind == "none":
            terms["contact"] = torch.zeros_like(lift)
            return terms
        if r.kind == "sdf":
            if self.cfg.representation == "sdf":
                distance = obs["object"]
            else:
                distance = self.objects.sdf.query(tips, obj_pos, obj_quat, self.env_object)
            # A fingertip pressed into the surface is in contact: its distance is 0, not < 0.
            total = distance.clamp_min(0.0).sum(-1)
        else:
            total = (tips - obj_pos[:, None, :]).norm(dim=-1).sum(-1)
        terms["contact"] = r.c3 / (total + r.eps_sdf)
        return terms

    def _get_termination(
        self, lift: torch.Tensor, h_bar: torch.Tensor, obj_pos: torch.Tensor,
        step_count: torch.Tensor,
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(success, terminated, truncated), each (E,) bool. A blown-up simulation also
        truncates; ``_observe`` adds that from the backend's ``unstable``."""
        success = lift >= h_bar
        fell = obj_pos[:, 2] < self.cfg.fall_height
        return success, success | fell, step_count >= self.cfg.max_steps

    def close(self, *, raise_if_closed: bool = True) -> None:  # noqa: D102
        self.backend.close()
        super().close(raise_if_closed=raise_if_closed)
