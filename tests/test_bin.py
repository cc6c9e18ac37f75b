"""The bin-picking task on the built-in objects: the clutter settles inside the bin, the target's
id, representation, reward and success all refer to the same object, the context's shapes and
mask, and one-line errors for impossible bins."""

from __future__ import annotations

import dataclasses
import shutil
from pathlib import Path

import mujoco
import numpy as np
import pytest
import torch
from tensordict import TensorDict
from torchrl.envs.utils import check_env_specs

from geomgrasp.rotations import quat_to_matrix
from geomprep.config import Config
from trainer.config import load_env_config
from trainer.errors import TrainerError
from trainer.representations import object_representation
from trainer.tasks import GraspTask, make_env

E = 8


def bin_config(data_dir: Path, **overrides):  # noqa: ANN003, ANN201
    values = {
        "num_envs": E, "task": "bin", "objects": "builtin", "data_dir": data_dir,
        "bin": {"num_objects": 5, "layouts": 3, "bank_size": 6},
    }
    return load_env_config(**{**values, **overrides})


@pytest.fixture(scope="module")
def env(builtin_data: Config) -> GraspTask:
    cfg = bin_config(builtin_data.data_dir, context="bbox", reward={"kind": "com"})
    environment = make_env(cfg)
    yield environment
    environment.close()


def test_specs_and_defaults(env: GraspTask) -> None:
    assert env.cfg.representation == "bbox"  # the paper's choice for the bin
    check_env_specs(env)
    td = env.reset()
    assert td["object"].shape == (E, 10)
    assert td["context"].shape == (E, 4, 10) and td["context_mask"].shape == (E, 4)
    # Each env's layout holds 5 different objects; the 3 layouts share the 8 envs in blocks.
    assert all(len(set(row.tolist())) == 5 for row in env.assignment)
    assert env.env_layout.tolist() == sorted(env.env_layout.tolist())


def test_clutter_settles_inside_the_bin_without_interpenetration(env: GraspTask) -> None:
    env.reset()
    b = env.cfg.bin
    qpos = env.backend.qpos.double().numpy()
    slots = env.slot_poses(env.backend.qpos)
    inner = torch.tensor(b.inner_half_size)
    assert (slots[..., :2].abs() < inner).all(), "an object's centre is outside the bin"
    assert (slots[..., 2] > -0.01).all() and (slots[..., 2] < 0.3).all()
    for i in range(E):
        model = env.backend.model_for_env(i)
        data = mujoco.MjData(model)
        data.qpos[:] = qpos[i]
        mujoco.mj_forward(model, data)
        depth = -min((data.contact[c].dist for c in range(data.ncon)), default=0.0)
        assert depth <= b.max_penetration + 1e-6, f"env {i}: interpenetration {depth:.4f} m"
    # At rest: holding still for a few steps hardly moves the clutter (2 cm at most).
    hold = torch.zeros(E, 11)
    hold[:, 6], hold[:, 7:] = 1.0, -1.0
    for _ in range(5):
        env.step(TensorDict({"action": hold}, batch_size=[E]))
    moved = (env.slot_poses(env.backend.qpos)[..., :3] - slots[..., :3]).norm(dim=-1)
    assert moved.max() < 0.02


def test_target_id_representation_and_reward_refer_to_the_target(env: GraspTask) -> None:
    env.reset()
    td = env.step(TensorDict({"action": torch.zeros(E, 11)}, batch_size=[E]))["next"]
    slot = env.state["target_slot"]
    target = env.assignment[torch.arange(E), slot]
    assert torch.equal(td["object_id"][:, 0], target)
    qpos = env.backend.qpos
    pose = qpos[torch.arange(E)[:, None], env.slot_qpos[slot]]  # the target slot's free joint
    expected = object_representation("bbox", env.objects, target, pose[:, :3], pose[:, 3:], None)
    torch.testing.assert_close(td["object"], expected)
    # The com reward's contact term: fingertip distances to the target's centre of mass.
    tips = env.kinematics.forward(qpos).site_pos[:, 1:]
    contact = 1.0 / ((tips - pose[:, None, :3]).norm(dim=-1).sum(-1) + env.cfg.reward.eps_sdf)
    torch.testing.assert_close(td["reward_contact"][:, 0], contact)
    # The box really is the target's: its centre is the target's pose applied to its own box.
    centre = pose[:, :3] + (quat_to_matrix(pose[:, 3:]) @ env.objects.bbox_center[target][..., None])[..., 0]  # noqa: E501
    torch.testing.assert_close(td["object"][:, :3], centre)


def _teleport_up(env: GraspTask, slots: torch.Tensor, height: float) -> None:
    """Raise the objects in ``slots`` (E,) by ``height`` (m), keeping everything else."""
    qpos = env.backend.qpos.clone()
    index = env.slot_qpos[slots, 2]
    qpos[torch.arange(E), index] += height
    env.backend.set_state(
        torch.arange(E), qpos, torch.zeros_like(env.backend.qvel), env.state["ctrl"],
        *env.mocap_targets(),
    )


def test_success_only_for_the_target(env: GraspTask) -> None:
    env.reset()
    other = (env.state["target_slot"] + 1) % env.cfg.bin.num_objects
    _teleport_up(env, other, 0.35)  # another object far above the bin: not a success
    td = env.step(TensorDict({"action": torch.zeros(E, 11)}, batch_size=[E]))["next"]
    assert not td["success"].any()
    env.reset()
    _teleport_up(env, env.state["target_slot"], 0.35)  # the target, but nothing holds it
    td = env.step(TensorDict({"action": torch.zeros(E, 11)}, batch_size=[E]))["next"]
    assert (td["lift_height"] > env.cfg.reward.h_bar).all() and not td["success"].any()
    # Without the hold condition (hold_tips = 0, eager step outputs read their config each
    # step) the same rise of the target is a success in every env.
    held_cfg = env.cfg
    env.cfg = env.outputs.cfg = dataclasses.replace(
        held_cfg, reward=dataclasses.replace(held_cfg.reward, hold_tips=0)
    )
    try:
        env.reset()
        _teleport_up(env, env.state["target_slot"], 0.35)
        td = env.step(TensorDict({"action": torch.zeros(E, 11)}, batch_size=[E]))["next"]
    finally:
        env.cfg = env.outputs.cfg = held_cfg
    assert td["success"].all() and td["terminated"].all()


def test_context_lists_the_other_objects_and_masks_fallen_ones(env: GraspTask) -> None:
    td = env.reset()
    slot = env.state["target_slot"]
    qpos = env.backend.qpos
    for i in range(E):
        others = [k for k in range(5) if k != int(slot[i])]
        ids = env.assignment[i, others]
        pose = env.slot_poses(qpos)[i, others]
        boxes = object_representation("bbox", env.objects, ids, pose[:, :3], pose[:, 3:], None)
        torch.testing.assert_close(td["context"][i], boxes)
    assert td["context_mask"].all()
    # An object below the table (fallen off) is masked out.
    other = (slot + 1) % 5
    _teleport_up(env, other, -1.0)
    td = env.step(TensorDict({"action": torch.zeros(E, 11)}, batch_size=[E]))["next"]
    rank = other - (other > slot).long()  # its position among the others
    assert not td["context_mask"][torch.arange(E), rank].any()
    assert td["context_mask"].sum() == E * 3


def _mixed_data(builtin_data: Config, ycb_data: Config, tmp_path: Path) -> Path:
    """One data directory with the 7 built-in and the 4 test YCB objects."""
    data = tmp_path / "data"
    shutil.copytree(builtin_data.data_dir, data)
    shutil.copytree(ycb_data.data_dir, data, dirs_exist_ok=True)
    return data


@pytest.mark.slow
def test_ten_object_bin_with_context(
    builtin_data: Config, ycb_data: Config, tmp_path: Path
) -> None:
    data = _mixed_data(builtin_data, ycb_data, tmp_path)
    cfg = bin_config(data, objects="all", num_envs=4, context="bbox",
                     bin={"num_objects": 10, "layouts": 2, "bank_size": 2})
    environment = make_env(cfg)
    td = environment.reset()
    assert td["context"].shape == (4, 9, 10) and td["context_mask"].all()
    assert all(len(set(row.tolist())) == 10 for row in environment.assignment)
    slots = environment.slot_poses(environment.backend.qpos)
    assert (slots[..., :2].abs() < torch.tensor(cfg.bin.inner_half_size)).all()
    environment.close()


def test_impossible_bins_are_one_line_errors(builtin_data: Config) -> None:
    with pytest.raises(TrainerError, match="has only 7"):
        make_env(bin_config(builtin_data.data_dir, bin={"num_objects": 8}))
    with pytest.raises(TrainerError, match="num_objects"):
        bin_config(builtin_data.data_dir, bin={"num_objects": 0})
    with pytest.raises(TrainerError, match="context"):
        load_env_config(task="lift", context="bbox")
    with pytest.raises(TrainerError, match="task"):
        load_env_config(task="stack")


def test_bank_is_cached_and_rebuilt_when_damaged(builtin_data: Config) -> None:
    cfg = bin_config(builtin_data.data_dir, num_envs=2, bin={"num_objects": 5, "layouts": 1,
                                                             "bank_size": 6})
    first = make_env(cfg)
    files = sorted((Path(cfg.data_dir) / "interim" / "trainer" / "init_states").glob("5obj-*"))
    assert files
    banks = first.banks.clone()
    first.close()
    for path in files:
        path.write_bytes(b"garbage")
    second = make_env(cfg)
    assert torch.equal(second.banks, banks)  # rebuilt, and deterministically the same
    second.close()
    rebuilt = [p for p in files if p.read_bytes() != b"garbage"]
    assert [np.load(p).shape for p in rebuilt] == [(6, 5, 7)]


def test_fixed_drops_keep_each_envs_settled_state(env: GraspTask) -> None:
    """``[run] fixed_drops`` (``use_fixed_drops``): every reset puts each env's clutter back
    exactly as its first one did, unturned, the envs of a layout on different states of its
    bank, while the target is still drawn per episode; the default draws a new state."""
    from trainer.tasks.starts import FixedDrop, SettledStart

    env.use_fixed_drops()
    try:
        assert isinstance(env.starts[0], FixedDrop)
        env.reset()
        first = env.slot_poses(env.backend.qpos).clone()
        targets = [env.state["target_slot"].clone()]
        for _ in range(3):
            env.reset()
            torch.testing.assert_close(env.slot_poses(env.backend.qpos), first)
            targets.append(env.state["target_slot"].clone())
        assert any(not torch.equal(t, targets[0]) for t in targets[1:])
        layout = env.env_layout.tolist()
        for a in range(E):
            for b in range(a + 1, E):
                if layout[a] == layout[b]:  # (3 layouts of <= 3 envs, banks of 6 states)
                    assert not torch.allclose(first[a], first[b]), (a, b)
    finally:
        env.starts = [SettledStart() if isinstance(s, FixedDrop) else s for s in env.starts]
    env.reset()
    drawn = env.slot_poses(env.backend.qpos).clone()
    env.reset()
    assert not torch.allclose(env.slot_poses(env.backend.qpos), drawn)
