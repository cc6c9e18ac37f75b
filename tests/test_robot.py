"""The robot built in code: the SIH hand's structure and couplings, the UR5e against its DH
table, the torch kinematics against MuJoCo, and the Jacobian-transpose step."""

from __future__ import annotations

import dataclasses

import mujoco
import numpy as np
import pytest
import torch

from trainer import constants as C
from trainer.assets.arm import dh_forward
from trainer.assets.scene import Scene, build_scene, ur5e_home_joints
from trainer.config import load_env_config
from trainer.kinematics import SiteKinematics, jacobian_transpose_step, pose_error


def _model(kind: str) -> mujoco.MjModel:
    cfg = load_env_config()
    cfg = dataclasses.replace(cfg, robot=dataclasses.replace(cfg.robot, kind=kind))
    return build_scene(cfg, Scene(num_slots=0), []).compile()


@pytest.fixture(scope="module")
def ur5e() -> mujoco.MjModel:
    return _model("ur5e")


@pytest.fixture(scope="module")
def floating() -> mujoco.MjModel:
    return _model("floating")


def test_hand_has_11_joints_5_actuators_and_fingertips(floating: mujoco.MjModel) -> None:
    hand_joints = [floating.joint(n) for n in C.SIH_JOINTS]
    assert len(hand_joints) == 11
    assert floating.nu == 5
    assert [floating.actuator(i).name for i in range(5)] == [a[0] for a in C.SIH_ACTUATORS]
    for name in C.FINGERTIPS:
        assert floating.site(name).id >= 0
    # Index fingertip at q = 0, palm frame: (-0.0435, 0.0175, 0.230) per sih_hand.md.
    data = mujoco.MjData(floating)
    mujoco.mj_kinematics(floating, data)
    palm = data.body("palm")
    local = palm.xmat.reshape(3, 3).T @ (data.site("tip_if").xpos - palm.xpos)
    np.testing.assert_allclose(local, [-0.0435, 0.0175, 0.230], atol=1e-6)
    thumb = palm.xmat.reshape(3, 3).T @ (data.site("tip_th").xpos - palm.xpos)
    np.testing.assert_allclose(thumb, [-0.1201, 0.024, 0.096], atol=1e-6)


def test_couplings_hold_while_closing(floating: mujoco.MjModel) -> None:
    data = mujoco.MjData(floating)
    for name, _, _, closed in C.SIH_ACTUATORS:
        data.ctrl[floating.actuator(name).id] = 0.6 * closed
    for _ in range(600):
        mujoco.mj_step(floating, data)
    q = {n: data.qpos[floating.joint(n).qposadr[0]] for n in C.SIH_JOINTS}
    assert q["if_proximal"] < -0.5  # the fingers did close
    for follower, leader in C.SIH_COUPLINGS:
        assert abs(q[follower] - q[leader]) < 0.02, (follower, leader, q)


def test_ur5e_matches_dh_table(ur5e: mujoco.MjModel) -> None:
    cfg = load_env_config()
    data = mujoco.MjData(ur5e)
    rng = np.random.default_rng(0)
    for _ in range(5):
        q = rng.uniform(-np.pi, np.pi, 6)
        data.qpos[:6] = q
        mujoco.mj_kinematics(ur5e, data)
        expected = dh_forward(q)
        flange = data.site("flange")
        np.testing.assert_allclose(
            flange.xpos, expected[:3, 3] + np.array(cfg.robot.base_pos), atol=1e-9
        )
        np.testing.assert_allclose(flange.xmat.reshape(3, 3), expected[:3, :3], atol=1e-9)


@pytest.mark.parametrize("kind", ["ur5e", "floating"])
def test_torch_kinematics_match_mujoco(kind: str) -> None:
    model = _model(kind)
    data = mujoco.MjData(model)
    rng = np.random.default_rng(1)
    sites = ["palm", *C.FINGERTIPS]
    kinematics = SiteKinematics(model, sites)
    for _ in range(3):
        data.qpos[:] = model.qpos0 + rng.normal(0.0, 0.4, model.nq)
        mujoco.mj_normalizeQuat(model, data.qpos)
        mujoco.mj_forward(model, data)
        poses = kinematics.forward(torch.as_tensor(data.qpos)[None])
        expected = np.stack([data.site(s).xpos for s in sites])
        # float32 against float64: far below the 1 mm requirement
        assert np.abs(poses.site_pos[0].numpy() - expected).max() < 1e-5
    if kind == "ur5e":
        jac = kinematics.jacobian(poses, "palm", C.UR5E_JOINTS)[0].numpy()
        jp, jr = np.zeros((3, model.nv)), np.zeros((3, model.nv))
        mujoco.mj_jacSite(model, data, jp, jr, model.site("palm").id)
        np.testing.assert_allclose(jac, np.vstack([jp, jr])[:, :6], atol=1e-5)


def test_jacobian_transpose_moves_hand_toward_command(ur5e: mujoco.MjModel) -> None:
    cfg = load_env_config()
    kinematics = SiteKinematics(ur5e, ["palm"])
    qpos = torch.as_tensor(ur5e.qpos0, dtype=torch.float32)[None].repeat(4, 1)
    qpos[:, :6] = torch.as_tensor(ur5e_home_joints(cfg), dtype=torch.float32)
    start = kinematics.forward(qpos)
    offsets = torch.tensor(
        [[0.03, 0.0, 0.0], [0.0, -0.03, 0.0], [0.0, 0.0, 0.03], [0.02, 0.02, -0.02]]
    )
    target_pos = start.site_pos[:, 0] + offsets
    target_rot = start.site_rot[:, 0]
    before = pose_error(target_pos, target_rot, start.site_pos[:, 0], start.site_rot[:, 0])
    arm = torch.arange(6)
    moved = qpos.clone()
    moved[:, :6] = jacobian_transpose_step(
        kinematics, qpos, arm, C.UR5E_JOINTS, "palm", target_pos, target_rot, 1
    )
    after = kinematics.forward(moved)
    err1 = pose_error(target_pos, target_rot, after.site_pos[:, 0], after.site_rot[:, 0])
    # One step lowers the position error and the error JT minimises (rotation in metres at
    # the default 0.2 m/rad).
    weight = torch.tensor([1.0, 1.0, 1.0, 0.2, 0.2, 0.2])
    assert (err1[:, :3].norm(dim=1) < before[:, :3].norm(dim=1)).all()
    assert ((err1 * weight).norm(dim=1) < 0.8 * (before * weight).norm(dim=1)).all()
    # Repeated steps (as across control periods) converge to the command.
    for _ in range(20):
        moved[:, :6] = jacobian_transpose_step(
            kinematics, moved, arm, C.UR5E_JOINTS, "palm", target_pos, target_rot, 5
        )
    final = kinematics.forward(moved)
    err = pose_error(target_pos, target_rot, final.site_pos[:, 0], final.site_rot[:, 0])
    assert err[:, :3].norm(dim=1).max() < 2e-3
    assert err[:, 3:].norm(dim=1).max() < 0.02
