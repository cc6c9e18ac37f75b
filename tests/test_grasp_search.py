"""The keyframe grasp and the cross-entropy search behind the ``searched`` grasp family: the
parameters that reproduce the top grasp mean its pose, the search runs on MuJoCo rollouts and
writes what the family reads, and its errors are one line."""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path
from types import SimpleNamespace

import pytest
import torch

import trainer.cli
import trainer.config
from geomprep.config import Config
from tests.tiny_runs import own_data_dir, trainer_main
from trainer.config import NEUTRAL_DEFAULTS, load_env_config, load_train_config
from trainer.errors import TrainerError
from trainer.grasps import FAMILIES, TopGrasp, record_grasp, searched
from trainer.grasps.families import load_searched
from trainer.grasps.keyframes import DIM, PARAMS, KeyframeGrasp, index, top_grasp_theta
from trainer.grasps.search import cem
from trainer.tasks import make_env
from trainer.training.grasp_starts import starts_key


def _env(data: Config, n: int, objects: str = "builtin_cylinder", seed: int = 5):  # noqa: ANN202
    cfg = load_env_config(num_envs=n, objects=objects, representation="com",
                          data_dir=data.data_dir)
    return make_env(cfg, seed=seed)


def test_top_grasp_parameters_mean_the_top_grasp_pose(builtin_data: Config) -> None:
    """``top_grasp_theta`` puts the palm where the top grasp does, turned as it is, with its
    hand commands; a parameter moves the pose in the target's grasp frame."""
    env = _env(builtin_data, 3, "builtin_cylinder,builtin_box,builtin_dice")
    env.reset()
    top_plan: dict = {}
    top_action = TopGrasp().action(env, 0, top_plan)
    theta = top_grasp_theta()
    plan = KeyframeGrasp(theta).plan(env)
    torch.testing.assert_close(plan["goal"], top_plan["goal"], atol=1e-5, rtol=0)
    torch.testing.assert_close(plan["rot"], top_plan["rot"], atol=1e-5, rtol=0)
    torch.testing.assert_close(plan["open"], top_action[:, 6:], atol=1e-6, rtol=0)
    assert torch.equal(plan["drag"], torch.zeros(3, 3))
    # Raising z by 1 cm raises the goal by 1 cm in every env; x moves it across the palm.
    moved = theta.clone()
    moved[index("z")] += 0.01
    moved[index("x")] += 0.02
    other = KeyframeGrasp(moved).plan(env)
    shift = other["goal"] - plan["goal"]
    torch.testing.assert_close(shift[:, 2], torch.full((3,), 0.01), atol=1e-6, rtol=0)
    torch.testing.assert_close((shift * plan["rot"][..., 0]).sum(-1), torch.full((3,), 0.02),
                               atol=1e-6, rtol=0)
    env.close()


def test_search_scores_rollouts_and_keeps_a_lifting_grasp(builtin_data: Config) -> None:
    """From the top grasp on the built-in cylinder (which it lifts), one iteration of the
    search and the final re-run: every candidate is a rollout of the lift task, the history
    says so, and the kept grasp lifts in its final trials."""
    population, trials = 4, 2
    env = _env(builtin_data, population * trials)
    rows: list[dict] = []
    result = cem(env, top_grasp_theta(), population, trials, 1, 2, seed=0,
                 on_iteration=rows.append)
    env.close()
    assert result.theta.shape == (DIM,)
    assert rows == result.history and len(rows) == 1
    assert 0 <= rows[0]["lift_rate"] <= rows[0]["elite_lift_rate"] <= 1
    # The kept grasp's count is taken again on every env, after the pick.
    assert result.final_trials == population * trials
    assert result.lifted >= 1
    assert set(result.as_dict()) == set(PARAMS)
    with pytest.raises(ValueError, match="needs 8"):
        cem(_env(builtin_data, 3), top_grasp_theta(), population, trials, 1, 2)


def test_grasp_search_command_writes_the_family_file(
    builtin_data: Config, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
    capsys,  # noqa: ANN001
) -> None:
    """``trainer grasp-search`` writes each object's grasp with its configuration; the file
    reads back as the family's rows, and a keyframe grasp refuses an object it has no row
    for in one line naming the command that adds it."""
    out = tmp_path / "searched.json"
    monkeypatch.setattr(sys, "argv", [
        "trainer", "grasp-search", "--objects", "builtin_cylinder", "--population", "2",
        "--trials", "2", "--iterations", "1", "--elite", "2",
        "--data-dir", str(builtin_data.data_dir), "--out", str(out),
    ])
    trainer.cli.main()
    assert "builtin_cylinder: best " in capsys.readouterr().out
    data = load_searched(out)
    entry = data["objects"]["builtin_cylinder"]
    assert data["config"] == {} and set(entry["theta"]) == set(PARAMS)
    assert entry["search"]["population"] == 2 and len(entry["history"]) == 1
    script = KeyframeGrasp(by_object=(("builtin_cylinder",
                                       tuple(entry["theta"][p] for p in PARAMS)),))
    env = _env(builtin_data, 2, "builtin_cylinder,builtin_box")
    env.reset()
    with pytest.raises(TrainerError) as info:
        record_grasp(env, script)
    env.close()
    message = str(info.value)
    assert message.startswith("no searched grasp for builtin_box: search one with `trainer "
                              "grasp-search --objects builtin_box`") and "\n" not in message
    # --refine continues from the file's grasp and keeps the earlier search's record.
    monkeypatch.setattr(sys, "argv", [
        "trainer", "grasp-search", "--objects", "builtin_cylinder", "--population", "2",
        "--trials", "2", "--iterations", "1", "--elite", "2", "--refine", "--spread", "0.5",
        "--data-dir", str(builtin_data.data_dir), "--out", str(out),
    ])
    trainer.cli.main()
    refined = load_searched(out)["objects"]["builtin_cylinder"]
    assert refined["search"]["refine"] and refined["search"]["spread"] == 0.5
    assert refined["earlier"][0]["search"] == entry["search"]
    # A script longer than the env's episodes is refused in one line (no silent truncation).
    long = KeyframeGrasp(top_grasp_theta(), lift_steps=400)
    env = _env(builtin_data, 1)
    with pytest.raises(TrainerError, match=r"max_steps >= \d+"):
        record_grasp(env, long)
    env.close()
    # A file of another configuration is refused, not mixed.
    monkeypatch.setattr(sys, "argv", [
        "trainer", "grasp-search", "--objects", "builtin_box", "--population", "2",
        "--trials", "1", "--iterations", "1", "--elite", "2", "--config",
        str(_config(tmp_path)), "--data-dir", str(builtin_data.data_dir), "--out", str(out),
    ])
    with pytest.raises(SystemExit):
        trainer.cli.main()
    err = capsys.readouterr().err.strip()
    assert "holds grasps searched with another configuration" in err and "\n" not in err
    out.write_text(json.dumps({"config": {}, "objects": {"x": {"theta": {}}}}))
    with pytest.raises(TrainerError, match="not a searched-grasp file"):
        load_searched(out)


def _config(tmp_path: Path) -> Path:
    path = tmp_path / "noslip.toml"
    path.write_text("[physics]\nnoslip_iterations = 5\n")
    return path


def _search(data_dir: Path, *extra: str) -> list[str]:
    return ["trainer", "grasp-search", "--objects", "builtin_cylinder", "--population", "2",
            "--trials", "1", "--iterations", "1", "--elite", "2", "--data-dir", str(data_dir),
            *extra]


def test_grasp_search_writes_the_data_directory_per_hand(
    builtin_data: Config, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
    capsys,  # noqa: ANN001
) -> None:
    """With its defaults ``trainer grasp-search`` writes the object's grasp into the data
    directory (``grasps/searched/<object>.json``), keyed by the hand and physics, never into
    the package; another configuration adds a second grasp beside it (no "another
    configuration" error); the ``searched`` family runs the one of the env's hand and physics;
    a damaged file is one line, before any search."""
    seed = searched.SEARCHED_PATH.read_bytes()
    data_dir = own_data_dir(builtin_data, tmp_path / "data")
    monkeypatch.setattr(sys, "argv", _search(data_dir))
    trainer.cli.main()
    path = searched.object_path(data_dir, "builtin_cylinder")
    assert path == data_dir / "grasps" / "searched" / "builtin_cylinder.json"
    assert f"written: {path}" in capsys.readouterr().out
    assert searched.SEARCHED_PATH.read_bytes() == seed  # the package is not written
    default = load_env_config(data_dir=data_dir)
    grasps = searched.read_object(data_dir, "builtin_cylinder")
    assert list(grasps) == [searched.hand_key(default)]
    entry = grasps[searched.hand_key(default)]
    assert entry["config"] == {} and set(entry["theta"]) == set(PARAMS)
    assert entry["hand_and_physics"] == searched.hand_and_physics(default)
    # Another hand's search goes beside it.
    other = tmp_path / "soft.toml"
    other.write_text("[robot]\nhand_forcerange = 1.5\n")
    monkeypatch.setattr(sys, "argv", _search(data_dir, "--config", str(other)))
    trainer.cli.main()
    soft = load_env_config(other, data_dir=data_dir)
    grasps = searched.read_object(data_dir, "builtin_cylinder")
    assert set(grasps) == {searched.hand_key(default), searched.hand_key(soft)}
    assert grasps[searched.hand_key(soft)]["config"] == {"robot": {"hand_forcerange": 1.5}}
    # The family runs each env's own grasp.
    script = FAMILIES["searched"].variants["base"].script
    for cfg in (default, soft):
        row = torch.tensor(searched.theta_row(grasps[searched.hand_key(cfg)]))
        torch.testing.assert_close(script.env_theta(_FakeEnv(cfg, ["builtin_cylinder"]))[0], row)
    # A damaged file is refused in one line, before anything is searched.
    path.write_text("{}")
    capsys.readouterr()
    monkeypatch.setattr(sys, "argv", _search(data_dir))
    with pytest.raises(SystemExit):
        trainer.cli.main()
    captured = capsys.readouterr()
    assert captured.err.strip() == (
        f"error: {path}: not a searched-grasp file ('grasps'): rerun trainer grasp-search")
    assert "candidates" not in captured.out


class _FakeEnv:
    """What the keyframe grasp's rows need of an env: its config, objects and targets."""

    def __init__(self, cfg, names: list[str]) -> None:  # noqa: ANN001
        self.cfg, self.objects = cfg, SimpleNamespace(names=names)
        self.num_envs, self.device = len(names), torch.device("cpu")

    def target_objects(self) -> torch.Tensor:
        return torch.arange(self.num_envs)


def test_the_searched_family_falls_back_to_the_shipped_grasps(tmp_path: Path) -> None:
    """Without grasps in the data directory the family runs the shipped ``searched.json``'s (as
    before they moved); a data-directory grasp for the env's hand and physics takes its
    object's place, one for another physics does not."""
    seed = load_searched()["objects"]
    names = ["062_dice", "053_mini_soccer_ball"]
    cfg = load_env_config(data_dir=tmp_path)
    script = FAMILIES["searched"].variants["base"].script
    shipped = torch.tensor([searched.theta_row(seed[n]) for n in names])
    torch.testing.assert_close(script.env_theta(_FakeEnv(cfg, names)), shipped)
    assert searched.grasp_for(cfg, "062_dice") == seed["062_dice"]
    assert searched.grasp_for(cfg, "builtin_box") is None
    mine = {"theta": {p: 0.01 * i for i, p in enumerate(PARAMS)}}
    searched.write_entry(tmp_path, "062_dice", searched.hand_key(cfg), mine)
    theta = script.env_theta(_FakeEnv(cfg, names))
    torch.testing.assert_close(theta[0], torch.tensor(searched.theta_row(mine)))
    torch.testing.assert_close(theta[1], shipped[1])
    assert searched.grasp_for(cfg, "062_dice") == mine
    noslip0 = load_env_config(data_dir=tmp_path, physics={"noslip_iterations": 0})
    torch.testing.assert_close(script.env_theta(_FakeEnv(noslip0, names)), shipped)
    assert searched.grasp_for(noslip0, "062_dice") == seed["062_dice"]


def test_the_hand_key_is_the_hand_and_the_physics() -> None:
    """The key changes with the hand and the physics, not with how a policy's hand actions are
    read or the thread count; the shipped grasps' configuration is today's default hand, so a
    default search is what the family's runs (with that configuration) look up."""
    key = searched.hand_key(load_env_config())
    assert searched.hand_key(load_env_config(nthread=1)) == key
    assert searched.hand_key(load_env_config(robot={"hand_action": "relative"})) == key
    assert searched.hand_key(load_env_config(robot={"hand_forcerange": 1.5})) != key
    assert searched.hand_key(load_env_config(physics={"substeps": 20})) != key
    assert searched.hand_key(load_env_config(**load_searched()["config"])) == key


def test_a_field_added_at_its_neutral_default_keeps_the_cached_grasps(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A grasp stored before ``physics.table_plane`` existed (its stored hand and physics lack
    the field) is found by today's config at the field's neutral value (False), not by one
    that turns it on; the recorded starts' cache key leaves the field out the same way."""
    assert NEUTRAL_DEFAULTS["env.physics.table_plane"] is False
    cfg = load_env_config(data_dir=tmp_path)
    before = searched.hand_and_physics(cfg)
    del before["physics"]["table_plane"]
    entry = {"theta": {p: 0.0 for p in PARAMS}, "hand_and_physics": before}
    searched.write_entry(tmp_path, "builtin_box", "stored-before-the-field", entry)
    assert searched.grasp_for(cfg, "builtin_box") == entry
    assert searched.hand_key(cfg) == searched.key_of(before)
    plane = load_env_config(data_dir=tmp_path, physics={"table_plane": True})
    assert searched.grasp_for(plane, "builtin_box") is None
    run = load_train_config(None)
    grasps: dict = {}
    on = load_train_config(None, sets={"physics.table_plane": True})
    key = starts_key(run, grasps)
    assert key != starts_key(on, grasps)
    monkeypatch.setattr(trainer.config, "NEUTRAL_DEFAULTS", {})
    assert starts_key(run, grasps) != key  # the field counts once it is not neutral


def test_the_arena_size_keeps_the_cached_grasps_and_starts(tmp_path: Path) -> None:
    """``physics.memory_mb`` (the trainer's warning says to raise it) changes no simulated
    result, so at any value it leaves the searched grasps' and the recorded starts' keys as
    they were before the field existed (a bin run re-searched the 78 grasps without this)."""
    cfg = load_env_config(data_dir=tmp_path)
    before = searched.hand_and_physics(cfg)
    del before["physics"]["memory_mb"]
    roomy = load_env_config(data_dir=tmp_path, physics={"memory_mb": 64.0})
    assert searched.hand_key(cfg) == searched.hand_key(roomy) == searched.key_of(before)
    grasps: dict = {}
    assert starts_key(load_train_config(None), grasps) == starts_key(
        load_train_config(None, sets={"physics.memory_mb": 64.0}), grasps)
    # a field that does change the physics still changes both
    assert searched.hand_key(load_env_config(physics={"noslip_iterations": 2})) != \
        searched.hand_key(cfg)


def test_committed_searched_grasps_are_complete() -> None:
    """The package's searched grasps (``searched.json``) name their configuration and have
    every parameter and the lifts they were measured with; the family runs them."""
    fam = FAMILIES["searched"]
    data = load_searched()
    assert set(fam.objects) == set(data["objects"])
    for name, entry in data["objects"].items():
        assert 0 <= entry["lifted"] <= entry["final_trials"], name
        assert all(abs(entry["theta"][f"closed{i}"]) <= 1 for i in range(5)), name
    assert fam.variants["base"].env == data["config"]


def test_grasps_shipped_per_hand_are_found_by_the_ycb_preset() -> None:
    """``searched_by_hand.json`` holds searched grasps with their hand and physics, under
    the key those give today, for the hand of ``configs/cpu-ycb.toml`` (the 78 together), and
    names the measurement they come from."""
    data = json.loads(searched.SHIPPED_PATH.read_text())
    root = Path(__file__).parents[1]
    ycb = load_env_config(root / "configs" / "cpu-ycb.toml")
    assert (root / data["sources"][searched.hand_key(ycb)]).is_dir()
    assert len(data["grasps"]) >= 60
    for name, entries in data["grasps"].items():
        for key, entry in entries.items():
            assert key == searched.key_of(entry["hand_and_physics"]), name
            assert 0 <= entry["lifted"] <= entry["final_trials"], name
            assert "history" not in entry, name
        assert searched.shipped_object(name).get(searched.hand_key(ycb)) is not None, name


def test_best_families_group_objects_and_carry_the_hand() -> None:
    """``trainer demo --family best``: the objects grouped by their best family, every batch
    with the searched grasps' hand configuration under the variant's own overrides; an
    object no family lifts is a one-line error."""
    from trainer.grasps.families import BEST, best_variants

    batches = best_variants(["062_dice", "013_apple", "053_mini_soccer_ball", "032_knife"])
    assert {spec: names for spec, (_, names) in batches.items()} == {
        "searched": ["062_dice", "053_mini_soccer_ball"], "top": ["013_apple"],
        "pinch:press6+noslip": ["032_knife"],
    }
    hand = load_searched()["config"]
    pinch = batches["pinch:press6+noslip"][0]
    assert pinch.env["robot"] == hand["robot"] and pinch.env["physics"]["noslip_iterations"] == 5
    assert set(BEST) >= set(FAMILIES["searched"].objects)
    assert list(best_variants(["029_plate"])) == ["pinch:rim"]  # upright plates only
    with pytest.raises(TrainerError) as info:
        best_variants(["013_apple", "builtin_mug"])
    assert str(info.value).startswith("no grasp family lifts builtin_mug yet: search one with "
                                      "`trainer grasp-search --objects builtin_mug`")
    # An object that has a searched grasp takes the searched family; BEST still decides for
    # the objects it names.
    batches = best_variants(["013_apple", "builtin_mug", "062_dice"],
                            searched=["builtin_mug", "013_apple"])
    assert {spec: names for spec, (_, names) in batches.items()} == {
        "top": ["013_apple"], "searched": ["builtin_mug", "062_dice"]}
    assert batches["searched"][0].env == hand


def test_find_grasps_searches_and_stores_only_what_nobody_has(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``find_grasps``: an object with a grasp (here the shipped seed's, which serves every
    hand and physics without one of its own) is not searched; one without is searched once,
    said in a line before and after, and stored in the data directory with its search's
    settings, its configuration and the hand and physics, where the next call finds it."""
    import trainer.grasps.search as search
    from trainer.grasps.search import SearchResult, SearchSettings, find_grasps

    cfg = load_env_config(data_dir=tmp_path, robot={"hand_forcerange": 1.5})
    calls: list[str] = []

    def fake_search(cfg, name: str, settings: SearchSettings) -> SearchResult:  # noqa: ANN001
        calls.append(name)
        return SearchResult(top_grasp_theta(), 3, 6, [{"iteration": 0}])

    monkeypatch.setattr(search, "search_grasp", fake_search)
    lines: list[str] = []
    tiny = SearchSettings(population=4, trials=2, iterations=1, elite=2)
    found = find_grasps(cfg, ["builtin_box", "062_dice"], tiny, lines.append)
    assert calls == ["builtin_box"]
    assert found["062_dice"] == load_searched()["objects"]["062_dice"]
    path = searched.object_path(tmp_path, "builtin_box")
    assert lines == [
        "no grasp for builtin_box with this hand and physics: searching (4 candidates x 2 "
        "trials, 1 iterations)",
        f"builtin_box: the grasp found lifted 3 of 6 final trials; stored in {path}",
    ]
    entry = searched.read_object(tmp_path, "builtin_box")[searched.hand_key(cfg)]
    assert found["builtin_box"] == entry
    assert entry["lifted"] == 3 and entry["history"] == [{"iteration": 0}]
    assert entry["search"]["population"] == 4 and entry["search"]["refine"] is False
    assert entry["config"]["robot"] == {"hand_forcerange": 1.5}
    assert entry["hand_and_physics"] == searched.hand_and_physics(cfg)
    torch.testing.assert_close(torch.tensor(searched.theta_row(entry)), top_grasp_theta(),
                               atol=1e-4, rtol=0)  # (stored to 4 decimals)
    lines.clear()
    assert find_grasps(cfg, ["builtin_box", "062_dice"], tiny, lines.append) == found
    assert calls == ["builtin_box"] and lines == []  # stored: not searched again
    assert SearchSettings().describe() == (
        "24 candidates x 4 trials, 6 iterations, about 2-3 minutes of one core")


def test_demo_of_the_best_families_runs_searched_grasps(
    builtin_data: Config, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
    capsys,  # noqa: ANN001
) -> None:
    """``trainer demo --family best`` on an object without a ``BEST`` entry: a one-line error
    naming the search while it has no grasp; once the data directory has one for the demo's
    hand and physics, the demo runs it."""
    data_dir = own_data_dir(builtin_data, tmp_path / "data")
    argv = ["demo", "--family", "best", "--objects", "builtin_cylinder", "--trials", "1",
            "--video", "", "--data-dir", str(data_dir)]
    code, out, err = trainer_main(argv, monkeypatch, capsys)
    assert code == 1 and err.strip().startswith(
        "error: no grasp family lifts builtin_cylinder yet: search one with `trainer "
        "grasp-search --objects builtin_cylinder`") and "\n" not in err.strip()
    hand = load_env_config(data_dir=data_dir, **FAMILIES["searched"].variants["base"].env)
    theta = {p: float(v) for p, v in zip(PARAMS, top_grasp_theta(), strict=True)}
    searched.write_entry(data_dir, "builtin_cylinder", searched.hand_key(hand), {"theta": theta})
    code, out, err = trainer_main(argv, monkeypatch, capsys)
    assert code == 0, err
    assert "builtin_cylinder  lifted " in out


SEARCHED_OBJECTS = ("053_mini_soccer_ball", "073-g_lego_duplo", "062_dice")


@pytest.mark.slow
def test_searched_grasps_lift_their_objects(tmp_path_factory: pytest.TempPathFactory) -> None:
    """The searched family keeps its measured counts (results/graspability-search-2026-11-26:
    ball 8-9, Duplo 8-10, dice 8-10 of 10 over seeds 0-2): >= 8 of 10 each, seed 0 (YCB
    models required)."""
    from tests.conftest import build_ycb
    from trainer.grasps import measure

    data = build_ycb(tmp_path_factory, "searched", SEARCHED_OBJECTS)
    rows = measure("searched", "base", FAMILIES["searched"].variants["base"], SEARCHED_OBJECTS,
                   10, seed=0, data_dir=data.data_dir)
    assert all(r["lifted"] >= 8 for r in rows), rows


_SHIP_PATH = Path(__file__).parents[1] / "scripts" / "ship_searched_grasps.py"
_SHIP_SPEC = importlib.util.spec_from_file_location("ship_searched_grasps", _SHIP_PATH)
ship_script = importlib.util.module_from_spec(_SHIP_SPEC)
_SHIP_SPEC.loader.exec_module(ship_script)


def test_shipped_grasps_spare_a_fresh_data_directory_the_search(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A grasp shipped for a hand key (``scripts/ship_searched_grasps.py``) is found by a run
    of that hand with an empty data directory, without its search history; a data-directory
    grasp of the same key comes first; another hand does not get it; nothing to ship is a
    one-line error."""
    searched_dir, fresh = tmp_path / "searched", tmp_path / "fresh"
    cfg = load_env_config(data_dir=searched_dir)
    mine = {"theta": {p: 0.01 * i for i, p in enumerate(PARAMS)}, "lifted": 20,
            "history": [{"iteration": 0}]}
    searched.write_entry(searched_dir, "builtin_box", searched.hand_key(cfg), mine)
    target = tmp_path / "searched_by_hand.json"
    with pytest.raises(TrainerError, match="no searched grasp for hand key"):
        ship_script.ship(fresh, searched.hand_key(cfg), "results/x", target)
    assert ship_script.ship(searched_dir, searched.hand_key(cfg), "results/x", target) == 1
    monkeypatch.setattr(searched, "SHIPPED_PATH", target)
    fresh_cfg = load_env_config(data_dir=fresh)
    shipped = {k: v for k, v in mine.items() if k != "history"}
    assert searched.grasp_for(fresh_cfg, "builtin_box") == shipped
    assert searched.data_rows(_FakeEnv(fresh_cfg, ["builtin_box", "builtin_dice"])) == {
        "builtin_box": searched.theta_row(mine)}
    other = load_env_config(data_dir=fresh, physics={"noslip_iterations": 0})
    assert searched.grasp_for(other, "builtin_box") is None
    own = {"theta": {p: 0.02 for p in PARAMS}}
    searched.write_entry(fresh, "builtin_box", searched.hand_key(cfg), own)
    assert searched.grasp_for(fresh_cfg, "builtin_box") == own
    assert json.loads(target.read_text())["sources"] == {searched.hand_key(cfg): "results/x"}
