"""The ``trainer`` command line: it starts fast (no torch at import), bad options and paths are
one ``error:`` line with exit status 1, and eval / play / report know the task (lift or bin) of
a run, on one-iteration runs. (Training itself: tests/test_ppo.py.)"""

from __future__ import annotations

import csv
import dataclasses
import json
import subprocess
import sys
from pathlib import Path

import pytest
import torch

import trainer.cli
import trainer.ppo
from geomprep.config import Config
from tests.tiny_runs import trainer_main
from trainer.config import config_dict, load_train_config
from trainer.training.run_dir import RunDir


def test_importing_the_cli_does_not_import_torch() -> None:
    # torch, TorchRL and MuJoCo take seconds to import: --help and a mistyped option must not
    # wait for them.
    code = (
        "import sys, trainer.cli; "
        "print(sorted(m for m in ('torch', 'torchrl', 'tensordict', 'mujoco') "
        "if m in sys.modules))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=120
    )
    assert out.stdout.strip() == "[]"


def test_training_does_not_need_the_mesh_libraries() -> None:
    # The trainer only reads geomprep's artifacts: a machine without open3d and coacd (a GPU box
    # given only the built data) must import everything a run uses.
    code = (
        "import sys\n"
        "class Block:\n"
        "    def find_spec(self, name, path=None, target=None):\n"
        "        if name.split('.')[0] in ('open3d', 'coacd'):\n"
        "            raise ImportError(f'blocked {name}')\n"
        "sys.meta_path.insert(0, Block())\n"
        "import trainer.objects, trainer.tasks, trainer.ppo, trainer.evaluation\n"
        "print(sorted(m for m in ('open3d', 'coacd') if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]"


def invoke(argv: list[str], monkeypatch: pytest.MonkeyPatch, capsys) -> tuple[int, str]:  # noqa: ANN001
    """Run the real entry point (as the installed ``trainer`` script does): exit code, stderr."""
    code, _, err = invoke_all(argv, monkeypatch, capsys)
    return code, err


def invoke_all(argv: list[str], monkeypatch: pytest.MonkeyPatch, capsys) -> tuple[int, str, str]:  # noqa: ANN001, E501
    """Like ``invoke``: exit code, stdout, stderr (stripped)."""
    code, out, err = trainer_main(argv, monkeypatch, capsys)
    return code, out.strip(), err.strip()


@pytest.mark.parametrize(
    "argv, expected",
    [
        (["run", "--steps", "0"], "error: --steps 0: must be >= 1"),
        (["run", "--steps", "-5"], "error: --steps -5: must be >= 1"),
        (["run", "--seed", "-1"], "error: --seed -1: must be >= 0"),
        (["run", "--num-envs", "0"], "error: --num-envs 0: must be >= 1"),
        (["run", "--bin-objects", "0"], "error: --bin-objects 0: must be >= 1"),
        (["run", "--task", "bin", "--bin-objects", "-3"], "error: --bin-objects -3: must be >= 1"),
        # The lift task has no other objects to see.
        (["run", "--context", "bbox"], "error: context = 'bbox': only the bin task has other "
         "objects to see; use --task bin or drop --context"),
        (["run", "--task", "lift", "--context", "bbox"], "error: context = 'bbox': only the bin"),
        (["run", "--device", "bogus"], "error: --device bogus: not a torch device: use cpu or"),
        (["run", "--resume", "nowhere", "--num-envs", "4"],
         "error: --num-envs cannot change a resumed run"),
        (["run", "--resume", "nowhere", "--no-compile"],
         "error: --no-compile cannot change a resumed run"),
        (["run", "--resume", "nowhere"], "error: nowhere: no such run directory"),
        (["eval", "nowhere"], "error: nowhere: no such run directory"),
        (["eval", ".", "--episodes-per-object", "0"], "error: --episodes-per-object 0: must be"),
        (["eval", ".", "--max-rounds", "0"], "error: --max-rounds 0: must be >= 1"),
        (["eval", "."], "error: . is not a run directory (no config.json)"),
        (["play", "nowhere", "--object", "x"], "error: nowhere: no such run directory"),
        (["play", ".", "--object", "x", "--episodes", "0"], "error: --episodes 0: must be >= 1"),
        (["play", ".", "--object", "x", "--episodes", "2", "--tries", "1"],
         "error: --tries 1: must be >= --episodes (2)"),
        (["report", "nowhere"], "error: nowhere: no such run directory"),
        (["demo", "--trials", "0"], "error: --trials 0: must be >= 1"),
    ],
)
def test_bad_input_is_one_line(
    argv: list[str], expected: str, monkeypatch: pytest.MonkeyPatch, capsys, tmp_path: Path  # noqa: ANN001
) -> None:
    monkeypatch.chdir(tmp_path)
    code, err = invoke(argv, monkeypatch, capsys)
    assert code == 1 and err.startswith(expected) and "\n" not in err, err


def test_unknown_task_is_clicks_usage_error(monkeypatch: pytest.MonkeyPatch, capsys) -> None:  # noqa: ANN001
    code, err = invoke(["run", "--task", "stack"], monkeypatch, capsys)
    assert code == 2 and err.endswith(
        "Error: Invalid value for '--task': 'stack' is not one of 'lift', 'bin'."
    ), err


def test_cuda_without_a_gpu_is_one_line(monkeypatch: pytest.MonkeyPatch, capsys) -> None:  # noqa: ANN001
    import torch

    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    code, err = invoke(["run", "--device", "cuda"], monkeypatch, capsys)
    assert code == 1 and err == (
        "error: --device cuda: no CUDA device is available (torch.cuda.is_available() is "
        "False): use --device cpu"
    )


def test_compile_flag_overrides_the_config_only_when_given(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys  # noqa: ANN001
) -> None:
    seen = []
    monkeypatch.setattr(trainer.ppo, "train", lambda cfg, run_dir, **kw: seen.append(cfg))
    config = tmp_path / "c.toml"
    config.write_text("compile = true\n")
    common = ["run", "--config", str(config), "--run-dir", str(tmp_path / "r")]
    assert invoke(common, monkeypatch, capsys)[0] == 0
    assert invoke([*common, "--no-compile"], monkeypatch, capsys)[0] == 0
    assert invoke(["run", "--run-dir", str(tmp_path / "r")], monkeypatch, capsys)[0] == 0
    assert invoke(["run", "--compile", "--run-dir", str(tmp_path / "r")], monkeypatch, capsys)[0] == 0  # noqa: E501
    # The config's value, the flag's, the one default (EnvConfig's), the flag's.
    assert [cfg.env.compile for cfg in seen] == [True, False, False, True]


def test_resume_checks_steps_and_needs_a_checkpoint(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys  # noqa: ANN001
) -> None:
    # A run killed before its first checkpoint: --steps is checked like the file's value, and
    # there is nothing to resume from.
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    (run_dir / "config.json").write_text(json.dumps(config_dict(load_train_config())))
    code, err = invoke(["run", "--resume", str(run_dir), "--steps", "0"], monkeypatch, capsys)
    assert code == 1 and err == "error: --steps 0: must be >= 1"
    code, err = invoke(["run", "--resume", str(run_dir)], monkeypatch, capsys)
    assert code == 1 and err.startswith(f"error: {run_dir}: no checkpoint yet"), err


# ---- eval, play and report on one-iteration runs of each task ---------------------------------

BIN_OBJECTS = "builtin_box,builtin_cylinder,builtin_sphere,builtin_dice,builtin_mug,builtin_plate"
"""Six objects, one bin of five: exactly one of them is in no bin."""
TINY_PPO = {"frames_per_env": 8, "minibatches": 2, "min_minibatch": 1, "epochs": 1,
            "hidden": (32, 32, 32), "context_hidden": (16, 16)}


def _train(env: dict, path: Path) -> Path:
    from trainer.ppo import train

    cfg = load_train_config(
        env={"num_envs": 4, "max_steps": 10, **env}, ppo=TINY_PPO,
        run={"total_steps": 32, "checkpoint_every": 1, "seed": 3},
    )
    return train(cfg, path, progress=False).path


@pytest.fixture(scope="module")
def bin_run(builtin_data: Config, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A one-iteration bin run: one bin of 5 of BIN_OBJECTS, 4 envs, 10-step episodes."""
    return _train(
        {"task": "bin", "objects": BIN_OBJECTS, "data_dir": builtin_data.data_dir,
         "bin": {"num_objects": 5, "layouts": 1, "bank_size": 2}},
        tmp_path_factory.mktemp("bin") / "run",
    )


@pytest.fixture(scope="module")
def lift_run(builtin_data: Config, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A one-iteration lift run on two objects."""
    return _train(
        {"objects": "builtin_cylinder,builtin_sphere", "representation": "com",
         "data_dir": builtin_data.data_dir},
        tmp_path_factory.mktemp("lift") / "run",
    )


def _bins_hold(run_dir: Path) -> tuple[list[str], list[str]]:
    """(objects in the run's bins, objects of its set in none), from the run's own env."""
    from trainer.session import EvalSession

    env = EvalSession(RunDir(run_dir).load_config()).bin_env(1)
    names = env.objects.names
    held = {names[k] for k in env.layouts.unique().tolist()}
    env.close()
    return sorted(held), sorted(set(names) - held)


def _per_object(run_dir: Path, folder: str = "eval") -> dict[str, dict[str, str]]:
    rows = csv.DictReader((run_dir / folder / "per_object.csv").read_text().splitlines())
    return {row["object"]: row for row in rows}


def test_lift_eval_names_the_task(
    lift_run: Path, monkeypatch: pytest.MonkeyPatch, capsys  # noqa: ANN001
) -> None:
    code, out, err = invoke_all(["eval", str(lift_run), "--episodes-per-object", "3"],
                                monkeypatch, capsys)
    assert code == 0, err
    lines = out.splitlines()
    assert lines[0] == "task lift, representation com: success per target object"
    assert [line.split()[0] for line in lines[1:]] == ["builtin_cylinder", "builtin_sphere",
                                                       "overall", "success:"]
    assert lines[-1].startswith("success: the target lifted by 0.2 m while held")
    rows = _per_object(lift_run)
    assert [int(r["episodes"]) for r in rows.values()] == [3, 3]  # exactly, as before the tasks
    assert {r["task"] for r in rows.values()} == {"lift"}
    table = (lift_run / "eval" / "table.md").read_text()
    assert table.startswith(
        "Success per target object: task lift, representation com; the last checkpoint."
    )
    assert "| object | episodes | com |" in table and "| **all (6 episodes)** |" in table


def test_lift_eval_sample_draws_the_actions_and_says_so(
    lift_run: Path, monkeypatch: pytest.MonkeyPatch, capsys  # noqa: ANN001
) -> None:
    """``trainer eval --sample``: the policy's actions are drawn from its Gaussian (as in
    training), so the rollouts differ from the mean's; seeded, they repeat; the output folder
    (eval-sampled) and the table say which, and the deterministic eval is left alone."""
    import torch

    from trainer.session import run_episodes
    from trainer.tasks import make_env

    code, _, err = invoke_all(["eval", str(lift_run), "--episodes-per-object", "2"],
                              monkeypatch, capsys)
    assert code == 0, err
    deterministic = (lift_run / "eval" / "table.md").read_text()
    code, out, err = invoke_all(["eval", str(lift_run), "--episodes-per-object", "2",
                                 "--sample"], monkeypatch, capsys)
    assert code == 0, err
    assert out.splitlines()[0] == (
        "task lift, representation com: success per target object (actions sampled)"
    )
    table = (lift_run / "eval-sampled" / "table.md").read_text()
    assert table.startswith("Success per target object: task lift, representation com; the "
                            "last checkpoint; actions sampled from the policy (as in training).")
    assert (lift_run / "eval" / "table.md").read_text() == deterministic
    assert "sampled" not in deterministic

    cfg, agent = trainer.training.checkpoint.load_agent(lift_run, "cpu")

    def final_qpos(deterministic: bool, seed: int) -> torch.Tensor:
        env = make_env(cfg.env, seed=3)
        with torch.random.fork_rng():
            torch.manual_seed(seed)
            run_episodes(env, agent.actor, deterministic)
        qpos = env.backend.qpos.clone()
        env.close()
        return qpos

    mean = final_qpos(True, 0)
    assert torch.equal(mean, final_qpos(True, 1))  # the mean draws nothing
    sampled = final_qpos(False, 0)
    assert not torch.equal(mean, sampled)
    assert torch.equal(sampled, final_qpos(False, 0)) and not torch.equal(
        sampled, final_qpos(False, 1)
    )


def test_lift_eval_pads_counts_held_successes(
    lift_run: Path, monkeypatch: pytest.MonkeyPatch, capsys  # noqa: ANN001
) -> None:
    """``trainer eval --pads``: the held-lift analysis (results/cpu-table1, "Tosses are not
    lifts") as columns of the eval; without it the files keep their columns."""
    import torch

    from trainer.evaluation import SuccessPads
    from trainer.session import Episodes

    code, out, err = invoke_all(["eval", str(lift_run), "--episodes-per-object", "2",
                                 "--hold-tips", "0", "--pads", "--out", "eval-pads"],
                                monkeypatch, capsys)
    assert code == 0, err
    assert "held by two pads" in out.splitlines()[1]
    header = (lift_run / "eval-pads" / "per_object.csv").read_text().splitlines()[0]
    assert header.endswith(",representation,held_successes,nearest_pad_median_m")
    assert "| object | successes | held | nearest pad, median |" in (
        lift_run / "eval-pads" / "table.md").read_text()
    # The counting itself: two successes of object 1, one held (two pads within 2 cm).
    # (A third episode, of object 2, failed: its distances are not counted.)
    pads = SuccessPads()
    nan = float("nan")
    pads.parts.append(torch.tensor([[0.0, 0.01, 0.3, 0.3, 0.3], [0.25, 0.3, 0.3, 0.3, 0.22],
                                    [nan] * 5]))
    episodes = Episodes(torch.tensor([True, True, False]), torch.tensor([5, 7, 9]),
                        torch.tensor([1, 1, 2]))
    assert pads.held(episodes, 3) == [0, 1, 0]
    nearest = pads.nearest(episodes, 3)
    assert nearest[0] is None and nearest[1] == pytest.approx(0.0) and nearest[2] is None


def test_bin_eval_counts_episodes_per_target(
    bin_run: Path, monkeypatch: pytest.MonkeyPatch, capsys  # noqa: ANN001
) -> None:
    held, absent = _bins_hold(bin_run)
    assert len(held) == 5 and len(absent) == 1
    code, out, err = invoke_all(["eval", str(bin_run), "--episodes-per-object", "2"],
                                monkeypatch, capsys)
    assert code == 0, err
    # 5 objects x 2 episodes, 4 envs a round with the targets balanced: 3 rounds, 12 episodes.
    assert out.splitlines()[0] == (
        "task bin (5 objects per bin), representation bbox, context none; 3 rounds of episodes: "
        "success per target object"
    )
    assert out.splitlines()[-1] == f"note: in none of the run's bins (never a target): {absent[0]}"
    rows = _per_object(bin_run)
    assert list(rows) == BIN_OBJECTS.split(",")
    episodes = {name: int(row["episodes"]) for name, row in rows.items()}
    assert episodes[absent[0]] == 0 and rows[absent[0]]["success_rate"] == ""
    assert all(episodes[name] >= 2 for name in held) and sum(episodes.values()) == 12
    assert all(0 <= int(r["successes"]) <= int(r["episodes"]) for r in rows.values())
    assert {(r["task"], r["bin_objects"], r["context"]) for r in rows.values()} == {
        ("bin", "5", "none")
    }
    table = (bin_run / "eval" / "table.md").read_text()
    assert "task bin (5 objects per bin), representation bbox, context none" in table
    assert "| object | episodes | bin5-bbox |" in table and f"| {absent[0]} | 0 | — |" in table
    # The report reads the bin run's eval and names its task.
    code, out, err = invoke_all(["report", str(bin_run), "--out", str(bin_run.parent / "rep")],
                                monkeypatch, capsys)
    assert code == 0, err
    report = (bin_run.parent / "rep" / "report.md").read_text()
    assert "| bin5-bbox | 1 |" in report
    assert "| object | bin5-bbox |" in report


def test_bin_eval_stops_at_max_rounds(
    bin_run: Path, monkeypatch: pytest.MonkeyPatch, capsys  # noqa: ANN001
) -> None:
    code, out, err = invoke_all(
        ["eval", str(bin_run), "--episodes-per-object", "3", "--max-rounds", "1"],
        monkeypatch, capsys,
    )
    assert code == 0, err
    assert "; 1 round of episodes:" in out.splitlines()[0]
    # One round of 4 envs: 4 of the 5 objects got one episode each, none got 3.
    note = next(line for line in out.splitlines() if "--max-rounds" in line)
    assert note.startswith("note: after 1 round (--max-rounds) 5 objects have fewer than 3")
    assert sum(int(r["episodes"]) for r in _per_object(bin_run).values()) == 4


def test_forced_targets_are_the_asked_object(bin_run: Path) -> None:
    """play's bin episodes: the envs whose bin holds the object get it as the target, its lift
    measured from its own height at the reset."""
    import torch

    from trainer.session import EvalSession, force_targets

    held, _ = _bins_hold(bin_run)
    cfg = RunDir(bin_run).load_config()
    env, ids, slots = EvalSession(cfg).play_env(held[-1], 2, seed=7)
    k = env.objects.names.index(held[-1])
    assert ids == [0, 1] and (slots[2:] == -1).all()  # one bin: every env holds it
    env.reset()
    td = force_targets(env, slots)
    assert (env.target_objects()[ids] == k).all() and (td["object_id"][ids, 0] == k).all()
    heights = env.slot_poses(env.backend.qpos)[..., 2]
    target = env.state["target_slot"]
    torch.testing.assert_close(env.state["start_height"], heights.gather(1, target[:, None])[:, 0])
    env.close()


def test_bin_play_bad_object_is_one_line(
    bin_run: Path, monkeypatch: pytest.MonkeyPatch, capsys  # noqa: ANN001
) -> None:
    held, absent = _bins_hold(bin_run)
    code, err = invoke(["play", str(bin_run), "--object", absent[0]], monkeypatch, capsys)
    assert code == 1 and err == (
        f"error: --object {absent[0]}: none of the run's 1 bins holds it (they hold "
        f"{', '.join(held)}): play one of those"
    )
    code, err = invoke(["play", str(bin_run), "--object", "builtin_knife"], monkeypatch, capsys)
    assert code == 1 and err.startswith(
        f"error: --object builtin_knife: not in the object set '{BIN_OBJECTS}' of this bin run"
    ) and "\n" not in err, err


def test_bin_play_renders_episodes_of_the_target(
    bin_run: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys  # noqa: ANN001
) -> None:
    held, _ = _bins_hold(bin_run)
    video = tmp_path / "play.gif"
    code, out, err = invoke_all(
        ["play", str(bin_run), "--object", held[0], "--episodes", "2", "--video", str(video)],
        monkeypatch, capsys,
    )
    assert code == 0, err
    assert out.startswith(f"{held[0]}: success ") and "/2, " in out and str(video) in out
    assert video.stat().st_size > 1000


def test_bin_play_steps_only_as_many_envs_per_bin_as_its_episodes_need(bin_run: Path) -> None:
    """``trainer play`` in a bin run gives each bin as many envs as the bins holding the
    target need between them for its episodes (every env steps: with one per bin and episode,
    a target in 5 of 64 bins ran 512 envs for 8 episodes)."""
    from trainer.session import EvalSession

    cfg = RunDir(bin_run).load_config()
    cfg = dataclasses.replace(cfg, env=dataclasses.replace(
        cfg.env, bin=dataclasses.replace(cfg.env.bin, layouts=3)))
    session = EvalSession(cfg)
    probe = session.bin_env(3)
    names = probe.objects.names
    holding = {n: int((probe.assignment.cpu() == k).any(1).sum()) for k, n in enumerate(names)}
    probe.close()
    name = max(holding, key=holding.get)  # in 2 or 3 of the 3 bins
    assert holding[name] >= 2
    env, ids, slots = session.play_env(name, 4, seed=0)
    assert env.num_envs == 3 * -(-4 // holding[name])  # 6 (or 3): not 3 x 4
    assert len(ids) == 4
    assert (env.assignment.cpu()[ids] == names.index(name)).any(1).all()
    assert (slots[ids] >= 0).all() and (slots[[i for i in range(env.num_envs)
                                                 if i not in ids]] == -1).all()
    env.close()


def test_a_trainer_warning_is_one_line_and_others_keep_their_source() -> None:
    """The CLI prints a ``TrainerWarning`` (e.g. the hand starting in an object) as one
    ``warning:`` line that names the setting; any other warning keeps Python's format."""
    from trainer.errors import TrainerWarning

    text = trainer.cli.format_warning(TrainerWarning("raise [robot] home_hand_height"),
                                      TrainerWarning, "/somewhere/base.py", 12)
    assert text == "warning: raise [robot] home_hand_height\n"
    other = trainer.cli.format_warning(DeprecationWarning("old"), DeprecationWarning,
                                       "/somewhere/lib.py", 7)
    assert "/somewhere/lib.py:7" in other and "DeprecationWarning" in other


def test_held_out_objects_are_never_trained_on_and_evaluated_apart(
    builtin_data: Config, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    # held_out: the run's envs hold only the other objects; `trainer eval --held-out` runs the
    # held-out ones alone (eval-held-out/), the plain eval the trained ones.
    from tests.tiny_runs import tiny_run, trainer_main
    from trainer.session import EvalSession

    run = tiny_run(builtin_data, tmp_path / "run", "builtin_cylinder,builtin_box,builtin_sphere",
                   held_out="builtin_box")
    session = EvalSession.load(run.path, policy=False)
    assert session.names() == ["builtin_cylinder", "builtin_sphere"]
    assert session.env(4, seed=0, quiet=True).objects.names == ["builtin_cylinder",
                                                               "builtin_sphere"]
    code, out, err = trainer_main(["eval", str(run.path), "--held-out",
                                   "--episodes-per-object", "2"], monkeypatch, capsys)
    assert code == 0, err
    rows = (run.path / "eval-held-out" / "per_object.csv").read_text().splitlines()
    assert [r.split(",")[0] for r in rows[1:]] == ["builtin_box"]
    code, out, err = trainer_main(["eval", str(run.path), "--episodes-per-object", "2"],
                                  monkeypatch, capsys)
    assert code == 0, err
    rows = (run.path / "eval" / "per_object.csv").read_text().splitlines()
    assert [r.split(",")[0] for r in rows[1:]] == ["builtin_cylinder", "builtin_sphere"]
    # What cannot be meant is one line each.
    code, _, err = trainer_main(["eval", str(run.path), "--held-out", "--objects", "builtin_box"],
                                monkeypatch, capsys)
    assert code != 0 and "--held-out and --objects: pass one" in err
    other = tiny_run(builtin_data, tmp_path / "other", "builtin_cylinder")
    code, _, err = trainer_main(["eval", str(other.path), "--held-out"], monkeypatch, capsys)
    assert code != 0 and "holds out no objects" in err and len(err.strip().splitlines()) == 1
    for held, message in (("builtin_mug", "not among objects"),
                          ("builtin_cylinder,builtin_box", "holds out every object")):
        code, _, err = trainer_main(["run", "--objects", "builtin_cylinder,builtin_box",
                                     "--set", f"held_out={held}", "--steps", "32",
                                     "--data-dir", str(builtin_data.data_dir),
                                     "--run-dir", str(tmp_path / f"bad-{held}")],
                                    monkeypatch, capsys)
        assert code != 0 and message in err and len(err.strip().splitlines()) == 1


def test_bin_eval_on_new_bins(
    bin_run: Path, lift_run: Path, monkeypatch: pytest.MonkeyPatch, capsys  # noqa: ANN001
) -> None:
    """--new-bins: the run's policy in bins it never trained on (another seed's layouts), in
    eval-new; the run's own bins are kept as they were; a lift run has none to draw."""
    from trainer.session import EvalSession

    session = EvalSession(RunDir(bin_run).load_config())
    own, new = session.bin_env(4), session.bin_env(4, new_bins=True)
    assert not torch.equal(own.layouts, new.layouts)
    assert torch.equal(own.layouts, session.bin_env(4).layouts)
    for env in (own, new):
        env.close()
    code, out, err = invoke_all(["eval", str(bin_run), "--episodes-per-object", "1",
                                 "--new-bins", "--max-rounds", "1"], monkeypatch, capsys)
    assert code == 0, err
    assert "in new bins (never trained on)" in out.splitlines()[0]
    assert (bin_run / "eval-new" / "per_object.csv").is_file()
    code, _, err = invoke_all(["eval", str(lift_run), "--new-bins"], monkeypatch, capsys)
    assert code != 0 and "only a bin run has bins to draw anew" in err
    assert len(err.strip().splitlines()) == 1


def test_bin_eval_on_bins_of_another_size(
    bin_run: Path, lift_run: Path, monkeypatch: pytest.MonkeyPatch, capsys  # noqa: ANN001
) -> None:
    """--bin-objects N: the run's policy on new bins of N objects (the paper's ten-object
    evaluation of its five-object policy), in eval-binN; a lift run has no bins to resize."""
    code, out, err = invoke_all(["eval", str(bin_run), "--episodes-per-object", "1",
                                 "--bin-objects", "6", "--max-rounds", "2"], monkeypatch, capsys)
    assert code == 0, err
    assert out.splitlines()[0].startswith("task bin (6 objects per bin), representation bbox")
    rows = _per_object(bin_run, "eval-bin6")
    assert {r["bin_objects"] for r in rows.values()} == {"6"}
    # six objects in every bin of a six-object set: each one is in some bin
    assert "in none of the run's bins" not in out
    code, out, err = invoke_all(["eval", str(lift_run), "--bin-objects", "6"], monkeypatch,
                                capsys)
    assert code != 0 and "Traceback" not in err
    assert "is a lift run: only a bin run's evaluation takes a number of objects" in err
