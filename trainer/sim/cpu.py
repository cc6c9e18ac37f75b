"""CPU backend: MuJoCo's C ``rollout`` on a persistent pool of threads.

One model is compiled per distinct assignment of objects to the scene's slots (one per object
for lift, one per bin layout for bin picking). Environments are sorted by model, so each
model's environments form a contiguous block of the state array. The blocks are cut into
chunks; each pool thread runs
``mujoco.rollout.rollout`` on a chunk with its own ``MjData`` for that model. ``rollout`` releases
the GIL, so the threads step in parallel, and no Python code runs per environment or per
physics step.

With ``sleep`` (``[physics] sleep``) the envs are stepped by MuJoCo's ``mujoco.batch.Batch``
instead, one persistent batch per model (one MjData per env, which sleeping islands need:
``rollout`` starts every control period from the saved state, which wakes every object). The
state array stays the source of truth: each step copies it into the batches' rows and back. The
copy is bitwise, so an island asleep stays asleep; a reset writes new values and wakes it.

**A state MuJoCo cannot step.** A pile of objects can make more constraint rows than a model's
arena holds; MuJoCo then stops with an error (``mj_stackAlloc: out of memory``) instead of
stepping. Such an env is left where it was: its clock does not advance, so it counts as
stalled, the task resets it (``unstable``), and ``drain_warnings`` says how many there were and
which knob to raise (``[physics] memory_mb``). The other envs step as usual.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor

import mujoco
import numpy as np
import torch
from mujoco import rollout
from mujoco.batch import Batch, SimulationError

from trainer.sim.backend import MAX_SPEED, SimBackend

FULL = int(mujoco.mjtState.mjSTATE_FULLPHYSICS)
CONTROL = int(
    mujoco.mjtState.mjSTATE_CTRL
    | mujoco.mjtState.mjSTATE_MOCAP_POS
    | mujoco.mjtState.mjSTATE_MOCAP_QUAT
)
QPOS = int(mujoco.mjtState.mjSTATE_QPOS)
INTEGRATION = int(mujoco.mjtState.mjSTATE_INTEGRATION)
SLEEP = int(mujoco.mjtEnableBit.mjENBL_SLEEP)


def state_offset(model: mujoco.MjModel, component: int, within: int = FULL) -> int:
    """Offset of ``component`` (an mjtState bit inside ``within``) in a ``within`` state."""
    offset = 0
    bit = 1
    while bit < component:
        if within & bit:
            offset += mujoco.mj_stateSize(model, bit)
        bit <<= 1
    return offset


def state_columns(model: mujoco.MjModel, components: int, within: int) -> np.ndarray:
    """Columns of a ``within`` state (a superset of ``components``) that hold the
    ``components`` state, in the order of a ``components`` state."""
    columns = []
    for i in range(int(mujoco.mjtState.mjNSTATE)):
        bit = 1 << i
        if components & bit:
            start = state_offset(model, bit, within)
            columns.append(np.arange(start, start + mujoco.mj_stateSize(model, bit)))
    return np.concatenate(columns)


class MujocoCPUBackend(SimBackend):
    """Steps ``len(env_model)`` environments; environment i simulates ``models[env_model[i]]``.

    models: compiled models with identical nq, nv, nu, nmocap (the same robot, different
    objects); env_model: (E,) int, non-decreasing; substeps: physics steps per ``step``;
    nthread: pool threads (0 = all cores); render_model: builds the full (rendering) model of
    a layout for ``model_for_env`` (default: the stepping model itself); sleep: let resting
    objects sleep (one persistent ``Batch`` per model, see the module docstring).
    """

    def __init__(
        self,
        models: Sequence[mujoco.MjModel],
        env_model: np.ndarray,
        substeps: int,
        nthread: int = 0,
        device: str | torch.device = "cpu",
        render_model: Callable[[int], mujoco.MjModel] | None = None,
        sleep: bool = False,
    ) -> None:
        env_model = np.asarray(env_model, dtype=np.int64)
        if np.any(np.diff(env_model) < 0):
            raise ValueError("env_model must be sorted so that each model's envs are contiguous")
        first = models[0]
        for m in models[1:]:
            if (m.nq, m.nv, m.nu, m.nmocap, m.na) != (first.nq, first.nv, first.nu, first.nmocap, first.na):  # noqa: E501
                raise ValueError("all models must have the same state and control sizes")
        self._set_models(models, env_model, render_model)
        self.num_envs = len(env_model)
        self.device = torch.device(device)
        self.nq, self.nv, self.nu, self.nmocap = first.nq, first.nv, first.nu, first.nmocap
        self.substeps = substeps
        self.timestep = float(first.opt.timestep)
        self.nthread = nthread or os.cpu_count() or 1
        self.nstate = mujoco.mj_stateSize(first, FULL)
        qpos_start = state_offset(first, QPOS)
        self._qpos = slice(qpos_start, qpos_start + self.nq)
        self._qvel = slice(self._qpos.stop, self._qpos.stop + self.nv)
        self._state = np.zeros((self.num_envs, self.nstate))
        for k, m in enumerate(self.models):
            data = mujoco.MjData(m)
            row = np.empty(self.nstate)
            mujoco.mj_getState(m, data, row, FULL)
            self._state[env_model == k] = row
        # rollout's per-substep output (unused with sleep, which steps persistent batches)
        self._out = np.empty((0 if sleep else self.num_envs, substeps, self.nstate))
        # Controls are held over the control period; rollout wants one row per physics step.
        self._control = np.zeros((self.num_envs, substeps, mujoco.mj_stateSize(first, CONTROL)))
        self._chunks = self._make_chunks()
        self._local = threading.local()
        self._pool = ThreadPoolExecutor(self.nthread, thread_name_prefix="mujoco")
        self._cache: dict[str, torch.Tensor] = {}
        self._stalled = np.zeros(self.num_envs, dtype=bool)
        # Envs MuJoCo refused to step in the last period (written by the pool threads, each its
        # own rows), how many since the last drain_warnings, and MuJoCo's message.
        self._refused = np.zeros(self.num_envs, dtype=bool)
        self._refusals = 0
        self._refusal = ""
        self.sleep = sleep
        self._batches: list[tuple[np.ndarray, Batch]] = []
        if sleep:
            self._full_columns = state_columns(first, FULL, INTEGRATION)
            self._control_columns = state_columns(first, CONTROL, INTEGRATION)
            for k, model in enumerate(self.models):
                ids = np.flatnonzero(self.env_layout == k)
                if len(ids) == 0:
                    continue
                model = model.__copy__()  # the sleeping copy; videos and memory use the originals
                model.opt.enableflags |= SLEEP
                # nthread=1: the batch runs on the pool thread that calls it (``_step_batch``).
                batch = Batch(model, nsim=len(ids), nthread=1, persistent=True)
                self._batches.append((ids, batch))

    def _make_chunks(self) -> list[tuple[int, int, int]]:
        """(model, start, stop) pieces: about 4 per thread so the threads finish together."""
        target = max(1, self.num_envs // (4 * self.nthread))
        chunks = []
        for k in range(len(self.models)):
            ids = np.flatnonzero(self.env_layout == k)
            if len(ids) == 0:
                continue
            for start in range(ids[0], ids[-1] + 1, target):
                chunks.append((k, start, min(start + target, ids[-1] + 1)))
        return chunks

    def _thread_local(self, k: int) -> tuple[rollout.Rollout, mujoco.MjData]:
        if not hasattr(self._local, "datas"):
            # nthread=0: each pool thread runs its chunk itself, with the GIL released.
            self._local.runner = rollout.Rollout(nthread=0)
            self._local.datas = {}
        if k not in self._local.datas:
            self._local.datas[k] = mujoco.MjData(self.models[k])
        return self._local.runner, self._local.datas[k]

    def _rollout(self, k: int, start: int, stop: int, out: np.ndarray) -> None:
        """Envs ``start:stop`` (all of model ``k``) by one control period, into ``out``."""
        runner, data = self._thread_local(k)
        runner.rollout(
            [self.models[k]] * (stop - start),
            [data],
            self._state[start:stop],
            self._control[start:stop],
            control_spec=CONTROL,
            nstep=self.substeps,
            state=out,
            skip_checks=True,
        )

    def _run(self, chunk: tuple[int, int, int]) -> None:
        k, start, stop = chunk
        try:
            self._rollout(k, start, stop, self._out[start:stop])
        except mujoco.FatalError:
            # One env of the chunk could not be stepped, and rollout gave up on the rest:
            # each env again on its own (the same states and controls, so the same result).
            for i in range(start, stop):
                self._run_alone(k, i, self._out[i : i + 1])

    def _run_alone(self, k: int, i: int, out: np.ndarray) -> None:
        """Env ``i`` alone into ``out`` (1, substeps, nstate); where MuJoCo refuses to step it,
        its state as it was (time not advanced: stalled) and the env noted as refused."""
        try:
            self._rollout(k, i, i + 1, out)
        except mujoco.FatalError as exc:
            del self._local.datas[k]  # its stack was left as the error found it: a new one
            out[0] = self._state[i]
            self._refused[i] = True
            self._refusal = str(exc).splitlines()[0]

    def _step_batch(self, item: tuple[np.ndarray, Batch]) -> None:
        ids, batch = item
        batch.state[:, self._full_columns] = self._state[ids]
        batch.state[:, self._control_columns] = self._control[ids, 0]
        try:
            batch.step(nstep=self.substeps)
        except SimulationError as exc:
            # The others stepped; the ones MuJoCo refused kept their state (time not advanced).
            self._refused[ids[exc.ids]] = True
            self._refusal = batch.error(int(exc.ids[0])).splitlines()[0]
        self._state[ids] = batch.state[:, self._full_columns]

    def _advance(self) -> None:
        """Every env by one control period, the controls held."""
        if self.sleep:
            list(self._pool.map(self._step_batch, self._batches))
        else:
            list(self._pool.map(self._run, self._chunks))
            self._state[:] = self._out[:, -1]

    def step(
        self,
        ctrl: torch.Tensor,
        mocap_pos: torch.Tensor | None = None,
        mocap_quat: torch.Tensor | None = None,
    ) -> None:
        self._write_control(slice(None), ctrl, mocap_pos, mocap_quat)
        time_before = self._state[:, 0].copy()
        self._refused[:] = False
        self._advance()
        self._refusals += int(self._refused.sum())
        # MuJoCo resets an environment whose accelerations go bad (and rollout stops stepping
        # it); both show as a clock that did not advance by the control period.
        advanced = self._state[:, 0] - time_before
        self._stalled = np.abs(advanced - self.substeps * self.timestep) > 0.5 * self.timestep
        self._cache.clear()

    def set_state(
        self,
        env_ids: torch.Tensor,
        qpos: torch.Tensor,
        qvel: torch.Tensor,
        ctrl: torch.Tensor,
        mocap_pos: torch.Tensor | None = None,
        mocap_quat: torch.Tensor | None = None,
    ) -> None:
        ids = env_ids.detach().cpu().numpy()
        self._state[ids] = 0.0
        self._state[ids, self._qpos] = qpos.detach().cpu().double().numpy()
        self._state[ids, self._qvel] = qvel.detach().cpu().double().numpy()
        self._write_control(ids, ctrl, mocap_pos, mocap_quat)
        self._stalled[ids] = False
        self._cache.clear()

    def _write_control(
        self,
        rows: slice | np.ndarray,
        ctrl: torch.Tensor,
        mocap_pos: torch.Tensor | None,
        mocap_quat: torch.Tensor | None,
    ) -> None:
        parts = [ctrl.detach().reshape(ctrl.shape[0], -1)]
        if self.nmocap:
            if mocap_pos is None or mocap_quat is None:
                raise ValueError("this model has mocap bodies: pass mocap_pos and mocap_quat")
            parts += [mocap_pos.detach().reshape(ctrl.shape[0], -1)]
            parts += [mocap_quat.detach().reshape(ctrl.shape[0], -1)]
        row = torch.cat(parts, dim=1).to("cpu", torch.float64).numpy()
        self._control[rows] = row[:, None, :]

    def _view(self, key: str, columns: slice) -> torch.Tensor:
        if key not in self._cache:
            self._cache[key] = torch.from_numpy(self._state[:, columns].astype(np.float32)).to(self.device)  # noqa: E501
        return self._cache[key]

    @property
    def qpos(self) -> torch.Tensor:
        return self._view("qpos", self._qpos)

    @property
    def qvel(self) -> torch.Tensor:
        return self._view("qvel", self._qvel)

    def unstable(self) -> torch.Tensor:
        finite = np.isfinite(self._state).all(axis=1)
        fast = (np.abs(self._state[:, self._qvel]) > MAX_SPEED).any(axis=1)
        return torch.from_numpy(~finite | fast | self._stalled).to(self.device)

    def drain_warnings(self) -> list[str]:
        if not self._refusals:
            return []
        count, self._refusals = self._refusals, 0
        size = self.models[0].narena / 2**20
        return [f"MuJoCo could not step {count} env step(s) ({self._refusal}); those envs were "
                f"reset: raise [physics] memory_mb (now {size:.0f} MB per env's arena)"]

    def state_dict(self) -> dict:
        return {"state": self._state.copy(), "stalled": self._stalled.copy()}

    def load_state_dict(self, state: dict) -> None:
        if state["state"].shape != self._state.shape:
            raise ValueError("the saved simulation state is for a different set of envs/models")
        self._state[:] = state["state"]
        self._stalled[:] = state["stalled"]
        self._cache.clear()

    def memory(self) -> dict[str, int]:
        """``models``: the stepping models' buffers; ``data``: one MjData per model and pool
        thread at most, or with ``sleep`` one per env (their contact/constraint arenas are
        reserved address space, resident only as used, and not counted); ``state``: the state,
        output and control arrays."""
        if self.sleep:
            data = sum(mujoco.MjData(b.model).nbuffer * len(ids) for ids, b in self._batches)
        else:
            data = sum(mujoco.MjData(m).nbuffer for m in self.models) * self.nthread
        arrays = self._state.nbytes + self._out.nbytes + self._control.nbytes
        return {"models": sum(m.nbuffer for m in self.models), "data": data, "state": arrays}

    def step_held(self) -> None:
        self._advance()

    def snapshot(self, env_id: int) -> tuple[mujoco.MjModel, mujoco.MjData]:  # noqa: D102
        model = self.models[int(self.env_layout[env_id])]
        data = mujoco.MjData(model)
        mujoco.mj_setState(model, data, self._state[env_id], FULL)
        mujoco.mj_setState(model, data, self._control[env_id, 0], CONTROL)
        mujoco.mj_forward(model, data)
        return model, data

    def close(self) -> None:
        self._pool.shutdown(wait=True)
