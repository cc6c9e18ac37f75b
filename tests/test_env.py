"""The lift task on the built-in objects: specs, resets, observations that move with the object,
and the paper's reward against a hand computation. (The bin task: tests/test_bin.py.)"""

from __future__ import annotations

import dataclasses

import h5py
import numpy as np
import pytest
import torch
from tensordict import TensorDict
from torchrl.envs.utils import check_env_specs

from geomgrasp.rotations import (
    axis_angle_to_matrix,
    euler_xyz_to_matrix,
    matrix_to_quat,
    quat_to_matrix,
)
from geomprep.config import Config
from geomprep.sdf_lookup import naive_query
from trainer.config import REPRESENTATIONS, load_env_config
from trainer.errors import TrainerError
from trainer.representations import object_representation, representation_shape
from trainer.tasks import GraspTask, make_env


@pytest.fixture(scope="module")
def env(builtin_data: Config) -> GraspTask:
    cfg = load_env_config(
        num_envs=7, objects="builtin", representation="sdf", data_dir=builtin_data.data_dir
    )
    environment = make_env(cfg, seed=0)
    yield environment
    environment.close()


def test_specs_and_rollout(env: GraspTask) -> None:
    check_env_specs(env)
    rollout = env.rollout(5, break_when_any_done=False)
    assert rollout["next", "reward"].shape == (7, 5, 1)
    assert torch.isfinite(rollout["next", "reward"]).all()
    assert rollout["next", "proprio"].shape == (7, 5, 20)
    # Every built-in object is in some environment.
    assert sorted(env.target_objects().tolist()) == list(range(7))
    assert torch.equal(rollout["next", "object_id"][:, 0, 0], env.target_objects())


def test_partial_reset_touches_only_masked_envs(env: GraspTask) -> None:
    env.reset()
    action = torch.zeros(7, 11)
    action[:, 2] = 1.0  # hands move up
    for _ in range(3):
        env.step(TensorDict({"action": action}, batch_size=[7]))
    before = env.backend.qpos.clone()
    mask = torch.zeros(7, 1, dtype=torch.bool)
    mask[2] = True
    env.reset(TensorDict({"_reset": mask}, batch_size=[7]))
    after = env.backend.qpos
    assert env.state["step_count"].tolist() == [3, 3, 0, 3, 3, 3, 3]
    assert torch.equal(after[mask[:, 0].logical_not()], before[mask[:, 0].logical_not()])
    torch.testing.assert_close(after[2, :6], env.home_qpos[0, :6])


def test_reward_matches_hand_computation(env: GraspTask) -> None:
    env.reset()
    td = env.step(TensorDict({"action": torch.zeros(7, 11)}, batch_size=[7]))["next"]
    r = env.cfg.reward
    lift = td["lift_height"][:, 0]
    distances = td["object"]  # the sdf representation: 5 fingertip distances
    # Independent check of the distances: the naive (unoptimised) grid lookup.
    qpos = env.backend.qpos
    tips = env.kinematics.forward(qpos).site_pos[:, 1:]
    pos, quat = env.target_pose(qpos)
    local = (tips - pos[:, None]) @ quat_to_matrix(quat)
    grids, lows, voxels = [], [], []
    for path in env.objects.h5_paths:
        with h5py.File(path, "r") as f:
            grids.append(f["sdf/grid"][:])
            lows.append(np.asarray(f["sdf"].attrs["bounds_min"]))
            voxels.append(float(np.atleast_1d(f["sdf"].attrs["voxel_size"])[0]))
    naive = naive_query(
        np.stack(grids), np.stack(lows), np.array(voxels), local.double().numpy(),
        env.target_objects().numpy(),
    )
    torch.testing.assert_close(distances.double(), torch.from_numpy(naive), atol=1e-4, rtol=0)
    expected = (
        r.c1 / ((r.h_bar - lift).abs() + r.eps_h)
        + r.c2 * (lift >= r.h_bar).float()
        + r.c3 / (distances.clamp_min(0).sum(-1) + r.eps_sdf)
    )
    torch.testing.assert_close(td["reward"][:, 0], expected)
    torch.testing.assert_close(
        td["reward_lift"] + td["reward_success"] + td["reward_contact"], td["reward"]
    )
    assert not td["success"].any() and not td["done"].any()


@pytest.mark.parametrize("reward", ["com", "none"])
def test_reward_ablations(builtin_data: Config, reward: str) -> None:
    cfg = load_env_config(num_envs=2, objects="builtin_box,builtin_mug", representation="com",
                          data_dir=builtin_data.data_dir)
    cfg = dataclasses.replace(cfg, reward=dataclasses.replace(cfg.reward, kind=reward))
    environment = make_env(cfg)
    environment.reset()
    td = environment.step(TensorDict({"action": torch.zeros(2, 11)}, batch_size=[2]))["next"]
    if reward == "none":
        assert (td["reward_contact"] == 0).all()
    else:
        qpos = environment.backend.qpos
        tips = environment.kinematics.forward(qpos).site_pos[:, 1:]
        com = environment.target_pose(qpos)[0]
        expected = 1.0 / ((tips - com[:, None]).norm(dim=-1).sum(-1) + 0.025)
        torch.testing.assert_close(td["reward_contact"][:, 0], expected)
    environment.close()


def test_contact_difference_pays_the_change_in_closeness(builtin_data: Config) -> None:
    """``reward.contact_shaping = "difference"``: on the same trajectory as the paper's per-step
    term (same seed, same actions), the contact output is the per-step value minus its value at
    the previous step (the first step after a reset: minus the reset state's, which the task
    keeps in ``contact_prev``); the lift and success terms are unchanged and the reward is their
    sum. After a partial reset the reset env starts again from its new state's value."""
    envs = []
    for shaping in ("per-step", "difference"):
        cfg = load_env_config(num_envs=3, objects="builtin_box,builtin_mug", representation="bbox",
                              data_dir=builtin_data.data_dir,
                              reward={"contact_shaping": shaping})
        envs.append(make_env(cfg, seed=1))
    per_step, difference = envs
    per_step.reset()
    difference.reset()
    start = difference.state["contact_prev"].clone()
    assert torch.isfinite(start).all() and (start > 0).all()
    gen = torch.Generator().manual_seed(0)
    previous = start
    for step in range(6):
        if step == 3:  # env 1 starts a new episode
            mask = torch.tensor([[False], [True], [False]])
            for e in envs:
                e.reset(TensorDict({"_reset": mask}, batch_size=[3]))
            previous = previous.clone()
            previous[1] = difference.state["contact_prev"][1]
            assert not torch.equal(previous[1], start[1])  # (another settled state)
        action = TensorDict({"action": torch.rand(3, 11, generator=gen) * 2 - 1}, batch_size=[3])
        paid = per_step.step(action.clone())["next"]
        shaped = difference.step(action.clone())["next"]
        torch.testing.assert_close(shaped["reward_contact"][:, 0],
                                   paid["reward_contact"][:, 0] - previous)
        for key in ("reward_lift", "reward_success"):
            torch.testing.assert_close(shaped[key], paid[key])
        torch.testing.assert_close(
            shaped["reward"],
            shaped["reward_lift"] + shaped["reward_success"] + shaped["reward_contact"],
        )
        previous = paid["reward_contact"][:, 0]
    for e in envs:
        e.close()


@pytest.mark.parametrize("name", REPRESENTATIONS)
def test_representations_move_with_the_object(env: GraspTask, name: str) -> None:
    ids = torch.arange(7)
    gen = torch.Generator().manual_seed(3)
    pos_a = torch.rand(7, 3, generator=gen) * 0.2
    rot_a = axis_angle_to_matrix(torch.randn(7, 3, generator=gen))
    tips_local = torch.randn(7, 5, 3, generator=gen) * 0.05
    move = axis_angle_to_matrix(torch.randn(7, 3, generator=gen))
    shift = torch.randn(7, 3, generator=gen) * 0.1
    pos_b = (move @ pos_a[..., None])[..., 0] + shift
    rot_b = move @ rot_a

    def rep(pos: torch.Tensor, rot: torch.Tensor) -> torch.Tensor:
        tips = tips_local @ rot.transpose(1, 2) + pos[:, None]
        return object_representation(name, env.objects, ids, pos, matrix_to_quat(rot), tips)

    a, b = rep(pos_a, rot_a), rep(pos_b, rot_b)
    assert a.shape == (7, *representation_shape(name))
    apply = lambda x: (move @ x[..., None])[..., 0] + shift  # noqa: E731
    if name == "com":
        torch.testing.assert_close(b[:, :3], apply(a[:, :3]), atol=1e-5, rtol=0)
    elif name == "bbox":
        torch.testing.assert_close(b[:, :3], apply(a[:, :3]), atol=1e-5, rtol=0)
        torch.testing.assert_close(
            quat_to_matrix(b[:, 3:7]), move @ quat_to_matrix(a[:, 3:7]), atol=1e-5, rtol=0
        )
        torch.testing.assert_close(b[:, 7:], a[:, 7:])
    elif name == "sq":
        torch.testing.assert_close(b[:, :5], a[:, :5])
        torch.testing.assert_close(b[:, 8:], apply(a[:, 8:]), atol=1e-5, rtol=0)
        torch.testing.assert_close(
            euler_xyz_to_matrix(b[:, 5:8]), move @ euler_xyz_to_matrix(a[:, 5:8]),
            atol=1e-5, rtol=0,
        )
    elif name.startswith("pc"):
        torch.testing.assert_close(b, a @ move.transpose(1, 2) + shift[:, None], atol=1e-5, rtol=0)
    else:  # sdf: fingertips fixed to the object see the same distances wherever it is
        torch.testing.assert_close(b, a, atol=1e-4, rtol=0)
        assert (a.abs() < 0.5).all()


@pytest.mark.slow
def test_compiled_env_matches_eager(builtin_data: Config) -> None:
    """``compile = true`` runs the same task computations through torch.compile: the same
    commands, observations and rewards, up to float32 rounding (and the SDF lookup's other
    code path under the compiler)."""
    outputs = []
    for compiled in (False, True):
        cfg = load_env_config(num_envs=7, objects="builtin", representation="sdf",
                              data_dir=builtin_data.data_dir)
        environment = make_env(dataclasses.replace(cfg, compile=compiled), seed=3)
        td = environment.reset()
        gen = torch.Generator().manual_seed(0)
        steps = []
        for _ in range(4):
            td["action"] = torch.rand(7, 11, generator=gen) * 2 - 1
            out, td = environment.step_and_maybe_reset(td)
            steps.append(out["next"].select("proprio", "object", "reward", "done").clone())
        outputs.append((steps, environment.state["ctrl"].clone()))
        environment.close()
    (eager, eager_ctrl), (compiled, compiled_ctrl) = outputs
    torch.testing.assert_close(compiled_ctrl, eager_ctrl, atol=1e-4, rtol=1e-4)
    for a, b in zip(eager, compiled, strict=True):
        for key in ("proprio", "object"):
            torch.testing.assert_close(b[key], a[key], atol=1e-3, rtol=1e-3)
        torch.testing.assert_close(b["reward"], a["reward"], atol=1e-2, rtol=1e-3)
        assert torch.equal(b["done"], a["done"])


@pytest.mark.slow
def test_compile_failure_falls_back_to_eager(builtin_data: Config) -> None:
    # A machine without a working C++ compiler: the env warns once per function and runs eagerly.
    import torch._inductor.config as inductor

    # The smallest graph to compile (the com reward: no SDF lookups), as compiling is what
    # takes the time here, up to the C++ step that fails.
    cfg = load_env_config(num_envs=3, objects="builtin_box", representation="com",
                          reward={"kind": "com"}, data_dir=builtin_data.data_dir)
    environment = make_env(dataclasses.replace(cfg, compile=True))
    # inductor's own patch (monkeypatch's undo leaves fx_graph_cache unreadable for later tests).
    broken = {"cpp.cxx": ("/nonexistent-c++",), "fx_graph_cache": False}
    with inductor.patch(broken), pytest.warns(UserWarning, match="torch.compile failed"):
        rollout = environment.rollout(2)
    assert torch.isfinite(rollout["next", "reward"]).all()
    environment.close()


def test_object_thrown_out_of_reach_is_unstable_not_a_lift(env: GraspTask) -> None:
    """A contact that launches an object (seen with impratio 10: hundreds of metres up, every
    speed finite and below MAX_SPEED) truncates the episode with no reward and no success, both
    once the object is out of reach and while it flies faster than LAUNCH_SPEED."""
    env.reset()
    qpos = env.backend.qpos.clone()
    slot = env.state["target_slot"]
    z = env.slot_qpos[slot, 2]  # (E,) the target's height in qpos
    qpos[0, z[0]] = 5.0  # far above any reach: launched
    qpos[1, z[1]] += 0.5  # lifted by 0.5 m, within reach (not held: no success, see below)
    qvel = torch.zeros_like(env.backend.qvel)
    qvel[2, env.slot_linvel[slot[2], 2]] = 20.0  # shot upward at 20 m/s, still on the table
    env.backend.set_state(torch.arange(7), qpos, qvel, env.state["ctrl"])
    td = env._observe(reset=False)
    assert td["unstable"][:, 0].tolist() == [True, False, True] + [False] * 4
    assert not td["success"][:, 0].any()
    assert td["truncated"][0, 0] and not td["terminated"][0, 0]
    assert td["reward"][0, 0] == 0.0 and td["reward"][1, 0] > 0.0


def test_hold_action_keeps_the_commands(env: GraspTask) -> None:
    """``hold_action`` (how ``trainer play`` holds a finished episode's grasp): the step it
    drives leaves the commanded palm pose and the hand's targets where they were, wherever the
    random actions before it had put them."""
    env.reset()
    generator = torch.Generator().manual_seed(0)
    for _ in range(4):
        action = 0.3 * (2.0 * torch.rand(7, 11, generator=generator) - 1.0)
        env.step(TensorDict({"action": action}, batch_size=[7]))
    before = {k: env.state[k].clone() for k in ("target_pos", "target_rot", "ctrl")}
    hold = env.hold_action()
    assert hold.shape == (7, 11) and bool((hold.abs() <= 1.0 + 1e-6).all())
    assert not torch.allclose(hold[:, 6:], hold[:1, 6:].expand(7, -1))  # the envs differ
    env.step(TensorDict({"action": hold}, batch_size=[7]))
    torch.testing.assert_close(env.state["target_rot"], before["target_rot"])
    hand = env.robot.hand.actuators
    torch.testing.assert_close(env.state["ctrl"][:, hand], before["ctrl"][:, hand])
    # The palm command stays unless the hand lags it by more than the leash.
    torch.testing.assert_close(env.state["target_pos"], before["target_pos"], atol=1e-5, rtol=0)


def test_success_is_a_lift_while_held() -> None:
    """Success needs the target lifted by h_bar *and* ``hold_tips`` fingertip pads within
    ``hold_distance`` of its surface: a policy that bats the ball up through h_bar (the hand
    ~20 cm away, seen in training) does not succeed. hold_tips = 0: any rise counts."""
    from trainer.config import EnvConfig, RewardConfig
    from trainer.tasks.outputs import termination

    far, near = 0.2, 0.005
    lift = torch.tensor([0.25, 0.25, 0.25, 0.10, 0.25])
    tip_distance = torch.tensor([
        [far] * 5,                    # tossed: nothing near
        [near, 0.019, far, far, far],  # thumb and index pads on it: held
        [near, far, far, far, far],    # one pad: balanced, not held
        [near] * 5,                    # held, not yet lifted enough
        [-0.003, near, far, far, far],  # a pad pressed into the surface counts
    ])
    step_count = torch.zeros(5, dtype=torch.long)
    obj_pos = torch.zeros(5, 3)
    obj_pos[:, 2] = 0.5
    for hold_tips, expected in ((2, [False, True, False, False, True]),
                                (1, [False, True, True, False, True]),
                                (0, [True, True, True, False, True])):
        cfg = EnvConfig(reward=RewardConfig(hold_tips=hold_tips))
        success, terminated, _ = termination(
            cfg, lift, torch.tensor(0.2), tip_distance, obj_pos, step_count
        )
        assert success.tolist() == expected, hold_tips
        assert torch.equal(terminated, success)  # on the table: only a success ends it


def test_hold_from_relaxes_only_the_low_training_targets() -> None:
    """``reward.hold_from``: a curriculum target below it succeeds on any rise (a toss too); at
    or above it, and so always at the task's h_bar, the target must be held. A hold_from above
    h_bar would let evaluation count tosses: refused in one line."""
    from trainer.config import EnvConfig, RewardConfig
    from trainer.tasks.outputs import termination

    far, near = 0.2, 0.005
    lift = torch.tensor([0.06, 0.06, 0.25, 0.25])
    h_bar = torch.tensor([0.05, 0.05, 0.2, 0.2])  # per env: two at a low target, two at h_bar
    tip_distance = torch.tensor([[far] * 5, [near] * 5, [far] * 5, [near] * 5])
    cfg = EnvConfig(reward=RewardConfig(hold_from=0.1))
    success, _, _ = termination(
        cfg, lift, h_bar, tip_distance, torch.zeros(4, 3), torch.zeros(4, dtype=torch.long)
    )
    assert success.tolist() == [True, True, False, True]
    with pytest.raises(TrainerError, match=r"hold_from.*at most h_bar"):
        load_env_config(reward={"hold_from": 0.3})


def test_observed_fingertips_extend_proprio_with_the_pad_positions(builtin_data: Config) -> None:
    """``observe_fingertips``: ``proprio`` gains the 5 fingertip pads' world positions after its
    20 values (the spec says 35); the 20 are what they were without it."""
    from trainer.kinematics import SiteKinematics

    cfg = load_env_config(num_envs=3, objects="builtin", representation="com",
                          data_dir=builtin_data.data_dir, observe_fingertips=True)
    env = make_env(cfg, seed=0)
    plain = make_env(dataclasses.replace(cfg, observe_fingertips=False), seed=0)
    try:
        check_env_specs(env)
        assert env.observation_spec["proprio"].shape == (3, 35)
        proprio = env.reset()["proprio"]
        torch.testing.assert_close(proprio[:, :20], plain.reset()["proprio"])
        kinematics = SiteKinematics(env.backend.model, env.robot.sites)
        tips = kinematics.forward(env.backend.qpos).site_pos[:, 1:]
        torch.testing.assert_close(proprio[:, 20:], tips.reshape(3, 15))
        td = env.rollout(3, break_when_any_done=False)
        tips = kinematics.forward(env.backend.qpos).site_pos[:, 1:]
        torch.testing.assert_close(td["next", "proprio"][:, -1, 20:], tips.reshape(3, 15))
    finally:
        env.close()
        plain.close()


def test_observed_hand_targets_follow_relative_actions(builtin_data: Config) -> None:
    """``observe_hand_targets``: ``proprio`` ends with the 5 servo targets on the actions'
    scale (home: thumb rotation +1, the rest -1 open); with relative actions a +1 action moves
    each by ``hand_relative_step`` of its range (in [-1, 1] units: 2 * step / span)."""
    cfg = load_env_config(num_envs=2, objects="builtin", representation="com",
                          data_dir=builtin_data.data_dir, observe_hand_targets=True,
                          robot={"hand_action": "relative"})
    env = make_env(cfg, seed=0)
    try:
        check_env_specs(env)
        assert env.observation_spec["proprio"].shape == (2, 25)
        targets = env.reset()["proprio"][:, 20:]
        torch.testing.assert_close(targets, torch.tensor([[1.0, -1, -1, -1, -1]] * 2))
        action = torch.zeros(2, 11)
        action[:, 7:] = 1.0  # close the thumb's flexion and the fingers by one step
        td = env.step(TensorDict({"action": action}, batch_size=[2]))
        span = (env.robot.hand.closed - env.robot.hand.open).abs()
        step = 2 * cfg.robot.hand_relative_step / span
        expected = torch.tensor([1.0, -1, -1, -1, -1]) + torch.cat([torch.zeros(1), step[1:]])
        torch.testing.assert_close(td["next", "proprio"][:, 20:], expected.expand(2, 5))
    finally:
        env.close()


def test_a_hand_that_starts_in_the_object_is_reported(builtin_data: Config) -> None:
    """Building a task checks every settled initial state with MuJoCo's collision detection:
    a home pose low enough to touch the object is one warning naming the object, in how many
    of its states, and the fix; a home pose above it is silent."""
    import warnings

    from trainer.assets.collision import BIT_HAND
    from trainer.errors import TrainerWarning
    from trainer.init_states import hand_touches, turned

    def build(home: float, above: bool = False) -> tuple[list[str], GraspTask]:
        cfg = load_env_config(num_envs=16, objects="builtin_cylinder", representation="com",
                              data_dir=builtin_data.data_dir,
                              robot={"home_hand_height": home, "home_above_objects": above})
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            env = make_env(cfg, seed=0)
        return [str(w.message) for w in caught if issubclass(w.category, TrainerWarning)], env

    def touched(env: GraspTask, home: int) -> np.ndarray:
        """(B,): the settled states the hand at ``home`` touches turned to any of 16 yaws."""
        states = env.banks[0]  # (B, 1, 7): the one layout's settled states
        yaws = torch.arange(16) * (torch.pi / 8)
        states = turned(states.repeat_interleave(16, 0), yaws.repeat(len(states)))
        hits = hand_touches(env.backend.models[0], env.home_qpos[home].cpu().numpy(),
                            states.numpy(), env.slot_qpos.cpu().numpy(), BIT_HAND)
        return hits.reshape(-1, 16).any(1)

    (low,), env = build(0.05)
    count = int(touched(env, 0).sum())
    assert count > 32  # the palm 5 cm above the table: in most of the cylinder's states
    assert f"builtin_cylinder ({count} of 64)" in low and "home_above_objects = true" in low
    assert "\n" not in low
    env.close()
    messages, env = build(0.28)
    assert messages == [] and not touched(env, 0).any() and len(env.home_height) == 1
    env.close()
    # Raised per settled state: each starts from the lowest 1 cm step that touches nothing.
    messages, env = build(0.05, above=True)
    assert messages == []
    torch.testing.assert_close(env.home_height, 0.05 + 0.01 * torch.arange(len(env.home_height)))
    index = env.home_index[0].cpu().numpy()
    hits = np.stack([touched(env, h) for h in range(len(env.home_height))])  # (H, B)
    states = np.arange(len(index))
    assert not hits[index, states].any() and hits[index[index > 0] - 1, states[index > 0]].all()
    assert index.min() < index.max()  # lying states start lower than standing ones
    # After a reset every env's hand is clear of its object, the palm at one of the heights.
    env.reset()
    qpos = env.backend.qpos.cpu().numpy()
    slots = env.slot_qpos.cpu().numpy()
    for i in range(env.cfg.num_envs):
        state = qpos[i, slots][None]  # (1, 1, 7): the object as the reset turned it
        assert not hand_touches(env.backend.models[0], qpos[i], state, slots, BIT_HAND).any()
    palm = env.kinematics.forward(env.backend.qpos).site_pos[:, 0, 2]
    assert ((palm[:, None] - env.home_height).abs().min(1).values < 2e-3).all()
    torch.testing.assert_close(env.state["palm_pos"][:, 2], palm, atol=2e-3, rtol=0)
    env.close()


def test_lift_clearance_counts_a_lift_not_a_tip(builtin_data: Config) -> None:
    """``reward.lift_clearance``: a settled box's lowest surface sample is on the table top
    (z = 0) and is the episode's ``start_low``; tipped 40 degrees about its lowest edge the box's
    centre rises past a 1 cm target but its lowest point does not: the lift (``lift_height``,
    the lift term) is the lowest point's ~0 and there is no success. Raised 5 cm more, clear of
    the table, the lift is the centre's rise and it succeeds. Without the option the tip is a
    lift (the paper's centre rise)."""
    from geomgrasp.rotations import axis_angle_to_matrix, matrix_to_quat, quat_to_matrix

    def build(clearance: float) -> GraspTask:
        cfg = load_env_config(num_envs=2, objects="builtin_box", representation="bbox",
                              data_dir=builtin_data.data_dir,
                              reward={"lift_clearance": clearance, "hold_tips": 0},
                              robot={"home_above_objects": True})
        env = make_env(cfg, seed=0)
        env.reset()
        env.set_lift_target(0.01)
        return env

    def place(env: GraspTask, tip: bool) -> torch.Tensor:
        """Env 0's box tipped (or raised 5 cm) from its reset pose; env 1 left as it is.
        Returns env 0's centre rise (m)."""
        qpos = env.backend.qpos.clone()
        pose_index = env.slot_qpos[env.state["target_slot"][0]]  # (7,)
        pos, quat = qpos[0, pose_index[:3]], qpos[0, pose_index[3:]]
        rot = quat_to_matrix(quat[None])[0]
        if tip:
            points = env.objects.points[0] @ rot.T + pos  # (512, 3) in the world
            bottom = points[points[:, 2] < points[:, 2].min() + 0.002]
            pivot = bottom[(bottom[:, :2] - pos[:2]).norm(dim=-1).argmax()]  # on an edge
            axis = torch.linalg.cross(torch.tensor([0.0, 0.0, 1.0]), pivot - pos)
            axis[2] = 0.0
            spin = axis_angle_to_matrix((axis / axis.norm() * -0.7)[None])[0]  # 40 degrees
            new_pos, new_rot = pivot + spin @ (pos - pivot), spin @ rot
            if new_pos[2] < pos[2]:  # the other way round lifts the centre
                spin = spin.T
                new_pos, new_rot = pivot + spin @ (pos - pivot), spin @ rot
        else:
            new_pos, new_rot = pos + torch.tensor([0.0, 0.0, 0.05]), rot
        qpos[0, pose_index[:3]] = new_pos
        qpos[0, pose_index[3:]] = matrix_to_quat(new_rot[None])[0]
        env.backend.set_state(torch.arange(2), qpos, torch.zeros_like(env.backend.qvel),
                              env.state["ctrl"])
        return new_pos[2] - pos[2]

    env = build(0.01)
    pos, quat = env.target_pose()
    low = env.lowest_point(pos, quat, env.target_objects())
    torch.testing.assert_close(env.state["start_low"], low)
    assert low.abs().max() < 0.003  # settled on the table top
    r = env.cfg.reward
    rise = place(env, tip=True)
    assert rise > 0.01
    td = env._observe(reset=False)
    assert not bool(td["success"].any())  # a tip is not a lift ...
    assert abs(float(td["lift_height"][0, 0])) < 0.003  # ... and is paid as none
    paid = r.c1 / ((0.01 - td["lift_height"][0, 0]).abs() + r.eps_h)
    torch.testing.assert_close(td["reward_lift"][0, 0], paid)
    place(env, tip=False)  # (from the tipped pose: tipped and 5 cm up, clear of the table)
    td = env._observe(reset=False)
    assert td["success"][:, 0].tolist() == [True, False]
    centre_rise = env.target_pose()[0][0, 2] - env.state["start_height"][0]
    torch.testing.assert_close(td["lift_height"][0, 0], centre_rise)
    env.close()
    plain = build(0.0)
    rise = place(plain, tip=True)
    td = plain._observe(reset=False)
    assert td["success"][:, 0].tolist() == [True, False]
    torch.testing.assert_close(td["lift_height"][0, 0], rise, atol=1e-5, rtol=0)
    plain.close()


@pytest.mark.parametrize("representation", ["bbox", "sdf"])
def test_observed_shapes_change_what_the_policy_is_told_only(
    builtin_data: Config, representation: str
) -> None:
    """``StepOutputs.observed``: objects told with other shapes (boxes twice their size, an SDF
    1 cm further out) change the ``object`` observation and nothing else: on the same seed and
    actions the physics, the proprioception, every reward term and the success are those of the
    real objects, also for sdf, whose reward otherwise reuses the observation's distances."""
    cfg = load_env_config(num_envs=3, objects="builtin_box,builtin_mug",
                          representation=representation, data_dir=builtin_data.data_dir)
    real, told = make_env(cfg, seed=2), make_env(cfg, seed=2)
    try:
        real_sdf = told.objects.sdf

        class FarSDF:  # the sdf representation told every fingertip 1 cm further out
            def query(self, *args: torch.Tensor) -> torch.Tensor:
                return real_sdf.query(*args) + 0.01

        told.outputs.observed = dataclasses.replace(
            told.objects, bbox_extents=told.objects.bbox_extents * 2, sdf=FarSDF())
        a, b = real.reset(), told.reset()
        gen = torch.Generator().manual_seed(0)
        for _ in range(4):
            if representation == "bbox":
                torch.testing.assert_close(b["object"][:, 7:], 2 * a["object"][:, 7:])
                torch.testing.assert_close(b["object"][:, :7], a["object"][:, :7])
            else:
                torch.testing.assert_close(b["object"], a["object"] + 0.01)
            torch.testing.assert_close(b["proprio"], a["proprio"])
            action = torch.rand(3, 11, generator=gen) * 2 - 1
            a = real.step(TensorDict({"action": action}, batch_size=[3]))["next"]
            b = told.step(TensorDict({"action": action.clone()}, batch_size=[3]))["next"]
            for key in ("reward", "reward_contact", "reward_lift", "success", "lift_height"):
                torch.testing.assert_close(b[key], a[key])
        torch.testing.assert_close(told.backend.qpos, real.backend.qpos)
    finally:
        real.close()
        told.close()
