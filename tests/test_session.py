"""trainer.session: the evaluation session reproduces ``trainer eval``'s episodes (its numbers,
in one batch of envs or in several), calls its hooks the expected number of times, and builds
the envs the probes and ``trainer play`` use."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest
import torch

from geomprep.config import Config
from tests.tiny_runs import tiny_dice_mug_run, tiny_run
from trainer.errors import TrainerError
from trainer.evaluation import evaluate
from trainer.session import MAX_ENVS, Episodes, EvalSession, success_reward


@pytest.fixture(scope="module")
def dice_mug(builtin_data: Config, tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tiny_dice_mug_run(builtin_data, tmp_path_factory.mktemp("session") / "run").path


def test_lift_batches_hold_whole_objects() -> None:
    """trainer eval's batch rule: as many whole objects as fit in max_envs envs, one at least."""
    names = ["a", "b", "c", "d", "e"]
    assert EvalSession.lift_batches(names, 300) == [(0, ["a", "b", "c"]), (3, ["d", "e"])]
    assert EvalSession.lift_batches(names, 10, max_envs=25) == [
        (0, ["a", "b"]), (2, ["c", "d"]), (4, ["e"])]
    assert EvalSession.lift_batches(names, 2000) == [(k, [n]) for k, n in enumerate(names)]
    assert EvalSession.lift_batches(names, 10) == [(0, names)] and MAX_ENVS == 1024


class Counting:
    """Hooks that count their calls and check what they are handed."""

    def __init__(self) -> None:
        self.resets: list[int] = []  # per run, its envs
        self.steps: list[int] = []  # per run, its steps
        self.ended: list[torch.Tensor] = []  # per run, (E,) the step each episode ended at
        self.success: list[torch.Tensor] = []

    def on_reset(self, env, td) -> None:  # noqa: ANN001
        assert td.batch_size == (env.num_envs,)
        self.resets.append(env.num_envs)
        self.steps.append(0)
        self.ended.append(torch.full((env.num_envs,), -1))
        self.success.append(torch.zeros(env.num_envs, dtype=torch.bool))

    def on_step(self, env, step: int, td) -> None:  # noqa: ANN001
        assert step == self.steps[-1]
        E = env.num_envs
        assert td["action"].shape == (E, 11) and td["scale"].shape == (E, 11)
        assert td["next", "reward"].shape == (E, 1) and td["next", "done"].shape == (E, 1)
        self.steps[-1] += 1

    def on_episode(self, env, ended: torch.Tensor, success: torch.Tensor) -> None:  # noqa: ANN001
        assert ended.shape == success.shape == (env.num_envs,) and ended.dtype == torch.bool
        assert bool(ended.any()) and not bool((success & ~ended).any())
        assert (self.ended[-1][ended] == -1).all()  # an env's episode ends once
        self.ended[-1][ended] = self.steps[-1] - 1
        self.success[-1] |= success

    def hooks(self) -> dict:
        return {"on_reset": self.on_reset, "on_step": self.on_step,
                "on_episode": self.on_episode}


@pytest.mark.parametrize("max_envs", [MAX_ENVS, 6])
def test_lift_episodes_reproduce_trainer_eval(dice_mug: Path, max_envs: int) -> None:
    """The session's lift episodes are trainer eval's (its counts, one batch or one per
    object), and the hooks run once per batch (reset), once per action (step) and once per
    episode (each env's end, at the step its episode's length says)."""
    result = evaluate(dice_mug, episodes_per_object=6, max_envs=max_envs, out="eval-session")
    session = EvalSession.load(dice_mug)
    names = session.names()
    hooks = Counting()
    episodes = session.lift_episodes(names, 6, max_envs=max_envs, **hooks.hooks())
    assert names == result.names == ["builtin_dice", "builtin_mug"]
    assert isinstance(episodes, Episodes) and episodes.success.shape == (12,)
    assert torch.bincount(episodes.target, minlength=2).tolist() == result.episodes == [6, 6]
    assert torch.bincount(episodes.target[episodes.success],
                          minlength=2).tolist() == result.successes
    assert hooks.resets == ([12] if max_envs == MAX_ENVS else [6, 6])
    ended = torch.cat(hooks.ended)
    assert (ended >= 0).all()  # every episode ended once (12 actions at most)
    torch.testing.assert_close(ended + 1, episodes.length)
    assert hooks.steps == [int(part.max()) + 1 for part in hooks.ended]
    assert torch.equal(torch.cat(hooks.success), episodes.success)
    if max_envs != MAX_ENVS:  # one object per batch: its targets are that object's index
        assert episodes.target.tolist() == [0] * 6 + [1] * 6


def test_run_and_success_override(dice_mug: Path) -> None:
    """``run`` plays one episode per env of any env of the session; ``watch`` ends the rollout
    when those envs have finished. ``load(h_bar=...)`` changes the success as ``trainer eval
    --h-bar`` does (hold_from no higher than it); a bin-only method refuses a lift run."""
    session = EvalSession.load(dice_mug, h_bar=0.05, hold_tips=0)
    reward = session.cfg.env.reward
    assert (reward.h_bar, reward.h_bar_start, reward.hold_tips) == (0.05, 0.05, 0)
    assert success_reward(reward, h_bar=0.01).hold_from <= 0.01
    env = session.env(3, seed=1, compile=False)
    assert env.num_envs == 3 and env.cfg.compile is False
    hooks = Counting()
    success, length, target = session.run(env, **hooks.hooks())
    assert success.shape == length.shape == target.shape == (3,)
    assert hooks.resets == [3] and hooks.steps == [int(length.max())]
    watched = session.run(env, watch=[0])
    assert int(watched.length[0]) == int(watched.length.max())  # stopped at env 0's end
    env.close()
    no_policy = EvalSession(session.cfg)
    with pytest.raises(TrainerError, match="no policy"):
        no_policy.actor  # noqa: B018
    bin_cfg = dataclasses.replace(session.cfg, env=dataclasses.replace(session.cfg.env,
                                                                       task="bin"))
    with pytest.raises(TrainerError, match="a bin run"):
        EvalSession(bin_cfg, session.agent).lift_episodes(["builtin_dice"], 2)


def test_eval_splits_each_object_by_how_its_target_started(dice_mug: Path) -> None:
    """trainer eval counts, per object, the episodes whose target started face up (its mesh's
    z axis up after the first action, as ``scripts/eval_upright.py`` reads it) and
    those that started upside down, with their successes: by_start.csv, summing to the
    per-object totals."""
    import csv

    from tests.tiny_runs import script

    result = evaluate(dice_mug, episodes_per_object=6, out="eval-by-start")
    assert result.face_up is not None
    rows = list(csv.DictReader((dice_mug / "eval-by-start" / "by_start.csv").open()))
    for k, row in enumerate(rows):
        up, down = int(row["face_up_episodes"]), int(row["upside_down_episodes"])
        held = int(row["face_up_successes"]) + int(row["upside_down_successes"])
        assert up + down == result.episodes[k] and held == result.successes[k]
    split = script("scripts", "eval_upright").split_by_start_up(dice_mug, 6)
    expected = [(up, up_held) for _, up, up_held, _, _ in split]
    assert result.face_up == expected


def test_eval_without_sdf_grids_leaves_never_reached_out(
    builtin_data: Config, tmp_path: Path,
) -> None:
    """A run that loads no SDF grids (the centre-of-mass reward, no hold test) has nothing to
    measure the pads' reach with: its evaluation counts the other endings, never reached is
    not a column (rather than zero, or a crash)."""
    import csv

    run = tiny_run(builtin_data, tmp_path / "run", "builtin_dice",
                   reward={"kind": "com", "hold_tips": 0})
    result = evaluate(run.path, episodes_per_object=2)
    assert result.endings is not None and "never reached" not in result.endings
    assert sum(by[0] for by in result.endings.values()) == 2
    header = (run.path / "eval" / "endings.csv").read_text().splitlines()[0]
    assert header == "object,episodes,success,never_lifted,dropped,stalled,knocked_off"
    assert "never reached" not in (run.path / "eval" / "table.md").read_text()
    rows = list(csv.DictReader((run.path / "eval" / "endings.csv").open()))
    assert rows[0]["object"] == "builtin_dice"


def test_eval_names_how_each_episode_ended(dice_mug: Path) -> None:
    """trainer eval puts every episode in one ending (endings.csv): the successes are the
    successes, the endings of an object add up to its episodes; the classes follow the target
    centre's height (never lifted, dropped, stalled, knocked off)."""
    import csv

    import torch

    from trainer.evaluation import ENDINGS, EpisodeEndings

    result = evaluate(dice_mug, episodes_per_object=4, out="eval-endings")
    assert result.endings is not None and set(result.endings) == set(ENDINGS)
    rows = list(csv.DictReader((dice_mug / "eval-endings" / "endings.csv").open()))
    for k, row in enumerate(rows):
        assert int(row["success"]) == result.successes[k]
        assert sum(int(row[e.replace(" ", "_")]) for e in ENDINGS) == result.episodes[k]
    assert "How the episodes ended" in (dice_mug / "eval-endings" / "table.md").read_text()
    # the classes, from the heights (m): start, highest, last of five episodes
    ends = EpisodeEndings()
    ends.parts = [torch.full((5,), -1)]
    ends.start = torch.tensor([0.02, 0.02, 0.02, 0.02, 0.02])
    ends.top = torch.tensor([0.025, 0.10, 0.10, 0.25, 0.02])
    ends.last = torch.tensor([0.02, 0.03, 0.09, 0.25, -0.20])
    ends.reached = torch.tensor([True, True, True, True, True])
    success = torch.tensor([False, False, False, True, False])
    assert [ENDINGS[i] for i in ends._classify(success)] == [
        "never lifted", "dropped", "stalled", "success", "knocked off"]
    # a target that never rose is never reached where two pads never came within 2 cm of it
    # together; one that rose counts by its heights whatever the pads did
    ends.reached = torch.tensor([False, False, True, True, True])
    assert [ENDINGS[i] for i in ends._classify(success)] == [
        "never reached", "dropped", "stalled", "success", "knocked off"]
