"""The MuJoCo Warp backend (``trainer/sim/warp.py``) against MuJoCo C, on Warp's CPU device
(or on ``$GEOMGRASP_WARP_TEST_DEVICE``, e.g. ``cuda``, where a GPU is present).

What the two backends may differ by: Warp computes in float32, MuJoCo C in float64, and the two
collision pipelines find different contact points for the same touching hulls (MuJoCo C's mesh
collisions can return several points where Warp's convex collision returns one, and their
penetration depths differ slightly), so:

* without contacts (the arm and hand tracking their commands, an object in free fall) the
  trajectories agree to float32 rounding: 1e-5 rad / 1e-5 m over 0.5 s (15 control periods);
* resting objects agree within 0.2 mm over 1 s and move by less than 1 mm on either backend;
  objects dropped from 5 cm land within 1 mm of each other (a landing amplifies float32
  differences).

Warp compiles its kernels on the first step (about 2 minutes on 2 cores, then cached in
``~/.cache/warp``): the first test that steps pays for all; keep the worlds few and the
horizons short (Warp's CPU device steps ~10 ms per physics step for up to ~30 worlds).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
import torch

pytest.importorskip("mujoco_warp", reason="MuJoCo Warp not installed (pip install -e '.[gpu]')")

from geomprep.config import Config  # noqa: E402
from tests.conftest import GRASP_TEST_OBJECTS, YCB_TEST_OBJECTS, build_ycb  # noqa: E402
from tests.test_ppo import main, metrics_iterations  # noqa: E402
from trainer.config import load_env_config, load_train_config  # noqa: E402
from trainer.grasps import run_scripted_grasp  # noqa: E402
from trainer.ppo import train  # noqa: E402
from trainer.tasks import make_env  # noqa: E402

DEVICE = os.environ.get("GEOMGRASP_WARP_TEST_DEVICE", "cpu")
"""Where the Warp envs of these tests run; MuJoCo C's always run on the CPU."""

BUILTIN = "builtin_cylinder,builtin_sphere,builtin_mug"
FLAT = "builtin_knife,builtin_plate"
"""Thin objects resting on one face: on MuJoCo Warp they need its multi-point convex contacts
(a single contact point let them tip into the table by 9 mm before the library meshes got
their hull data)."""


def env_pair(data_dir: Path, objects: str, num_envs: int, seed: int = 0, **extra):  # noqa: ANN003, ANN201
    """The same task on both backends, reset to the same initial states."""
    envs = {}
    for backend in ("cpu", "warp"):
        cfg = load_env_config(
            num_envs=num_envs, objects=objects, data_dir=data_dir, backend=backend,
            representation="com", device="cpu" if backend == "cpu" else DEVICE, **extra,
        )
        envs[backend] = make_env(cfg, seed=seed)
        envs[backend].reset()
    cpu, warp = envs["cpu"], envs["warp"]
    # The same seed draws the same initial states only on the same device: start the Warp envs
    # where the CPU ones are.
    mocap = [None if t is None else t.to(warp.device) for t in cpu.mocap_targets()]
    warp.backend.set_state(
        torch.arange(num_envs, device=warp.device), cpu.backend.qpos, cpu.backend.qvel,
        cpu.state["ctrl"], *mocap,
    )
    warp.state.update_(cpu.state.to(warp.device))
    assert torch.equal(cpu.backend.qpos, warp.backend.qpos.cpu())
    return cpu, warp


def rollout(env, actions: torch.Tensor) -> torch.Tensor:  # noqa: ANN001
    """qpos after each action from the current state: (T, E, nq) on the CPU."""
    out = []
    td = env._observe(reset=True)
    for action in actions:
        td = env.step(td.set("action", action.to(env.device)))["next"]
        out.append(env.backend.qpos.to("cpu", copy=True))
    return torch.stack(out)


def test_arm_hand_and_free_fall_agree_with_mujoco_c(builtin_data: Config) -> None:
    """The arm tracks a moving hand command and the fingers close while each env's object
    falls from 10 cm: no contacts for the first 0.13 s, so float32 rounding is all that
    differs."""
    cpu, warp = env_pair(builtin_data.data_dir, BUILTIN, 3)
    for env in (cpu, warp):  # raise the objects 10 cm, at rest
        qpos = env.backend.qpos.clone()
        qpos[:, env.slot_qpos[0, 2]] += 0.1
        env.backend.set_state(
            torch.arange(3, device=qpos.device), qpos, torch.zeros_like(env.backend.qvel),
            env.state["ctrl"],
        )
    actions = torch.zeros(15, 3, 11)
    actions[:, :, 0], actions[:, :, 5], actions[:, :, 6:] = 0.6, 0.4, 0.5
    # The thumb straight and the fingers half closed: the link hulls of a fully closed hand
    # touch each other and the palm, and contacts are where the backends part by more than
    # float32 rounding (the contact tests compare those).
    actions[:, :, 7] = -1.0
    # (Stepping without the reset of ``rollout``: the raised objects must stay raised.)
    trajectories = []
    for env in (cpu, warp):
        td = env._observe(reset=True)
        out = []
        for action in actions:
            td = env.step(td.set("action", action.to(env.device)))["next"]
            out.append(env.backend.qpos.to("cpu", copy=True))
        trajectories.append(torch.stack(out))
    a, b = trajectories
    robot = slice(0, int(cpu.slot_qpos[0, 0]))
    assert (a[:, :, robot] - a[0, :, robot]).abs().amax() > 0.3  # the arm and hand did move
    assert (a[:, :, robot] - b[:, :, robot]).abs().amax() < 1e-5
    falling = a[:4, :, cpu.slot_qpos[0, :3]]  # 4 periods: 0.13 s, a 8.7 cm fall
    assert (falling - b[:4, :, cpu.slot_qpos[0, :3]]).abs().amax() < 1e-5
    assert (falling[-1, :, 2] - falling[0, :, 2] < -0.05).all()


@pytest.mark.parametrize("objects", [BUILTIN, FLAT])
def test_resting_objects_agree_with_mujoco_c(builtin_data: Config, objects: str) -> None:
    """Objects resting where MuJoCo C settled them stay put on both backends for 1 s, within
    0.2 mm of each other."""
    cpu, warp = env_pair(builtin_data.data_dir, objects, 3)
    actions = torch.zeros(30, 3, 11)
    a, b = rollout(cpu, actions), rollout(warp, actions)
    pos = cpu.slot_qpos[0, :3]
    for traj in (a, b):
        assert (traj[:, :, pos] - traj[0, :, pos]).norm(dim=-1).amax() < 2.5e-3
    assert (a[:, :, pos] - b[:, :, pos]).norm(dim=-1).amax() < 2.5e-3
    # Both count the resting objects' contacts (bench/env_throughput.py --policy prints them):
    # at least one per env, each with its constraint rows (the pipelines' counts may differ).
    for env in (cpu, warp):
        load = env.backend.contact_load()
        assert 1.0 <= load["contacts"] <= 32.0, load
        assert load["constraint rows"] >= load["contacts"], load


def test_each_world_simulates_its_own_object(
    tmp_path_factory: pytest.TempPathFactory,
) -> None:
    """One batch holding the dice and the plate (YCB): each world has its own object's mass and
    hulls, and dropped from 5 cm each lands at its own height, the one MuJoCo C gives it."""
    data = build_ycb(tmp_path_factory, "ycb", YCB_TEST_OBJECTS)
    cpu, warp = env_pair(data.data_dir, "062_dice,029_plate", 4)
    backend = warp.backend
    masses = backend.m.body_mass.numpy()
    slot_body = backend.model.body("slot0").id
    dataid = backend.m.geom_dataid.numpy()
    for i in range(4):
        model = backend.models[int(backend.env_layout[i])]  # its stepping model (no visuals)
        assert masses[i, slot_body] == pytest.approx(model.body_mass[slot_body], rel=1e-6)
        hulls = int(model.body_geomnum[slot_body])
        start = int(backend.merged.body_geomadr[slot_body])
        width = int(backend.merged.body_geomnum[slot_body])
        assert (dataid[i, start: start + hulls] >= 0).all()  # its hulls, ...
        assert (dataid[i, start + hulls: start + width] < 0).all()  # ... the rest empty
    assert masses[0, slot_body] != masses[2, slot_body]  # envs 0, 1: dice; 2, 3: plate
    for env in (cpu, warp):
        qpos = env.backend.qpos.clone()
        qpos[:, env.slot_qpos[0, 2]] += 0.05
        env.backend.set_state(
            torch.arange(4, device=qpos.device), qpos, torch.zeros_like(env.backend.qvel),
            env.state["ctrl"],
        )
        for _ in range(30):
            env.hold()
    z = cpu.slot_qpos[0, 2]
    heights_c, heights_w = cpu.backend.qpos[:, z], warp.backend.qpos[:, z].cpu()
    assert (heights_c - heights_w).abs().amax() < 1e-3, (heights_c, heights_w)
    assert cpu.target_objects().tolist() == [0, 0, 1, 1] == warp.target_objects().tolist()
    assert (heights_w[:2] - heights_w[2:].flip(0)).abs().amin() > 1e-3  # dice and plate differ


def test_buffer_overflow_flags_the_world_and_names_the_knob(builtin_data: Config) -> None:
    cfg = load_env_config(
        num_envs=2, objects="builtin_mug", data_dir=builtin_data.data_dir, backend="warp",
        representation="com", warp={"contacts_per_world": 1}, device=DEVICE,
    )
    env = make_env(cfg, seed=0)
    env.reset()
    assert not env.backend.unstable().any()
    env.hold()  # a mug (several hulls) resting on the table: more than one contact each
    assert env.backend.unstable().all()
    (message,) = env.backend.drain_warnings()
    assert "[warp] contacts_per_world" in message
    assert env.backend.drain_warnings() == []  # reported once
    td = env._observe(reset=False)
    assert td["truncated"].all() and td["unstable"].all()  # the task resets them
    env.reset()
    assert not env.backend.unstable().any()


def test_masked_reset_and_snapshot_restore(builtin_data: Config) -> None:
    """A reset writes only the chosen worlds; a restored snapshot continues bit for bit."""
    cfg = load_env_config(
        num_envs=3, objects=BUILTIN, data_dir=builtin_data.data_dir, backend="warp",
        representation="com", device=DEVICE,
    )
    env = make_env(cfg, seed=1)
    td = env.reset()
    action = torch.full((3, 11), 0.3, device=env.device)
    for _ in range(3):
        td = env.step(td.set("action", action))["next"]
    before = env.backend.qpos.clone()
    env._reset_envs(torch.tensor([1], device=env.device))
    after = env.backend.qpos
    assert torch.equal(after[[0, 2]], before[[0, 2]]) and not torch.equal(after[1], before[1])
    snapshot = env.snapshot()
    runs = []
    for _ in range(2):
        env._restore(snapshot)
        for _ in range(3):
            env.hold()
        runs.append(env.backend.qpos.clone())
    if DEVICE == "cpu":
        assert torch.equal(runs[0], runs[1])
    else:  # on a GPU, contacts are gathered by atomics: their order, not the physics, varies
        assert (runs[0] - runs[1]).abs().amax() < 1e-3


@pytest.mark.slow
def test_scripted_grasp_lifts_ycb_objects_on_warp(
    tmp_path_factory: pytest.TempPathFactory,
) -> None:
    """The issue's bar on this backend: 077_rubiks_cube, 013_apple and 005_tomato_soup_can
    lifted by 0.2 m in >= 8 of 10 trials each (30 worlds in one batch, on Warp's CPU device)."""
    names = GRASP_TEST_OBJECTS
    data = build_ycb(tmp_path_factory, "grasp", names)
    cfg = load_env_config(
        num_envs=30, objects=",".join(names), data_dir=data.data_dir, backend="warp",
        representation="com", device=DEVICE,
    )
    env = make_env(cfg, seed=1)
    lifted = run_scripted_grasp(env).cpu().numpy()
    ids = env.target_objects().cpu().numpy()
    counts = {name: int(lifted[ids == k].sum()) for k, name in enumerate(names)}
    assert all(n >= 8 for n in counts.values()), counts


def test_training_run_and_resume_on_warp(
    builtin_data: Config, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys  # noqa: ANN001
) -> None:
    """``trainer run --backend warp --device cpu`` trains, checkpoints and resumes; the resumed
    run ends exactly where an uninterrupted one does."""
    cfg = load_train_config(
        env={"num_envs": 3, "objects": BUILTIN, "representation": "com", "backend": "warp",
             "data_dir": builtin_data.data_dir, "max_steps": 6, "device": DEVICE},
        ppo={"frames_per_env": 4, "minibatches": 2, "min_minibatch": 1, "epochs": 1,
             "hidden": (16, 16)},
        run={"total_steps": 3 * 4 * 3, "checkpoint_every": 1, "seed": 2},
    )
    straight = train(cfg, tmp_path / "straight", progress=False)
    train(cfg, tmp_path / "killed", progress=False, stop_after=2)
    code, _, err = main(["run", "--resume", str(tmp_path / "killed")], monkeypatch, capsys)
    assert code == 0, err
    assert metrics_iterations(tmp_path / "killed") == [1, 2, 3]
    a = torch.load(straight.checkpoints / "iter_000003.pt", weights_only=False)
    b = torch.load(tmp_path / "killed" / "checkpoints" / "iter_000003.pt", weights_only=False)
    if DEVICE != "cpu":  # GPU contact order comes from atomics: a resume need not be bitwise
        return
    for key, value in a["agent"].items():
        assert torch.equal(value, b["agent"][key]), key
    assert torch.equal(a["env"]["backend"]["qpos"], b["env"]["backend"]["qpos"])


def test_warp_without_the_extra_or_a_gpu_is_one_line(
    builtin_data: Config, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys  # noqa: ANN001
) -> None:
    import importlib.util

    args = ["run", "--backend", "warp", "--objects", "builtin_box", "--data-dir",
            str(builtin_data.data_dir), "--run-dir", str(tmp_path / "run")]
    if not torch.cuda.is_available():
        code, _, err = main([*args, "--device", "cuda"], monkeypatch, capsys)
        assert code == 1 and err.count("\n") == 1 and "no CUDA device" in err
    real = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util, "find_spec",
        lambda name, *a: None if name in ("mujoco_warp", "warp") else real(name, *a),
    )
    code, _, err = main(args, monkeypatch, capsys)
    assert code == 1 and err.count("\n") == 1, err
    assert 'pip install -e ".[gpu]"' in err
    assert not (tmp_path / "run").exists()


def test_per_world_fields_come_from_each_layouts_model(builtin_data: Config) -> None:
    """The merged model's per-world values are those of each world's own MuJoCo C model: with
    one slot (the last body), the merged geoms other than the mesh library's are the layout's
    geoms in order, then the slot's unused hull geoms."""
    from trainer.sim.warp import BODY_FIELDS, GEOM_FIELDS, LIBRARY_GEOM

    cfg = load_env_config(
        num_envs=2, objects="builtin_box,builtin_mug", data_dir=builtin_data.data_dir,
        backend="warp", representation="com", device=DEVICE,
    )
    backend = make_env(cfg, seed=0).backend
    for i in range(2):
        model = backend.models[int(backend.env_layout[i])]
        merged = backend.merged
        scene = [g for g in range(merged.ngeom) if LIBRARY_GEOM not in merged.geom(g).name]
        library = np.setdiff1d(np.arange(merged.ngeom), scene)
        assert len(library) and (backend.m.geom_dataid.numpy()[i][library] == -1).all()
        for name in GEOM_FIELDS + BODY_FIELDS:
            ours = getattr(model, name)
            rows = getattr(backend.m, name).numpy()[i]
            if name in GEOM_FIELDS:
                rows = rows[scene]
            if name == "geom_dataid":  # mesh ids differ: the same mesh, from the library
                ids = rows[: len(ours)]
                assert ((ids >= 0) == (ours >= 0)).all()
                mesh = ids >= 0
                assert (merged.mesh_vertnum[ids[mesh]] == model.mesh_vertnum[ours[mesh]]).all()
                continue
            values = rows.reshape(-1, *ours.shape[1:])
            np.testing.assert_allclose(
                values[: len(ours)], ours, rtol=1e-6, atol=1e-7, err_msg=name
            )


def test_bin_clutter_agrees_with_mujoco_c(builtin_data: Config) -> None:
    """Five slots, each world its own draw of objects (two layouts): the settled clutter stays
    where MuJoCo C keeps it (within 1 mm over 0.33 s), so every slot holds the right object."""
    cpu, warp = env_pair(
        builtin_data.data_dir, "builtin", 2, task="bin",
        bin={"num_objects": 5, "layouts": 2, "bank_size": 2},
    )
    assert not torch.equal(cpu.assignment[0], cpu.assignment[1])
    for env in (cpu, warp):
        for _ in range(10):
            env.hold()
    a, b = cpu.slot_poses(cpu.backend.qpos), warp.slot_poses(warp.backend.qpos).cpu()
    assert (a[..., :3] - b[..., :3]).norm(dim=-1).amax() < 1e-3
