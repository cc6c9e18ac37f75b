"""GPU backend: MuJoCo Warp, every environment a *world* of one batched model, torch end to end.

**One model for every object.** All worlds step one ``mujoco_warp`` model with one launch per
kernel, whatever objects they hold. The model is the scene with each slot body carrying ``H``
mesh geoms, ``H`` the most convex hulls of any object in the set, and the hull meshes of every
object in the set, each used by a static *library geom* that collides with nothing and is absent
from every world (only so that MuJoCo compiles the hull graph and polygons of every mesh, which
MuJoCo Warp's multi-point convex contacts need: without them a knife resting on the table gets
one contact point and tips 9 mm into it). A world selects its own objects through MuJoCo
Warp's *batched* model fields (arrays with a leading world dimension, read as
``field[world % batch]``):

* ``geom_dataid``: which mesh each slot geom is, ``-1`` for the slots an object with fewer hulls
  leaves empty. MuJoCo Warp treats a mesh geom with ``dataid = -1`` as absent from that world
  (its broad phase skips it), so an unused slot collides with nothing;
* ``geom_pos/quat/size/aabb/rbound`` and the contact parameters of those geoms (MuJoCo centres
  each mesh at its centroid, so a hull's placement belongs to the hull);
* ``body_mass/inertia/ipos/iquat/subtreemass/invweight0`` and ``dof_invweight0``: the object's
  mass properties and what the constraint solver derives from them.

Each world's values are copied from the MuJoCo C model of its own assignment (compiled exactly
as the CPU backend compiles it), so the two backends simulate the same objects. This is the
per-world geometry that MuJoCo Warp added for heterogeneous worlds (batched ``geom_dataid``,
as mjlab uses for per-environment object variants); the alternatives were one model per object
(78 launches per kernel per step) or every hull of every object present in every world and
parked away (78x the broad phase). The batch is one row per world (not one per distinct
assignment read with ``world % L``), so the envs keep the task's order; the price is memory:
the per-world geom fields hold every geom of the model, library geoms included (78 YCB objects:
~1,700 geoms, ~200 bytes each per world, ~3.5 GB at 16,384 worlds; unmeasured on a GPU).

**Torch end to end.** ``qpos``, ``qvel``, ``ctrl``, mocap targets and the overflow flags are
Warp arrays viewed as torch tensors (``wp.to_torch``: same memory, same device, no copies).
Controls are written into those views, resets write only the chosen worlds' rows, and nothing is
read back to the host during a step; on CUDA, Warp runs on a stream of its own, ordered after
and before torch's current stream by stream waits (a graph cannot be captured on the legacy
default stream, which is torch's usual one), and the ``substeps`` physics steps of one control
period are one captured CUDA graph (first run on an H100: results/gpu-h100-first/).

**Buffers.** Contacts live in one pool for all worlds (``contacts_per_world`` x worlds) and
constraints in per-world rows (``constraints_per_world``); both are derived from the scene
unless ``[warp]`` sets them. MuJoCo Warp flags a world whose constraints overflow (and every
world when the shared contact pool does); such worlds are ``unstable`` (the task truncates and
resets them, ``metrics.csv`` counts them) and ``drain_warnings`` names the knob to raise.

Precision: MuJoCo Warp computes in float32 (MuJoCo C in float64); ``tests/test_warp.py`` states
how closely the two agree.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from contextlib import nullcontext
from dataclasses import fields, is_dataclass
from pathlib import Path

import mujoco
import numpy as np
import torch
import warp as wp

from trainer.assets.scene import Scene, build_scene, slot_name, strip_visuals
from trainer.config import EnvConfig
from trainer.sim.backend import MAX_SPEED, SimBackend

# Before MuJoCo Warp initialises Warp: no line per compiled or loaded kernel module.
wp.config.log_level = wp.LOG_WARNING
import mujoco_warp as mjw  # noqa: E402, I001

BODY_FIELDS = (
    "body_mass", "body_inertia", "body_ipos", "body_iquat", "body_subtreemass", "body_invweight0",
)
DOF_FIELDS = ("dof_invweight0",)
GEOM_FIELDS = (
    "geom_dataid", "geom_size", "geom_aabb", "geom_rbound", "geom_pos", "geom_quat",
    "geom_friction", "geom_solref", "geom_solimp", "geom_solmix", "geom_margin", "geom_gap",
)
LIBRARY_GEOM = "library_geom"
LIBRARY_CONTYPE = 1 << 30
"""The library geoms' collision bit: in no geom's conaffinity, so they collide with nothing."""
PER_WORLD_FIELDS = BODY_FIELDS + DOF_FIELDS + GEOM_FIELDS
"""The model fields that differ between worlds (each gets a leading world dimension)."""

BUFFER_OVERFLOWS = int(
    mjw.OverflowType.NEFC | mjw.OverflowType.NJMAX_NNZ | mjw.OverflowType.BROADPHASE
    | mjw.OverflowType.NARROWPHASE | mjw.OverflowType.CCD | mjw.OverflowType.EPA_HORIZON
)
"""Overflows that lose contacts or constraints (solver iteration limits are not among them)."""
KNOB = {
    int(mjw.OverflowType.NEFC): "[warp] constraints_per_world",
    int(mjw.OverflowType.NJMAX_NNZ): "[warp] constraints_per_world",
    int(mjw.OverflowType.BROADPHASE): "[warp] contacts_per_world",
    int(mjw.OverflowType.NARROWPHASE): "[warp] contacts_per_world",
    int(mjw.OverflowType.CCD): "[warp] contacts_per_world",
    int(mjw.OverflowType.EPA_HORIZON): "[warp] contacts_per_world",
}


def warp_device(device: torch.device) -> str:
    """The Warp device of a torch device (``cpu`` -> ``cpu``, ``cuda[:N]`` -> ``cuda:N``)."""
    if device.type == "cuda":
        return f"cuda:{device.index if device.index is not None else torch.cuda.current_device()}"
    return "cpu"


# --- the batched model ----------------------------------------------------------------------
def _slot_geoms(model: mujoco.MjModel, k: int) -> range:
    body = model.body(slot_name(k)).id
    start = int(model.body_geomadr[body])
    return range(start, start + int(model.body_geomnum[body]))


def build_batched_model(
    cfg: EnvConfig,
    scene: Scene,
    layouts: Sequence[Sequence[Path]],
    models: Sequence[mujoco.MjModel],
) -> tuple[mujoco.MjModel, dict[str, np.ndarray]]:
    """The one model every world steps, and each layout's values of ``PER_WORLD_FIELDS``.

    layouts: L assignments (the MJCF files in the K slots); models: their compiled MuJoCo C
    stepping models (``build_scene(..., visual=False)``). Returns the merged model and, per
    field, an array (L, *MjModel field shape) holding layout l's values in the merged model's
    geom order."""
    K = scene.num_slots
    hulls = max((len(_slot_geoms(m, k)) for m in models for k in range(K)), default=1)
    spec = build_scene(cfg, scene, layouts[0], visual=False)
    # Every object's hull meshes, attached once: the attached body is deleted again, so the
    # merged model has the scene's bodies and joints, and the meshes compile exactly as in each
    # layout's own model. MuJoCo computes a mesh's convex-hull graph and polygons (which MuJoCo
    # Warp's multi-point convex collisions need) only for meshes that a colliding geom uses, so
    # each library mesh gets a static *library geom* that collides with nothing (a contype bit
    # no geom has in its conaffinity) and is absent from every world (dataid -1).
    library: dict[str, str] = {}
    for xml in dict.fromkeys(Path(x) for row in layouts for x in row):
        prefix = f"lib{len(library)}/"
        child = mujoco.MjSpec.from_file(str(xml))
        strip_visuals(child)
        body = spec.worldbody.add_frame().attach_body(child.body(xml.stem), prefix, "")
        meshes = [geom.meshname for geom in body.geoms]
        spec.delete(body)
        for i, mesh_name in enumerate(meshes):
            geom = spec.worldbody.add_geom()
            geom.name = f"{prefix}{LIBRARY_GEOM}{i}"
            geom.type = mujoco.mjtGeom.mjGEOM_MESH
            geom.meshname = mesh_name
            geom.contype, geom.conaffinity, geom.group = LIBRARY_CONTYPE, 0, 5
        library[str(xml)] = prefix
    for k in range(K):
        body = spec.body(slot_name(k))
        geoms = list(body.geoms)
        first = geoms[0]
        for _ in range(hulls - len(geoms)):
            extra = body.add_geom()
            for attr in ("type", "meshname", "contype", "conaffinity", "condim", "friction",
                         "solref", "solimp", "solmix", "margin", "gap", "priority", "group",
                         "rgba"):
                setattr(extra, attr, getattr(first, attr))
    merged = spec.compile()

    for m in models:
        if m.nbody != merged.nbody or m.nv != merged.nv or m.nq != merged.nq:
            raise ValueError("a layout's model differs from the merged model beyond its geoms")
    values: dict[str, list[np.ndarray]] = {name: [] for name in PER_WORLD_FIELDS}
    slot_ranges = [_slot_geoms(merged, k) for k in range(K)]
    in_slot = np.zeros(merged.ngeom, dtype=bool)
    for r in slot_ranges:
        in_slot[list(r)] = True
    in_library = np.array([LIBRARY_GEOM in merged.geom(g).name for g in range(merged.ngeom)])
    fixed = np.flatnonzero(~in_slot & ~in_library)  # robot, fixtures: in every layout, in order
    for m, row in zip(models, layouts, strict=True):
        for name in BODY_FIELDS + DOF_FIELDS:
            values[name].append(np.array(getattr(m, name)))
        # Where each of this layout's geoms sits in the merged model: its robot and fixture
        # geoms in the same order, slot k's hulls in the first of slot k's H geoms.
        dst_of = np.empty(m.ngeom, dtype=np.int64)
        own = np.zeros(m.ngeom, dtype=bool)
        for k in range(K):
            for i, g in enumerate(_slot_geoms(m, k)):
                dst_of[g] = slot_ranges[k][i]
                own[g] = True
        if int((~own).sum()) != len(fixed):
            raise ValueError("a layout's robot and fixtures differ from the merged model's")
        dst_of[~own] = fixed
        for name in GEOM_FIELDS:
            out = np.array(getattr(merged, name))  # the empty hull slots keep these values
            out[dst_of] = getattr(m, name)
            if name == "geom_dataid":
                out[in_library] = -1
                for k in range(K):
                    out[list(slot_ranges[k])] = -1  # empty slots: absent from this world
                    prefix = library[str(Path(row[k]))]
                    for i, g in enumerate(_slot_geoms(m, k)):
                        mesh_name = m.mesh(int(m.geom_dataid[g])).name.split("/", 1)[1]
                        mesh = merged.mesh(prefix + mesh_name).id
                        _check_same_mesh(m, int(m.geom_dataid[g]), merged, mesh)
                        out[slot_ranges[k][i]] = mesh
            values[name].append(out)
    return merged, {name: np.stack(v) for name, v in values.items()}


def _check_same_mesh(a: mujoco.MjModel, i: int, b: mujoco.MjModel, j: int) -> None:
    """The merged model's mesh ``j`` is the layout model's mesh ``i`` (same vertices)."""
    va = a.mesh_vert[a.mesh_vertadr[i]: a.mesh_vertadr[i] + a.mesh_vertnum[i]]
    vb = b.mesh_vert[b.mesh_vertadr[j]: b.mesh_vertadr[j] + b.mesh_vertnum[j]]
    if va.shape != vb.shape or not np.allclose(va, vb, atol=1e-9):
        raise ValueError(f"mesh {b.mesh(j).name} compiled differently in the merged model")


def derived_buffers(cfg: EnvConfig, model: mujoco.MjModel, num_slots: int) -> tuple[int, int]:
    """(contacts, constraints) per world: ``[warp]`` values, or derived from the scene.

    Derived: 4 contact points for each colliding geom of the robot and 8 per object (resting
    on its support and touching a neighbour), times ``buffer_margin``; a contact takes
    ``condim`` constraint rows (elliptic cones), plus one row per limited joint and six per
    equality. Measured with MuJoCo C on the Table I objects (scripted reach-and-close, 32 envs):
    at most 43 contacts per world in lift, 98 in a 10-object bin; the derived sizes are 120 and
    228 (margin 1.5)."""
    w = cfg.warp
    slot_geom = np.zeros(model.ngeom, dtype=bool)
    for k in range(num_slots):
        slot_geom[list(_slot_geoms(model, k))] = True
    movable = model.body_weldid[model.geom_bodyid] != 0
    colliding = (model.geom_contype | model.geom_conaffinity) != 0
    robot = int(np.sum(movable & colliding & ~slot_geom))
    contacts = w.contacts_per_world or math.ceil(w.buffer_margin * (4 * robot + 8 * num_slots))
    rows = int(model.jnt_limited.sum()) + 6 * model.neq
    constraints = w.constraints_per_world or contacts * int(cfg.physics.condim) + rows
    return contacts, constraints


# --- the backend ----------------------------------------------------------------------------
class MujocoWarpBackend(SimBackend):
    """E worlds of one MuJoCo Warp model; world i holds layout ``env_layout[i]``.

    merged: the batched model (``build_batched_model``); per_layout: its per-layout field values;
    models: the layouts' MuJoCo C models (``model``, ``model_for_env`` and rendering);
    contacts, constraints: buffer sizes per world; render_model: the full model of a layout."""

    def __init__(
        self,
        merged: mujoco.MjModel,
        per_layout: dict[str, np.ndarray],
        models: Sequence[mujoco.MjModel],
        env_layout: np.ndarray,
        substeps: int,
        contacts: int,
        constraints: int,
        device: str | torch.device = "cpu",
        render_model: Callable[[int], mujoco.MjModel] | None = None,
    ) -> None:
        self.device = torch.device(device)
        self._set_models(models, env_layout, render_model)
        self.merged = merged
        self.num_envs = E = len(self.env_layout)
        self.nq, self.nv, self.nu, self.nmocap = merged.nq, merged.nv, merged.nu, merged.nmocap
        self.substeps = substeps
        self.contacts, self.constraints = contacts, constraints
        self._wp_device = wp.get_device(warp_device(self.device))
        # On CUDA the physics runs on a stream of its own (a CUDA graph cannot be captured on
        # the default stream, torch's usual one), ordered after and before torch's current
        # stream by stream waits: no host synchronization.
        self._torch_stream = torch.cuda.Stream(self.device) if self.device.type == "cuda" else None
        self._stream = (
            wp.stream_from_torch(self._torch_stream) if self._torch_stream is not None else None
        )
        with wp.ScopedDevice(self._wp_device):
            self.m = mjw.put_model(merged, batch_sizes=dict.fromkeys(PER_WORLD_FIELDS, E))
            for name in PER_WORLD_FIELDS:
                array = getattr(self.m, name)
                rows = per_layout[name][self.env_layout]  # (E, *MjModel field shape)
                shape = array.shape + tuple(getattr(array.dtype, "_shape_", ()))
                dtype = np.int32 if name == "geom_dataid" else np.float32
                array.assign(np.ascontiguousarray(rows.reshape(shape), dtype=dtype))
            self.m.opt.warn_overflow = 0  # reported per iteration by drain_warnings instead
            self.d = mjw.make_data(merged, nworld=E, nconmax=contacts, njmax=constraints)
        t = wp.to_torch
        self._qpos, self._qvel, self._ctrl = t(self.d.qpos), t(self.d.qvel), t(self.d.ctrl)
        self._act, self._time = t(self.d.act), t(self.d.time)
        self._warmstart, self._overflow = t(self.d.qacc_warmstart), t(self.d.overflow)
        self._mocap_pos = t(self.d.mocap_pos) if self.nmocap else None
        self._mocap_quat = t(self.d.mocap_quat) if self.nmocap else None
        # Which overflow bits any world raised since the last drain_warnings (on the device).
        self._bits = torch.arange(16, device=self.device, dtype=self._overflow.dtype)
        self._seen = torch.zeros(16, dtype=self._overflow.dtype, device=self.device)
        self._graph = None
        self._stepped = False
        if self._torch_stream is not None:  # the model and data were written on Warp's stream
            wp.synchronize_device(self._wp_device)

    # --- stepping ----------------------------------------------------------------------------
    def _substeps(self) -> None:
        for _ in range(self.substeps):
            mjw.step(self.m, self.d)

    def step_held(self) -> None:
        stream = wp.ScopedStream(self._stream) if self._stream is not None else nullcontext()
        if self._torch_stream is not None:  # after torch's writes of ctrl, mocap, resets
            self._torch_stream.wait_stream(torch.cuda.current_stream(self.device))
        with wp.ScopedDevice(self._wp_device), stream:
            if self._graph is not None:
                wp.capture_launch(self._graph)
            elif self.device.type == "cuda" and self._stepped:
                # Kernels are compiled (the first period ran eagerly): capture the period.
                with wp.ScopedCapture(device=self._wp_device, stream=self._stream) as capture:
                    self._substeps()
                self._graph = capture.graph
                wp.capture_launch(self._graph)
            else:
                self._substeps()
        if self._torch_stream is not None:  # torch's reads of the new state wait for it
            torch.cuda.current_stream(self.device).wait_stream(self._torch_stream)
        self._stepped = True
        self._seen |= ((self._overflow[:, None] >> self._bits) & 1).amax(0)

    def step(
        self,
        ctrl: torch.Tensor,
        mocap_pos: torch.Tensor | None = None,
        mocap_quat: torch.Tensor | None = None,
    ) -> None:
        self._ctrl.copy_(ctrl)
        if self.nmocap:
            if mocap_pos is None or mocap_quat is None:
                raise ValueError("this model has mocap bodies: pass mocap_pos and mocap_quat")
            self._mocap_pos.copy_(mocap_pos.reshape(self._mocap_pos.shape))
            self._mocap_quat.copy_(mocap_quat.reshape(self._mocap_quat.shape))
        self.step_held()

    def set_state(
        self,
        env_ids: torch.Tensor,
        qpos: torch.Tensor,
        qvel: torch.Tensor,
        ctrl: torch.Tensor,
        mocap_pos: torch.Tensor | None = None,
        mocap_quat: torch.Tensor | None = None,
    ) -> None:
        ids = env_ids.to(self.device)
        self._qpos[ids] = qpos.to(self._qpos)
        self._qvel[ids] = qvel.to(self._qvel)
        self._ctrl[ids] = ctrl.to(self._ctrl)
        if self.nmocap and mocap_pos is not None and mocap_quat is not None:
            self._mocap_pos[ids] = mocap_pos.reshape(-1, self.nmocap, 3).to(self._mocap_pos)
            self._mocap_quat[ids] = mocap_quat.reshape(-1, self.nmocap, 4).to(self._mocap_quat)
        # What else carries over between steps: time, actuator activations, the solver's warm
        # start and the overflow flags.
        self._time[ids] = 0.0
        if self._act.numel():
            self._act[ids] = 0.0
        self._warmstart[ids] = 0.0
        self._overflow[ids] = 0

    # --- reading -----------------------------------------------------------------------------
    @property
    def qpos(self) -> torch.Tensor:
        """(E, nq) a view of the simulation's qpos: it changes with the next step (clone to
        keep)."""
        return self._qpos

    @property
    def qvel(self) -> torch.Tensor:
        return self._qvel

    def unstable(self) -> torch.Tensor:
        finite = torch.isfinite(self._qpos).all(1) & torch.isfinite(self._qvel).all(1)
        fast = (self._qvel.abs() > MAX_SPEED).any(1)
        overflow = (self._overflow & BUFFER_OVERFLOWS) != 0
        return ~finite | fast | overflow

    def drain_warnings(self) -> list[str]:
        seen = sum(1 << i for i in self._seen.nonzero()[:, 0].tolist())  # one host read
        seen &= BUFFER_OVERFLOWS
        self._seen.zero_()
        knobs = sorted({knob for bit, knob in KNOB.items() if seen & bit})
        if not knobs:
            return []
        return [
            f"MuJoCo Warp buffers overflowed (contacts {self.contacts}, constraints "
            f"{self.constraints} per world); those worlds were reset: raise {' and '.join(knobs)}"
        ]

    # --- checkpoints -------------------------------------------------------------------------
    def _state_views(self) -> dict[str, torch.Tensor]:
        views = {
            "qpos": self._qpos, "qvel": self._qvel, "ctrl": self._ctrl, "act": self._act,
            "time": self._time, "qacc_warmstart": self._warmstart, "overflow": self._overflow,
        }
        if self.nmocap:
            views["mocap_pos"], views["mocap_quat"] = self._mocap_pos, self._mocap_quat
        return views

    def state_dict(self) -> dict:
        return {name: view.detach().to("cpu", copy=True) for name, view in self._state_views().items()}  # noqa: E501

    def load_state_dict(self, state: dict) -> None:
        views = self._state_views()
        if set(state) != set(views) or state["qpos"].shape != self._qpos.shape:
            raise ValueError("the saved simulation state is for a different backend or envs")
        for name, view in views.items():
            view.copy_(torch.as_tensor(state[name]).to(view.device))

    # --- models ------------------------------------------------------------------------------
    def contact_load(self, sample: int = 32) -> dict[str, float]:
        """Every world's (``sample`` unused): the contacts and constraint rows of the last
        substep."""
        return {"contacts": float(wp.to_torch(self.d.nacon)[0]) / self.num_envs,
                "constraint rows": float(wp.to_torch(self.d.nefc).float().mean())}

    def memory(self) -> dict[str, int]:
        """``model`` and ``data``: bytes of the Warp arrays on the device."""
        return {"model": _array_bytes(self.m), "data": _array_bytes(self.d)}


def _array_bytes(obj: object) -> int:
    total = 0
    for f in fields(obj):
        value = getattr(obj, f.name, None)
        if isinstance(value, wp.array):
            total += value.capacity
        elif is_dataclass(value):
            total += _array_bytes(value)
    return total
