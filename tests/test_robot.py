"""The robot built in code: the SIH hand's structure and couplings, the UR5e against its DH
table, the torch kinematics against MuJoCo, and the Jacobian-transpose step."""

from __future__ import annotations

import dataclasses

import mujoco
import numpy as np
import pytest
import torch

from trainer.assets.scene import Scene, build_scene
from trainer.config import ACTION_DIM, load_env_config
from trainer.kinematics import SiteKinematics, jacobian_transpose_step, pose_error
from trainer.robots import ROBOTS, make_robot, sih
from trainer.robots.ur5e import JOINTS as UR5E_JOINTS
from trainer.robots.ur5e import UR5eRobot, dh_forward


def _model(kind: str, **robot: object) -> mujoco.MjModel:
    cfg = load_env_config()
    cfg = dataclasses.replace(cfg, robot=dataclasses.replace(cfg.robot, kind=kind, **robot))
    return build_scene(cfg, Scene(num_slots=0), []).compile()


@pytest.fixture(scope="module")
def ur5e() -> mujoco.MjModel:
    return _model("ur5e")


@pytest.fixture(scope="module")
def floating() -> mujoco.MjModel:
    return _model("floating")


def test_hand_has_11_joints_11_actuators_and_fingertips(floating: mujoco.MjModel) -> None:
    """The default hand drives every joint: the 5 servos' actuators first, then one per
    follower joint (``all-joints``)."""
    hand_joints = [floating.joint(n) for n in sih.JOINTS]
    assert len(hand_joints) == 11
    assert floating.nu == 11
    assert [floating.actuator(i).name for i in range(11)] == (
        [a[0] for a in sih.ACTUATORS] + [a[0] for a in sih.FOLLOWER_ACTUATORS])
    for name in sih.FINGERTIPS:
        assert floating.site(name).id >= 0
    # Index fingertip at q = 0, palm frame: (-0.0435, 0.0175, 0.230) per sih_hand.md.
    data = mujoco.MjData(floating)
    mujoco.mj_kinematics(floating, data)
    palm = data.body("palm")
    local = palm.xmat.reshape(3, 3).T @ (data.site("tip_if").xpos - palm.xpos)
    np.testing.assert_allclose(local, [-0.0435, 0.0175, 0.230], atol=1e-6)
    thumb = palm.xmat.reshape(3, 3).T @ (data.site("tip_th").xpos - palm.xpos)
    np.testing.assert_allclose(thumb, [-0.1201, 0.024, 0.096], atol=1e-6)


def test_couplings_hold_while_closing() -> None:
    """``hand_drive = "equalities"`` (the capsule hand's drive): 5 actuators, and the 6
    follower joints kept on their leaders by the equalities."""
    model = _model("floating", hand_drive="equalities")
    data = mujoco.MjData(model)
    for name, _, _, closed in sih.ACTUATORS:
        data.ctrl[model.actuator(name).id] = 0.6 * closed
    for _ in range(600):
        mujoco.mj_step(model, data)
    q = {n: data.qpos[model.joint(n).qposadr[0]] for n in sih.JOINTS}
    assert q["if_proximal"] < -0.5  # the fingers did close
    for follower, leader in sih.COUPLINGS:
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
    sites = ["palm", *sih.FINGERTIPS]
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
        jac = kinematics.jacobian(poses, "palm", UR5E_JOINTS)[0].numpy()
        jp, jr = np.zeros((3, model.nv)), np.zeros((3, model.nv))
        mujoco.mj_jacSite(model, data, jp, jr, model.site("palm").id)
        np.testing.assert_allclose(jac, np.vstack([jp, jr])[:, :6], atol=1e-5)


def test_jacobian_transpose_moves_hand_toward_command(ur5e: mujoco.MjModel) -> None:
    cfg = load_env_config()
    kinematics = SiteKinematics(ur5e, ["palm"])
    qpos = torch.as_tensor(ur5e.qpos0, dtype=torch.float32)[None].repeat(4, 1)
    qpos[:, :6] = torch.as_tensor(UR5eRobot(cfg.robot).home_joints(), dtype=torch.float32)
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
        kinematics, qpos, arm, UR5E_JOINTS, "palm", target_pos, target_rot, 1
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
            kinematics, moved, arm, UR5E_JOINTS, "palm", target_pos, target_rot, 5
        )
    final = kinematics.forward(moved)
    err = pose_error(target_pos, target_rot, final.site_pos[:, 0], final.site_rot[:, 0])
    assert err[:, :3].norm(dim=1).max() < 2e-3
    assert err[:, 3:].norm(dim=1).max() < 0.02


@pytest.mark.parametrize("kind", ["ur5e", "floating"])
def test_robot_home_puts_the_palm_at_its_home_pose(kind: str) -> None:
    """Each robot of the registry: its home state puts the palm keypoint at ``home_pose``, palm
    down, the hand open with the thumb opposed; its action has ``ACTION_DIM`` values."""
    cfg = load_env_config()
    robot = make_robot(dataclasses.replace(cfg.robot, kind=kind))
    assert isinstance(robot, ROBOTS[kind]) and robot.action_dim == ACTION_DIM
    model = _model(kind)
    robot.index(model, torch.device("cpu"))
    home = robot.home(model)
    poses = SiteKinematics(model, robot.sites).forward(home.qpos[None])
    keypoint, rot = robot.home_pose()
    np.testing.assert_allclose(poses.site_pos[0, 0].numpy(), keypoint, atol=1e-4)
    np.testing.assert_allclose(poses.site_rot[0, 0].numpy(), rot, atol=1e-4)
    torch.testing.assert_close(home.keypoint, torch.as_tensor(keypoint, dtype=torch.float32))
    hand = home.ctrl[robot.hand.actuators]
    assert hand[0] == robot.hand.closed[0] and (hand[1:] == robot.hand.open[1:]).all()
    assert home.qpos[robot.hand_qpos[0]] == robot.hand.closed[0]


@pytest.mark.parametrize("kind", ["ur5e", "floating"])
def test_robot_commands_and_hold_action(kind: str) -> None:
    """An action moves the commanded palm by ``pos_step`` per unit, sets the hand's targets
    between open (-1) and closed (+1), and ``hold_action`` gives back the action that keeps
    them; only the floating hand has mocap targets."""
    cfg = load_env_config()
    robot = make_robot(dataclasses.replace(cfg.robot, kind=kind))
    model = _model(kind)
    robot.index(model, torch.device("cpu"))
    home = robot.home(model)
    E = 3
    action = torch.zeros(E, robot.action_dim)
    action[:, 0] = torch.tensor([1.0, -1.0, 0.5])
    action[:, 6:] = torch.linspace(-1.0, 1.0, 5)
    palm = home.keypoint.expand(E, 3)
    target_pos, target_rot, ctrl = robot.commands(
        action, palm, palm, home.rot.expand(E, 3, 3), home.ctrl.expand(E, -1),
        home.qpos.expand(E, -1),
    )
    step = torch.tensor([1.0, -1.0, 0.5]) * cfg.robot.pos_step
    torch.testing.assert_close(target_pos[:, 0] - palm[:, 0], step)
    torch.testing.assert_close(target_rot, home.rot.expand(E, 3, 3))
    hand = ctrl[:, robot.hand.actuators]
    torch.testing.assert_close(hand[:, 0], robot.hand.open[0].expand(E))
    torch.testing.assert_close(hand[:, -1], robot.hand.closed[-1].expand(E))
    torch.testing.assert_close(robot.hold_action(ctrl)[:, 6:], action[:, 6:])
    assert not robot.hold_action(ctrl)[:, :6].any()
    mocap_pos, mocap_quat = robot.mocap(target_pos, target_rot)
    if kind == "floating":
        assert mocap_pos.shape == (E, 1, 3) and mocap_quat.shape == (E, 1, 4)
        torch.testing.assert_close(mocap_pos[:, 0], target_pos)
    else:
        assert mocap_pos is None and mocap_quat is None
        assert not torch.equal(ctrl[:, robot.arm_actuators], home.ctrl[robot.arm_actuators])


def test_relative_hand_actions_move_the_targets_by_steps_within_the_range() -> None:
    """``hand_action = "relative"``: an action moves each target by ``hand_relative_step`` per
    unit from where it was, never past open or closed; 0 holds the targets (``hold_action``)."""
    cfg = load_env_config(robot={"kind": "floating", "hand_action": "relative"})
    robot = make_robot(cfg.robot)
    model = _model("floating")
    robot.index(model, torch.device("cpu"))
    home = robot.home(model)
    hand = robot.hand
    action = torch.zeros(2, robot.action_dim)
    action[0, 6:] = torch.tensor([0.0, 1.0, 1.0, -1.0, 0.5])
    palm = home.keypoint.expand(2, 3)
    ctrl = home.ctrl.expand(2, -1)
    step = cfg.robot.hand_relative_step
    for _ in range(3):
        _, _, ctrl = robot.commands(
            action, palm, palm, home.rot.expand(2, 3, 3), ctrl, home.qpos.expand(2, -1)
        )
    targets = ctrl[:, hand.actuators]
    start = home.ctrl[hand.actuators]
    toward_closed = torch.sign(hand.closed - hand.open)  # +1 closes, as in absolute mode
    expected = (start + 3 * step * action[0, 6:] * toward_closed).clamp(hand.low, hand.high)
    torch.testing.assert_close(targets[0], expected)
    # The thumb rotation starts opposed (closed): +1 cannot move it further; the index closes.
    assert targets[0, 0] == start[0] and targets[0, 2] == start[2] - 3 * step
    torch.testing.assert_close(targets[1], start)  # action 0: the targets stay
    assert (targets >= hand.low).all() and (targets <= hand.high).all()
    assert not robot.hold_action(ctrl).any()
    many = robot.commands(
        torch.ones(1, robot.action_dim), palm[:1], palm[:1], home.rot[None], ctrl[:1],
        home.qpos[None],
    )[2][:, hand.actuators]
    assert (many >= hand.low).all() and (many <= hand.high).all()


# --- The link hulls (robot.hand_geometry = "hulls") ------------------------------------------


def _hull_model(kind: str, **robot: object) -> mujoco.MjModel:
    cfg = load_env_config(robot={"kind": kind, "hand_geometry": "hulls", **robot})
    return build_scene(cfg, Scene(num_slots=0), []).compile()


@pytest.fixture(scope="module")
def hulls() -> mujoco.MjModel:
    return _hull_model("floating")


def _signed_distance(model: mujoco.MjModel, data: mujoco.MjData, body: str,
                     point: np.ndarray) -> float:
    """Signed distance (m; negative inside) of a world ``point`` (3,) to the hull geom of
    ``body``: the largest of its face planes' signed distances (exact inside the hull and
    outside it opposite a face, a lower bound near an edge)."""
    from scipy.spatial import ConvexHull

    (geom,) = np.flatnonzero(model.geom_bodyid == model.body(body).id)
    assert model.geom_type[geom] == mujoco.mjtGeom.mjGEOM_MESH
    mesh = model.geom_dataid[geom]
    start, count = model.mesh_vertadr[mesh], model.mesh_vertnum[mesh]
    hull = ConvexHull(model.mesh_vert[start : start + count].astype(np.float64))
    local = data.geom_xmat[geom].reshape(3, 3).T @ (point - data.geom_xpos[geom])
    return float((hull.equations[:, :3] @ local + hull.equations[:, 3]).max())


def test_hull_hand_compiles_for_both_robots_with_the_capsules_bits_and_material() -> None:
    """Every finger and thumb link collides as one mesh geom from ``sih_hulls.json``; the palm
    stays the box; the meshes carry the capsules' collision bits and contact material."""
    for kind in ROBOTS:
        capsules, meshes = _model(kind, hand_geometry="capsules"), _hull_model(kind)
        for body in sih.HULL_OF:
            (cap,) = np.flatnonzero(capsules.geom_bodyid == capsules.body(body).id)
            (geom,) = np.flatnonzero(meshes.geom_bodyid == meshes.body(body).id)
            assert meshes.geom_type[geom] == mujoco.mjtGeom.mjGEOM_MESH
            assert capsules.geom_type[cap] == mujoco.mjtGeom.mjGEOM_CAPSULE
            for field in ("geom_contype", "geom_conaffinity", "geom_friction", "geom_solref",
                          "geom_solimp", "geom_condim", "geom_priority"):
                np.testing.assert_array_equal(getattr(meshes, field)[geom],
                                              getattr(capsules, field)[cap], err_msg=field)
            assert meshes.body(body).mass == pytest.approx(capsules.body(body).mass)
        (palm,) = np.flatnonzero(meshes.geom_bodyid == meshes.body("palm").id)
        assert meshes.geom_type[palm] == mujoco.mjtGeom.mjGEOM_BOX
        assert meshes.nmesh == len(sih.HULL_OF) == 11


def test_tip_hulls_hand_has_hulls_on_the_touching_links_and_capsules_elsewhere() -> None:
    """``tip-hulls``: the links of ``sih.TIP_LINKS`` collide as their hulls, the proximal links
    as their capsules, with the same masses and collision bits as either hand."""
    mixed = _model("floating", hand_geometry="tip-hulls")
    capsules = _model("floating", hand_geometry="capsules")
    assert set(sih.TIP_LINKS) < set(sih.HULL_OF) and mixed.nmesh == len(sih.TIP_LINKS) == 6
    for body in sih.HULL_OF:
        (geom,) = np.flatnonzero(mixed.geom_bodyid == mixed.body(body).id)
        expected = (mujoco.mjtGeom.mjGEOM_MESH if body in sih.TIP_LINKS
                    else mujoco.mjtGeom.mjGEOM_CAPSULE)
        assert mixed.geom_type[geom] == expected, body
        assert mixed.body(body).mass == pytest.approx(capsules.body(body).mass)
        assert mixed.geom_contype[geom] == capsules.geom_contype[
            np.flatnonzero(capsules.geom_bodyid == capsules.body(body).id)[0]]


def test_fingertip_sites_lie_on_the_distal_pads(hulls: mujoco.MjModel) -> None:
    """At q = 0 each fingertip site is within 1 mm of its distal hull's surface (sih_hand.md
    section 10 (a): -0.05 to -0.16 mm; the little finger +0.86 mm, its pad under-sampled)."""
    data = mujoco.MjData(hulls)
    mujoco.mj_forward(hulls, data)
    expected = {"if": -0.00013, "mf": -0.00016, "rf": -0.00013, "lf": 0.00086, "th": -0.00005}
    for finger, value in expected.items():
        distal = "th_distal" if finger == "th" else f"{finger}_distal"
        d = _signed_distance(hulls, data, distal, data.site(f"tip_{finger}").xpos)
        assert abs(d) < 0.001 and d == pytest.approx(value, abs=0.0001), (finger, d)


def test_joint_centres_lie_inside_both_adjacent_hulls(hulls: mujoco.MjModel) -> None:
    """Every hinge's anchor is inside the hull of its own link and (except where the parent is
    the palm box) of the parent link: the links meet at
    the joints as the meshes do (sih_hand.md section 10 (b): 5.6-7.9 mm deep at q = 0).
    At rest, half and fully closed."""
    data = mujoco.MjData(hulls)
    for fraction in (0.0, 0.5, 1.0):
        for name in sih.JOINTS:
            lo, hi = hulls.joint(name).range  # one end is 0 (open), the other closed
            data.qpos[hulls.joint(name).qposadr[0]] = fraction * (lo if lo < 0 else hi)
        mujoco.mj_forward(hulls, data)
        for name in sih.JOINTS:
            joint = hulls.joint(name)
            body = hulls.body(int(joint.bodyid[0]))
            parent = hulls.body(int(body.parentid[0]))
            for link in (body.name, parent.name):
                if link == "palm":
                    continue
                d = _signed_distance(hulls, data, link, data.joint(name).xanchor)
                assert d < -0.004, (fraction, name, link, d)


@pytest.mark.parametrize("kind", ["ur5e", "floating"])
def test_hull_hand_at_home_touches_nothing_of_itself(kind: str) -> None:
    """In the home pose (open, thumb opposed), after 50 physics steps holding it, no hand geom
    touches another (neighbouring fingers are 5-7 mm apart; the self-collision exclusions
    hold), and the hand's joints stay where they were put."""
    cfg = load_env_config(robot={"kind": kind, "hand_geometry": "hulls"})
    robot = make_robot(cfg.robot)
    model = _hull_model(kind)
    robot.index(model, torch.device("cpu"))
    home = robot.home(model)
    data = mujoco.MjData(model)
    data.qpos[:] = home.qpos.numpy()
    data.ctrl[:] = home.ctrl.numpy()
    mocap_pos, mocap_quat = robot.mocap(home.keypoint[None], home.rot[None])
    if mocap_pos is not None:
        data.mocap_pos[:] = mocap_pos[0].numpy()
        data.mocap_quat[:] = mocap_quat[0].numpy()
    hand = {model.body(n).id for n in ("palm", *sih.HULL_OF)}
    for _ in range(50):
        mujoco.mj_step(model, data)
    touching = [
        (model.body(model.geom_bodyid[c.geom1]).name, model.body(model.geom_bodyid[c.geom2]).name)
        for c in data.contact[: data.ncon]
        if model.geom_bodyid[c.geom1] in hand and model.geom_bodyid[c.geom2] in hand
    ]
    assert not touching
    q = data.qpos[robot.hand_qpos.numpy()]
    np.testing.assert_allclose(q, home.qpos[robot.hand_qpos].numpy(), atol=0.02)


def test_hand_joint_damping_is_a_knob_with_the_urdfs_default(floating: mujoco.MjModel) -> None:
    """``[robot] hand_joint_damping`` sets the 11 hand joints' damping; the default is the
    authors' URDF's 0.1."""
    dofs = [floating.joint(n).dofadr[0] for n in sih.JOINTS]
    np.testing.assert_array_equal(floating.dof_damping[dofs], sih.JOINT_DAMPING)
    assert sih.JOINT_DAMPING == 0.1
    model = _hull_model("floating", hand_joint_damping=1.0)
    np.testing.assert_allclose(model.dof_damping[dofs], 1.0)


def _drive_model(drive: str, **robot: object) -> tuple[mujoco.MjModel, object]:
    cfg = load_env_config(robot={"kind": "floating", "hand_drive": drive, **robot})
    return build_scene(cfg, Scene(num_slots=0), []).compile(), make_robot(cfg.robot)


def test_all_joints_drive_has_11_actuators_no_equalities_and_coupled_targets() -> None:
    """``hand_drive = "all-joints"``: the 5 servo actuators come first, then one per follower
    joint with its leader's range, force limit and gain; no equality couples the joints; every
    command (absolute or relative, and the home state) gives each follower its leader's target."""
    model, robot = _drive_model("all-joints", hand_forcerange=0.75)
    joint_eq = int(mujoco.mjtEq.mjEQ_JOINT)
    assert model.nu == 11 and not (model.eq_type == joint_eq).any()  # the mocap weld stays
    assert [model.actuator(i).name for i in range(5)] == [a[0] for a in sih.ACTUATORS]
    for name, joint, leader in sih.FOLLOWER_ACTUATORS:
        act, lead = model.actuator(name), model.actuator(sih.ACTUATORS[leader][0])
        assert model.joint(int(act.trnid[0])).name == joint
        np.testing.assert_array_equal(act.ctrlrange, lead.ctrlrange)
        np.testing.assert_array_equal(act.forcerange, [-0.75, 0.75])
        np.testing.assert_array_equal(act.gainprm[:1], lead.gainprm[:1])
    robot.index(model, torch.device("cpu"))
    home = robot.home(model)
    leaders = robot.hand.actuators[robot.hand.follower_leader]
    torch.testing.assert_close(home.ctrl[robot.hand.followers], home.ctrl[leaders])
    E = 4
    action = torch.zeros(E, robot.action_dim)
    action[:, 6:] = torch.rand(E, 5) * 2 - 1
    palm = home.keypoint.expand(E, 3)
    ctrl = robot.commands(action, palm, palm, home.rot.expand(E, 3, 3),
                          home.ctrl.expand(E, -1), home.qpos.expand(E, -1))[2]
    torch.testing.assert_close(ctrl[:, robot.hand.followers], ctrl[:, leaders])
    assert not torch.equal(ctrl[:, leaders], home.ctrl[leaders].expand(E, -1))
    _, relative = _drive_model("all-joints", hand_action="relative")
    relative.index(model, torch.device("cpu"))
    ctrl = relative.commands(action, palm, palm, home.rot.expand(E, 3, 3),
                             home.ctrl.expand(E, -1), home.qpos.expand(E, -1))[2]
    torch.testing.assert_close(ctrl[:, robot.hand.followers], ctrl[:, leaders])
    # ``equalities`` keeps 5 actuators and the 6 equalities.
    model, robot = _drive_model("equalities")
    assert model.nu == 5 and (model.eq_type == joint_eq).sum() == 6
    robot.index(model, torch.device("cpu"))
    assert robot.hand.followers.numel() == 0


def test_all_joints_drive_closes_each_follower_with_its_leader() -> None:
    """Driving the 11 joints to coupled targets closes the hand as the couplings do: after
    2 s toward 60 % closed at the real servo limit, each follower is within 0.05 rad of its
    leader and the fingers have closed."""
    model, _ = _drive_model("all-joints", hand_forcerange=0.75, hand_joint_damping=0.1)
    data = mujoco.MjData(model)
    for name, _, _, closed in sih.ACTUATORS:
        data.ctrl[model.actuator(name).id] = 0.6 * closed
    for name, _, leader in sih.FOLLOWER_ACTUATORS:
        data.ctrl[model.actuator(name).id] = 0.6 * sih.ACTUATORS[leader][3]
    for _ in range(600):
        mujoco.mj_step(model, data)
    q = {n: data.qpos[model.joint(n).qposadr[0]] for n in sih.JOINTS}
    assert q["if_proximal"] < -0.8
    for follower, leader in sih.COUPLINGS:
        assert abs(q[follower] - q[leader]) < 0.05, (follower, leader, q)
