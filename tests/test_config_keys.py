"""Every config key from one source (trainer.config_keys): ``trainer config`` prints them,
docs/config.md is written from them and kept up to date, each key says in a few lines what it
does and whether the paper states it, and ``--set section.key=value`` sets any of them on every
command that reads a config, checked like the file."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

import trainer.cli
import trainer.ppo
from geomgrasp.config_schema import field_docs
from tests.tiny_runs import trainer_main
from trainer.config import load_env_config, load_train_config
from trainer.config_keys import all_keys, markdown, parse_sets
from trainer.errors import TrainerError

ROOT = Path(__file__).resolve().parents[1]


def invoke(argv: list[str], monkeypatch: pytest.MonkeyPatch, capsys) -> tuple[int, str, str]:  # noqa: ANN001
    """The real entry point (as the installed ``trainer`` script): exit code, stdout, stderr."""
    code, out, err = trainer_main(argv, monkeypatch, capsys)
    return code, out, err.strip()


def test_docs_config_md_is_up_to_date() -> None:
    written = (ROOT / "docs" / "config.md").read_text(encoding="utf-8")
    assert written == markdown(), (
        "docs/config.md is out of date: run trainer config --markdown docs/config.md"
    )


def test_every_key_has_a_short_docstring_whose_links_exist() -> None:
    keys = all_keys()
    assert len(keys) == 124 and len({k.path for k in keys}) == 124
    for key in keys:
        doc = field_docs(key.owner).get(key.name)
        assert doc, f"{key.path} has no docstring"
        assert len(doc.splitlines()) <= 4, f"{key.path}: {len(doc.splitlines())} lines"
        for path in re.findall(r"results/[\w.\-/]*\w", doc):
            assert (ROOT / path).exists(), f"{key.path} links {path}, which does not exist"
    # The history moved to results/: each entry there is a key's.
    evidence = (ROOT / "results" / "config-evidence.md").read_text(encoding="utf-8")
    entries = re.findall(r"^### `([\w.]+)`$", evidence, re.M)
    assert {"run.warmup_objects", "run.init_agent_unseen"} <= set(entries)
    assert set(entries) <= {k.path for k in keys}
    assert "1.06 M env steps on the tuna can" in evidence  # warmup_objects' history, kept


PAPER_KEYS = {
    "num_envs", "task", "representation", "objects", "max_steps", "physics.control_hz",
    "robot.kind", "reward.kind", "reward.h_bar", "reward.c1", "reward.c2", "reward.c3",
    "reward.eps_h", "reward.eps_sdf", "bin.num_objects", "ppo.frames_per_env", "ppo.epochs",
    "ppo.minibatches", "ppo.hidden", "run.total_steps",
}


def test_the_paper_keys_are_marked_and_paper_toml_holds_their_numbers() -> None:
    keys = all_keys()
    assert {k.path for k in keys if k.paper is not None} == PAPER_KEYS
    # Where the paper states one number, configs/paper.toml (the paper's settings) has it.
    paper = load_train_config(ROOT / "configs" / "paper.toml")
    checked = 0
    for key in keys:
        number = re.fullmatch(r"(\d+(?:\.\d+)?)(?: \(.*\))?", key.paper or "")
        if number:
            node = paper.env if key.section not in ("ppo", "run") else paper
            for part in key.path.split("."):
                node = getattr(node, part)
            assert node == float(number.group(1)), key.path
            checked += 1
    assert checked == 13


def test_trainer_config_prints_a_paper_key_and_a_project_key(
    monkeypatch: pytest.MonkeyPatch, capsys  # noqa: ANN001
) -> None:
    code, out, err = invoke(["config", "reward.c3", "noslip"], monkeypatch, capsys)
    assert code == 0 and not err
    lines = out.splitlines()
    assert lines[0].startswith("[physics]  Simulation timing")
    assert re.fullmatch(r"  physics\.noslip_iterations = 5 +an integer >= 0 +ours", lines[1])
    assert lines[2].startswith("      Passes of MuJoCo's no-slip solver")
    assert lines[3] == "" and lines[4].startswith("[reward]  r = c1 /")
    assert re.fullmatch(r"  reward\.c3 = 1\.0 +a number +paper: 1 \(ablation: 0\)", lines[5])
    assert lines[6] == "      Weight of the contact term."
    # --paper: the paper's keys only; every key without arguments.
    code, out, _ = invoke(["config", "--paper"], monkeypatch, capsys)
    assert code == 0 and " ours\n" not in out and out.count("paper: ") == len(PAPER_KEYS)
    code, out, _ = invoke(["config"], monkeypatch, capsys)
    assert code == 0 and out.count("\n      ") == 124
    code, _, err = invoke(["config", "no_such_key"], monkeypatch, capsys)
    assert code == 1 and err == (
        "error: no key matches no_such_key: trainer config with no argument lists them all"
    )


def test_trainer_config_writes_the_markdown(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys  # noqa: ANN001
) -> None:
    out = tmp_path / "docs" / "config.md"
    code, stdout, _ = invoke(["config", "--markdown", str(out)], monkeypatch, capsys)
    assert code == 0 and stdout == f"written: {out}\n"
    assert out.read_text(encoding="utf-8") == markdown()


def test_set_values_are_toml_and_checked_against_the_keys() -> None:
    sets = parse_sets(["physics.substeps=12", "physics.sleep=true", "robot.hand_geometry=capsules",
                       'objects="a b"', "num_envs=8", "reward.c3=0"])
    assert sets == {"physics.substeps": 12, "physics.sleep": True,
                    "robot.hand_geometry": "capsules", "objects": "a b", "num_envs": 8,
                    "reward.c3": 0}
    cfg = load_env_config(None, sets)
    assert cfg.physics.substeps == 12 and cfg.physics.sleep and cfg.num_envs == 8
    assert cfg.robot.hand_geometry == "capsules" and cfg.reward.c3 == 0.0
    assert cfg.reward.c1 == 0.5  # the section's other keys keep their values
    train = parse_sets(["ppo.hidden=[8, 8]", "run.seed=3", "ppo.lr=1e-3"], training=True)
    cfg = load_train_config(None, sets=train)
    assert cfg.ppo.hidden == (8, 8) and cfg.run.seed == 3 and cfg.ppo.lr == 0.001


def test_set_wins_over_the_file_and_options_over_set(tmp_path: Path) -> None:
    path = tmp_path / "c.toml"
    path.write_text("num_envs = 8\n[reward]\nc3 = 2.0\nc1 = 0.25\n[run]\nseed = 4\n")
    sets = parse_sets(["reward.c3=3.0", "run.seed=5"], training=True)
    cfg = load_train_config(path, sets=sets)
    assert cfg.env.reward.c3 == 3.0 and cfg.env.reward.c1 == 0.25 and cfg.run.seed == 5
    cfg = load_train_config(path, env={"num_envs": 2}, run={"seed": 6}, sets=sets)
    assert cfg.env.num_envs == 2 and cfg.run.seed == 6 and cfg.env.reward.c3 == 3.0


@pytest.mark.parametrize(
    "texts, training, expected",
    [
        (["physics.substeps=0"], False,
         "--set physics.substeps=0: must be >= 1 (the default: physics.substeps = 10)"),
        (["physics.substeps=ten"], False,
         "--set physics.substeps=ten: expected an integer (the default: physics.substeps = 10)"),
        (["physics.substep=5"], False, "--set physics.substep=5: unknown key physics.substep "
         "(did you mean physics.substeps?): trainer config lists every key"),
        (["phyics.substeps=5"], False, "--set phyics.substeps=5: unknown key phyics.substeps "
         "(did you mean physics.substeps?)"),
        (["physics=5"], False, "--set physics=5: [physics] is a section: set one of its keys, "
         "e.g. physics.control_hz=30.0"),
        (["robot.hand_geometry=spheres"], False, '--set robot.hand_geometry=spheres: must be one '
         'of "capsules", "hulls"'),
        (["ppo.lr=0.1"], False, "--set ppo.lr=0.1: [ppo] configures training, which this "
         "command does not run: drop it"),
        (["ppo.lr=fast"], True, "--set ppo.lr=fast: expected a number (the default: ppo.lr = "),
        (["run.seed=-1"], True, "--set run.seed=-1: must be >= 0"),
        (["num_envs"], True, "--set 'num_envs': write KEY=VALUE with KEY as section.key"),
        (["physics.table_size=[0.4, 0]"], False, "--set physics.table_size=[0.4, 0]: expected "
         "a list of 3 numbers"),
    ],
)
def test_set_errors_are_one_line_naming_the_key_and_the_fix(
    texts: list[str], training: bool, expected: str
) -> None:
    with pytest.raises(TrainerError) as exc:
        parse_sets(texts, training=training)
    message = str(exc.value)
    assert "\n" not in message and message.startswith(expected), message


def test_run_takes_set_for_any_key(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys  # noqa: ANN001
) -> None:
    seen = []
    monkeypatch.setattr(trainer.ppo, "train", lambda cfg, run_dir, **kw: seen.append(cfg))
    config = tmp_path / "c.toml"
    config.write_text("[reward]\nc3 = 2.0\n")
    code, _, err = invoke(
        ["run", "--config", str(config), "--run-dir", str(tmp_path / "r"), "--set",
         "reward.c3=0", "--set", "ppo.lr=1e-4", "--set", "run.grasp_starts=0.5", "--set",
         "robot.hand_action=relative", "--num-envs", "4"], monkeypatch, capsys,
    )
    assert code == 0, err
    (cfg,) = seen
    assert cfg.env.reward.c3 == 0.0 and cfg.ppo.lr == 1e-4 and cfg.run.grasp_starts == 0.5
    assert cfg.env.robot.hand_action == "relative" and cfg.env.num_envs == 4


@pytest.mark.parametrize(
    "argv, expected",
    [
        (["run", "--set", "physics.substeps=0"],
         "error: --set physics.substeps=0: must be >= 1 (the default: physics.substeps = 10)"),
        # A check across keys names the --set that broke it.
        (["run", "--set", "reward.hold_from=0.5"],
         "error: --set reward.hold_from=0.5: must be at most h_bar (0.2)"),
        (["run", "--set", "run.warmup_steps=1000"],
         "error: --set run.warmup_steps=1000: needs the other: set warmup_objects and"),
        (["run", "--repr", "sq", "--set", "representation=bbox"],
         "error: --set representation and --repr both set representation: drop one"),
        (["run", "--steps", "5", "--set", "run.total_steps=6"],
         "error: --set run.total_steps and --steps both set run.total_steps: drop one"),
        (["run", "--resume", "nowhere", "--set", "ppo.lr=1e-3"],
         "error: --set cannot change a resumed run"),
        (["demo", "--set", "ppo.lr=0.1"], "error: --set ppo.lr=0.1: [ppo] configures training"),
        (["grasp", "--set", "robot.hand_kp=-1"], "error: --set robot.hand_kp=-1: must be >= 0"),
        (["grasp-search", "--objects", "x", "--set", "robot.hand_kpp=1"],
         "error: --set robot.hand_kpp=1: unknown key robot.hand_kpp (did you mean "
         "robot.hand_kp?)"),
    ],
)
def test_set_errors_on_every_command_are_one_line(
    argv: list[str], expected: str, monkeypatch: pytest.MonkeyPatch, capsys, tmp_path: Path  # noqa: ANN001
) -> None:
    monkeypatch.chdir(tmp_path)
    code, _, err = invoke(argv, monkeypatch, capsys)
    assert code == 1 and err.startswith(expected) and "\n" not in err, err


def test_grasp_passes_set_with_its_own_options(
    monkeypatch: pytest.MonkeyPatch, capsys  # noqa: ANN001
) -> None:
    import trainer.grasps.trials

    calls = []
    monkeypatch.setattr(trainer.grasps.trials, "measure", lambda *a, **kw: calls.append(kw) or [])
    code, _, err = invoke(
        ["grasp", "--objects", "builtin_box", "--hold-tips", "1", "--set", "reward.h_bar=0.1",
         "--set", "physics.noslip_iterations=0"], monkeypatch, capsys,
    )
    assert code == 0, err
    assert calls == [{"hold": False, "reward": {"h_bar": 0.1, "hold_tips": 1},
                      "physics": {"noslip_iterations": 0}}]
    code, _, err = invoke(["grasp", "--hold-tips", "1", "--set", "reward.hold_tips=3"],
                          monkeypatch, capsys)
    assert code == 1 and err == (
        "error: --set reward.hold_tips and --hold-tips both set reward.hold_tips: drop one"
    )
