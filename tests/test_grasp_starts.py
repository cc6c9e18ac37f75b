"""``[run] grasp_starts``: training episodes that start along a scripted grasp that lifted
(trainer.training.grasp_starts), on the built-in objects with the top grasp."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
from tensordict import TensorDict

from geomprep.config import Config
from tests.tiny_runs import own_data_dir, tiny_grasp_start_config
from trainer.config import RewardConfig, load_env_config
from trainer.errors import TrainerError
from trainer.randomness import RandomStreams
from trainer.tasks import make_env
from trainer.tasks.starts import GraspStarts
from trainer.training.curriculum import LiftCurriculum
from trainer.training.grasp_starts import record_grasp_starts
from trainer.training.outcomes import EpisodeStats


def _cfg(builtin_data: Config, robot: dict | None = None, **overrides: object):  # noqa: ANN202
    return load_env_config(**{"num_envs": 4, "objects": "builtin_cylinder,builtin_box",
                              "representation": "bbox", "data_dir": builtin_data.data_dir,
                              "robot": {"home_above_objects": True, **(robot or {})},
                              **overrides})


@pytest.fixture(scope="module")
def top_starts(builtin_data: Config) -> GraspStarts:
    """The top grasp's starts on ``_cfg`` (one round, seed 0), recorded once for the tests that
    use or compare with them (they only read them)."""
    return record_grasp_starts(_cfg(builtin_data), RandomStreams(0), "top", rounds=1)


def test_resets_start_from_recorded_grasps_that_lifted(
    builtin_data: Config, top_starts: GraspStarts
) -> None:
    """The recorded captures are valid only for trials that lifted their object; with fraction
    1 every env that has one starts from one of its own captures (its state, flagged
    ``grasp_start``, step 0), the others start home; with fraction 0 none does."""
    cfg = _cfg(builtin_data)
    starts = top_starts
    E, S = starts.valid.shape
    assert E == 4 and S >= 2
    assert torch.equal(starts.valid.any(1), starts.lifted.any(1))
    assert bool(starts.lifted.any())  # the top grasp lifts some of the built-in objects
    env = make_env(cfg, seed=RandomStreams(1))
    env.set_grasp_starts(starts, 1.0, torch.Generator().manual_seed(0))
    td = env.reset()
    flagged = td["grasp_start"][:, 0].clone()
    assert torch.equal(flagged, starts.valid.any(1))
    assert (env.state["step_count"] == 0).all()
    qpos = env.backend.qpos
    gap = (qpos[:, None] - starts.qpos).abs().amax(-1)  # (E, S)
    gap = gap.masked_fill(~starts.valid, float("inf")).amin(1)
    assert (gap[flagged] < 1e-6).all()  # each flagged env is in one of its own captures
    home = env.home_qpos[env.home_index[env.env_layout, 0]][:, env.hand_qpos]
    assert (qpos[~flagged][:, env.hand_qpos] - home[~flagged]).abs().max() < 1e-6
    # The hand keeps the script's commands: ctrl and the palm target come with the state.
    for i in flagged.nonzero()[:, 0].tolist():
        s = int(((qpos[i] - starts.qpos[i]).abs().amax(-1)).argmin())
        torch.testing.assert_close(env.state["ctrl"][i], starts.task["ctrl"][i, s])
        torch.testing.assert_close(env.state["target_pos"][i], starts.task["target_pos"][i, s])
    # Each output keeps its own flags: a collector stacks a rollout's outputs at its end,
    # after later resets have changed the task's state (this aliasing once mislabelled them).
    td["action"] = torch.zeros(4, 11)
    stepped = env._step(td)["grasp_start"][:, 0]  # the task's own output, as collectors keep it
    assert torch.equal(stepped, flagged)
    env.state["grasp_start"][:] = False  # as the next reset of these envs would
    assert torch.equal(stepped, flagged)
    env.set_grasp_starts(starts, 0.0, torch.Generator().manual_seed(0))
    assert not env.reset()["grasp_start"].any()
    env.close()


def test_grasp_start_episodes_count_in_no_success_rate() -> None:
    """Two episodes end lifted, one of them started from a scripted grasp: only the other
    counts in the success rates and in the curriculum."""
    stats = EpisodeStats(num_envs=2, window=16, task_h_bar=0.2, device=torch.device("cpu"))
    curriculum = LiftCurriculum(RewardConfig(h_bar_start=0.2), num_objects=1, window=16)
    flag = lambda *v: torch.tensor(v).reshape(2, 1, 1)  # noqa: E731
    data = TensorDict({"next": {
        "reward": torch.ones(2, 1, 1), "done": flag(True, True), "success": flag(True, True),
        "lift_height": torch.full((2, 1, 1), 0.25), "object_id": torch.zeros(2, 1, 1).long(),
        "unstable": flag(False, False), "grasp_start": flag(True, False),
    }}, batch_size=[2, 1])
    assert stats.record(data, curriculum)["episodes"] == 1
    assert list(stats.outcomes) == [True]
    assert list(curriculum.outcomes) == [True]


def test_bin_starts_restore_the_clutter_and_the_target(builtin_data: Config) -> None:
    """In the bin the script grasps each episode's target in its clutter: a start puts back
    every object of the bin as it was captured and the target slot the script grasped (another
    slot would reward lifting the wrong object), and the episode's object is that target's."""
    cfg = load_env_config(num_envs=8, task="bin", objects="builtin", representation="bbox",
                          data_dir=builtin_data.data_dir,
                          robot={"home_hand_height": 0.2, "home_above_objects": True},
                          bin={"num_objects": 3, "layouts": 2, "bank_size": 4})
    starts = record_grasp_starts(cfg, RandomStreams(0), "top", rounds=2)
    assert bool(starts.lifted.any())  # the top grasp picks some targets out of the bin
    assert torch.equal(starts.valid.any(1), starts.lifted.any(1))
    env = make_env(cfg, seed=RandomStreams(1))
    env.set_grasp_starts(starts, 1.0, torch.Generator().manual_seed(0))
    td = env.reset()
    flagged = td["grasp_start"][:, 0].clone()
    assert torch.equal(flagged, starts.valid.any(1))
    qpos = env.backend.qpos
    for i in flagged.nonzero()[:, 0].tolist():
        gap = (qpos[i] - starts.qpos[i]).abs().amax(-1)  # (S,) every slot's pose, the robot's
        s = int(gap.argmin())
        assert bool(starts.valid[i, s]) and gap[s] < 1e-6
        assert env.state["target_slot"][i] == starts.task["target_slot"][i, s]
        assert td["object_id"][i, 0] == env.assignment[i, starts.task["target_slot"][i, s]]
    env.close()


def test_objects_without_a_best_family_get_a_searched_grasp_once(
    builtin_data: Config, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Family "best" on objects nobody tuned (no ``BEST`` entry): each is searched once, said
    in a line, stored in the data directory for the run's hand and physics, and its searched
    grasp recorded (the searched family's script reads the stored rows); the next recording
    finds them and searches nothing."""
    import trainer.grasps.search as search
    from trainer.grasps import searched
    from trainer.grasps.search import SearchSettings

    data_dir = own_data_dir(builtin_data, tmp_path / "data")
    cfg = _cfg(Config(data_dir=data_dir))
    searches: list[str] = []
    real_search = search.search_grasp

    def counted(cfg, name: str, settings: SearchSettings) -> search.SearchResult:  # noqa: ANN001
        searches.append(name)
        return real_search(cfg, name, settings)

    monkeypatch.setattr(search, "search_grasp", counted)
    tiny = SearchSettings(population=2, trials=1, iterations=1, elite=2)
    lines: list[str] = []
    starts = record_grasp_starts(cfg, RandomStreams(0), "best", rounds=1, search=tiny,
                                 echo=lines.append)
    assert searches == ["builtin_cylinder", "builtin_box"]
    assert lines[0] == ("no grasp for builtin_cylinder with this hand and physics: searching "
                        "(2 candidates x 1 trials, 1 iterations)")
    assert len(lines) == 4 and lines[1].startswith("builtin_cylinder: the grasp found lifted")
    for name in ("builtin_cylinder", "builtin_box"):
        assert set(searched.read_object(data_dir, name)) == {searched.hand_key(cfg)}
    assert starts.valid.shape[0] == 4 and torch.equal(starts.valid.any(1),
                                                      starts.lifted.any(1))
    lines.clear()
    again = record_grasp_starts(cfg, RandomStreams(0), "best", rounds=1, search=tiny,
                                echo=lines.append)
    assert searches == ["builtin_cylinder", "builtin_box"] and lines == []
    assert torch.equal(again.valid, starts.valid)
    torch.testing.assert_close(again.qpos, starts.qpos)


def test_relative_hand_actions_record_the_same_starts(
    builtin_data: Config, top_starts: GraspStarts
) -> None:
    """The scripts command absolute targets; a run with relative hand actions has the same
    model and state, so its starts are recorded with absolute ones: the same states."""
    absolute = top_starts
    relative = record_grasp_starts(_cfg(builtin_data, robot={"hand_action": "relative"}),
                                   RandomStreams(0), "top", rounds=1)
    assert torch.equal(relative.valid, absolute.valid)
    torch.testing.assert_close(relative.qpos, absolute.qpos)


def test_what_the_policy_observes_and_the_shaping_term_share_one_recording(
    builtin_data: Config, top_starts: GraspStarts
) -> None:
    """Runs that differ only in ``UNRECORDED_FIELDS`` (representation, context, observed extras,
    the reward's shaping term) record the same states, so their starts share one key; a field
    the physics reads (the solver's iterations) is another key."""
    from trainer.config import load_train_config
    from trainer.training.grasp_starts import starts_key

    other = record_grasp_starts(
        _cfg(builtin_data, representation="sdf", observe_fingertips=True,
             reward={"kind": "com", "contact_shaping": "difference"}),
        RandomStreams(0), "top", rounds=1)
    assert torch.equal(other.valid, top_starts.valid) and torch.equal(other.qpos, top_starts.qpos)
    keys = top_starts.task.keys()  # (a TensorDict iterates over its rows)
    assert all(torch.equal(other.task[k], top_starts.task[k]) for k in keys)

    def key(**env: object) -> str:
        cfg = load_train_config(env={"objects": "builtin_cylinder", **env})
        return starts_key(cfg, {"builtin_cylinder": {"family": "top"}})

    base = key()
    assert key(task="bin", context="bbox") == key(task="bin")
    assert key(representation="pc128", observe_hand_targets=True,
               reward={"kind": "none", "contact_shaping": "difference"}) == base
    assert key(physics={"iterations": 7}) != base
    assert key(reward={"h_bar_start": 0.05}) != base  # the success test's curriculum counts


def test_closing_phase_keeps_the_states_of_the_closing_only(
    builtin_data: Config, top_starts: GraspStarts
) -> None:
    """``phase = "closing"``: one state every 10 actions of the script's closing window and its
    end, where ``approach`` keeps every 10 actions from the 10th; both end with the same state,
    the hand closed (the same trials)."""
    from trainer.grasps.top import TopGrasp

    start, end = TopGrasp().close_window
    approach = top_starts
    closing = record_grasp_starts(_cfg(builtin_data), RandomStreams(0), "top", rounds=1,
                                  phase="closing")
    assert closing.qpos.shape[1] == len({*range(start, end, 10), end})
    assert approach.qpos.shape[1] == len({*range(10, end, 10), end})
    torch.testing.assert_close(closing.qpos[:, -1], approach.qpos[:, -1])
    assert torch.equal(closing.lifted, approach.lifted)


def test_lift_phase_keeps_the_lift_and_starts_only_below_the_target(builtin_data: Config) -> None:
    """``phase = "lift"``: the closing's states and then the script's lift to its end, each with
    the target's rise; a reset starts only from states below the object's current lift target
    (one past it would begin an episode already succeeded), so raising the target brings the
    higher states into use."""
    from trainer.grasps.top import TopGrasp

    start, _ = TopGrasp().close_window
    end = TopGrasp().total_steps
    starts = record_grasp_starts(_cfg(builtin_data), RandomStreams(0), "top", rounds=1,
                                 phase="lift")
    assert starts.qpos.shape[1] == len({*range(start, end, 10), end})
    assert starts.lift is not None
    risen = starts.valid & (starts.lift > 0.05)
    assert bool(risen.any())  # the lift's states are kept, the target well up in them
    env = make_env(_cfg(builtin_data), seed=RandomStreams(1))
    env.set_grasp_starts(starts, 1.0, torch.Generator().manual_seed(0))
    for h_bar, reachable in ((0.03, False), (0.2, True)):
        env.set_lift_target(h_bar)
        picked_high = torch.zeros(4, dtype=torch.bool)
        for _ in range(12):
            env.reset()
            rise = env.lift_height()
            flagged = env.state["grasp_start"]
            assert (rise[flagged] < h_bar + 1e-3).all()
            picked_high |= flagged & (rise > 0.05)
        assert bool(picked_high.any()) == reachable
    env.close()


def test_searched_grasp_records_beside_other_families(
    builtin_data: Config, top_starts: GraspStarts, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Several objects whose best families differ, one of them a searched (keyframe) grasp
    with a row for its own object only (as ``searched.json`` has for the ten Table I objects):
    the recorder runs it on every env, the other objects' envs on a borrowed row, and keeps
    each env's captures from its own family. (The ten together once stopped here with "no
    searched grasp for ...".)"""
    import trainer.training.grasp_starts as grasp_starts
    from trainer.grasps.families import Variant
    from trainer.grasps.keyframes import PARAMS, KeyframeGrasp, top_grasp_theta
    from trainer.grasps.top import TopGrasp

    row = tuple(top_grasp_theta().tolist())
    searched = KeyframeGrasp(by_object=(("builtin_box", row),))
    with pytest.raises(TrainerError, match="no searched grasp for builtin_cylinder"):
        env = make_env(_cfg(builtin_data), seed=RandomStreams(0))
        try:
            searched.env_theta(env)
        finally:
            env.close()
    best = {"searched": (Variant(searched), ["builtin_box"]),
            "top": (Variant(TopGrasp()), ["builtin_cylinder"])}
    monkeypatch.setattr(grasp_starts, "best_variants", lambda names, searched=(): best)
    # (the keyframe grasp's stand-in for a searched one, found without a search)
    monkeypatch.setattr(grasp_starts, "find_grasps", lambda cfg, names, *args: {
        n: {"theta": dict(zip(PARAMS, row, strict=True))} for n in names})
    monkeypatch.setattr(grasp_starts, "BEST", {"builtin_box": "searched",
                                               "builtin_cylinder": "top"})
    starts = record_grasp_starts(_cfg(builtin_data), RandomStreams(0), "best", rounds=1)
    alone = top_starts
    env = make_env(_cfg(builtin_data), seed=RandomStreams(0))
    box = env.target_objects() == env.objects.names.index("builtin_box")
    env.close()
    assert bool(box.any()) and bool((~box).any())
    # The cylinder's envs keep the top grasp's captures, as a run of the top grasp alone.
    assert torch.equal(starts.lifted[~box], alone.lifted[~box])
    n = alone.qpos.shape[1]
    torch.testing.assert_close(starts.qpos[~box, :n], alone.qpos[~box])
    assert bool(starts.lifted.any())


def count_recordings(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    """Count the runs' grasp-start recordings: one item per call of ``record_grasp_starts``
    from ``trainer.ppo`` (which still records)."""
    import trainer.ppo

    recordings: list[int] = []
    real_record = trainer.ppo.record_grasp_starts

    def counted(*args: object, **kwargs: object) -> GraspStarts:
        recordings.append(1)
        return real_record(*args, **kwargs)

    monkeypatch.setattr(trainer.ppo, "record_grasp_starts", counted)
    return recordings


def test_recording_the_starts_says_so_and_counts_against_the_time_budget(
    builtin_data: Config, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys  # noqa: ANN001
) -> None:
    """A run with grasp starts says it is recording them (minutes for ten objects, before the
    first iteration) and its clock starts with that time: ``--minutes`` counts it."""
    import csv
    import time

    import trainer.ppo
    from trainer.ppo import train

    recording: list[float] = []

    def slow_record(*args: object, **kwargs: object):  # noqa: ANN202
        began = time.perf_counter()
        time.sleep(1.0)  # a recording long enough to tell from an iteration's time
        starts = record_grasp_starts(*args, **kwargs)
        recording.append(time.perf_counter() - began)
        return starts

    monkeypatch.setattr(trainer.ppo, "record_grasp_starts", slow_record)
    # (its own data directory: no recording of this config kept by another test of the session)
    cfg = tiny_grasp_start_config(Config(data_dir=own_data_dir(builtin_data, tmp_path / "data")))
    run = train(cfg, tmp_path / "run", progress=False)
    assert "recording the grasp starts" in capsys.readouterr().out
    (row,) = csv.DictReader(run.metrics.read_text().splitlines())
    assert len(recording) == 1 and float(row["wall_time_s"]) >= recording[0]


def test_a_repeated_run_loads_the_starts_an_earlier_run_recorded(
    builtin_data: Config, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys  # noqa: ANN001
) -> None:
    """The first run of a config records its grasp starts and keeps them in the data directory
    under the key of what they depend on; a second run of the same config and seed loads them
    (said in a line) instead of recording, and trains from the same starts; another seed is
    another key."""
    import dataclasses

    from trainer.ppo import train
    from trainer.training.grasp_starts import cached_starts_path, object_grasps

    data = Config(data_dir=own_data_dir(builtin_data, tmp_path / "data"))
    cfg = tiny_grasp_start_config(data)
    recordings = count_recordings(monkeypatch)
    first = train(cfg, tmp_path / "first", progress=False)
    cached = cached_starts_path(cfg, object_grasps(cfg.env, "top"))
    assert recordings == [1] and cached.parent == data.data_dir / "grasps" / "starts"
    capsys.readouterr()
    second = train(cfg, tmp_path / "second", progress=False)
    out = capsys.readouterr().out
    assert recordings == [1]
    assert f"grasp starts from {cached} (recorded by an earlier run" in out
    assert "recording the grasp starts" not in out
    a, b = GraspStarts.load(first.grasp_starts), GraspStarts.load(second.grasp_starts)
    assert torch.equal(a.valid, b.valid) and torch.equal(a.qpos, b.qpos)
    other = dataclasses.replace(cfg, run=dataclasses.replace(cfg.run, seed=1))
    assert cached_starts_path(other, object_grasps(cfg.env, "top")) != cached


def test_damaged_grasp_starts_are_recorded_again(
    builtin_data: Config, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys  # noqa: ANN001
) -> None:
    """A run's ``grasp_starts.pt`` or the data directory's recording that does not read back
    (cut short, other bytes, a part missing) is said in one line and replaced, no traceback:
    recorded again (the same states: the same streams) where the other copy is damaged too,
    else taken from the intact copy; ``GraspStarts.load`` refuses each in one line."""
    from trainer.ppo import grasp_starts_of
    from trainer.randomness import run_streams
    from trainer.training.grasp_starts import cached_starts_path, object_grasps
    from trainer.training.run_dir import RunDir

    data = Config(data_dir=own_data_dir(builtin_data, tmp_path / "data"))
    cfg = tiny_grasp_start_config(data)
    run = RunDir(tmp_path / "run")
    run.path.mkdir()
    recordings = count_recordings(monkeypatch)
    starts, _ = grasp_starts_of(cfg, run, run_streams(cfg), False, fresh=True)
    cached = cached_starts_path(cfg, object_grasps(cfg.env, "top"))
    assert recordings == [1] and cached.is_file() and run.grasp_starts.is_file()
    whole = run.grasp_starts.read_bytes()
    # Each damage is refused by the loader in one line naming the file.
    torch.save({"qpos": starts.qpos}, tmp_path / "part.pt")
    (tmp_path / "cut.pt").write_bytes(whole[: len(whole) // 2])
    (tmp_path / "text.pt").write_text("not a tensor file\n")
    for damaged in ("part.pt", "cut.pt", "text.pt"):
        with pytest.raises(TrainerError) as info:
            GraspStarts.load(tmp_path / damaged)
        message = str(info.value)
        assert message.startswith(f"{tmp_path / damaged} is damaged (") and "\n" not in message
    # Both copies damaged: a resumed run records again, the same states, and mends both.
    run.grasp_starts.write_bytes(whole[:100])
    cached.write_text("not a tensor file\n")
    capsys.readouterr()
    again, _ = grasp_starts_of(cfg, run, run_streams(cfg), False, fresh=False)
    out = capsys.readouterr().out
    assert recordings == [1, 1]
    (line,) = [x for x in out.splitlines() if "damaged" in x]
    assert line.startswith(f"{run.grasp_starts} is damaged (") and (
        f"{cached} is damaged (" in line) and line.endswith(
        "recording the grasp starts again; the same streams give the same states")
    assert torch.equal(again.valid, starts.valid) and torch.equal(again.qpos, starts.qpos)
    for path in (run.grasp_starts, cached):
        assert torch.equal(GraspStarts.load(path).qpos, starts.qpos)
    # Only the run's copy damaged: the intact recording is taken, nothing recorded.
    run.grasp_starts.write_bytes(whole[:100])
    again, _ = grasp_starts_of(cfg, run, run_streams(cfg), False, fresh=False)
    out = capsys.readouterr().out
    assert recordings == [1, 1] and torch.equal(again.qpos, starts.qpos)
    assert f"{run.grasp_starts} is damaged (" in out and f"grasp starts from {cached}" in out
    assert torch.equal(GraspStarts.load(run.grasp_starts).qpos, starts.qpos)
