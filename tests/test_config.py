"""The one dataclass-from-TOML loader (geomprep.config.build_dataclass) behind both configs:
types checked against the annotations, limits checked however a config is made, and every
problem one line that says where the value came from."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import pytest

from geomprep.config import (
    Checked,
    MeshParams,
    SDFParams,
    bounded,
    build_dataclass,
    load_config,
)
from geomprep.errors import GeomprepError
from trainer.config import (
    EnvConfig,
    RunConfig,
    TrainConfig,
    config_dict,
    load_env_config,
    load_train_config,
    read_train_config,
)
from trainer.errors import TrainerError


def one_line(exc_info: pytest.ExceptionInfo) -> str:
    message = str(exc_info.value)
    assert "\n" not in message, message
    return message


@pytest.mark.parametrize(
    "toml, expected",
    [
        ('num_envs = "16"', 'num_envs = "16": expected an integer'),
        ('[ppo]\nlr = "fast"', '[ppo] lr = "fast": expected a number'),
        ("[ppo]\nepochs = 2.5", "[ppo] epochs = 2.5: expected an integer"),
        ('[physics]\nsubsteps = "ten"', '[physics] substeps = "ten": expected an integer'),
        ("[run]\nseed = true", "[run] seed = true: expected an integer"),  # bool is no int
        ("compile = 1", "compile = 1: expected true or false"),
        ("[ppo]\nhidden = [64, 1.5]", "[ppo] hidden = [64, 1.5]: expected a list of integers"),
        ("[physics]\nsolref = [0.01]", "[physics] solref = [0.01]: expected a list of 2 numbers"),
        ("data_dir = 3", "data_dir = 3: expected a path"),
        ("physics = 3", "physics = 3: expected a table"),
        ("ppo = 3", "ppo = 3: expected a table"),
        ("[physics]\ncontrol_hz = 0", "[physics] control_hz = 0: must be > 0"),
        ("[ppo]\nminibatches = 0", "[ppo] minibatches = 0: must be >= 1"),
        ("[run]\ncheckpoint_every = 0", "[run] checkpoint_every = 0: must be >= 1"),
        ("[run]\ntotal_steps = -5", "[run] total_steps = -5: must be >= 1"),
        ("num_envs = 0", "num_envs = 0: must be >= 1"),
        ("[ppo]\ngamma = 1.5", "[ppo] gamma = 1.5: must be >= 0 and <= 1"),
        ("[ppo]\nlr = nan", "[ppo] lr = nan: must be a finite number"),
        # inf passes "> 0" (control_hz = inf used to end in a ZeroDivisionError traceback);
        # nan in an unbounded field would train on NaN losses.
        ("[physics]\ncontrol_hz = inf", "[physics] control_hz = inf: must be a finite number"),
        ("[ppo]\nentropy_coef = nan", "[ppo] entropy_coef = nan: must be a finite number"),
        (
            "[physics]\ntable_size = [0.4, inf, 0.02]",
            "[physics] table_size = [0.4, inf, 0.02]: must be a finite number",
        ),
        ("[ppo]\nlr = 1" + "0" * 400, "[ppo] lr = 1" + "0" * 400 + ": is too large for a number"),
        (
            "[physics]\ntable_size = [0.4, 0, 0.02]",
            "[physics] table_size = [0.4, 0, 0.02]: each element must be > 0",
        ),
        ('representation = "xyz"', 'representation = "xyz": must be one of "com"'),
        ('[reward]\nkind = "dense"', '[reward] kind = "dense": must be one of "sdf"'),
        ("[init]\ndrop_height = [0.2, 0.1]", "[init] drop_height = [0.2, 0.1]: must be [lowest"),
        ("[ppo]\ninit_action_mean = [0.0]", "[ppo] init_action_mean = [0.0]: needs 11 values"),
        ("[ppo]\ninit_log_std = [-1.0, -2.0]", "[ppo] init_log_std = [-1.0, -2.0]: needs one"),
        ("[physics]\nsubstep = 5", "[physics]: unknown key 'substep' (did you mean 'substeps'?)"),
    ],
)
def test_trainer_config_errors_name_file_section_key_and_value(
    tmp_path: Path, toml: str, expected: str
) -> None:
    path = tmp_path / "cfg.toml"
    path.write_text(toml + "\n")
    with pytest.raises(TrainerError) as exc:
        load_train_config(path)
    assert one_line(exc).startswith(f"{path} {expected}")


def test_type_errors_give_the_default_as_an_example(tmp_path: Path) -> None:
    path = tmp_path / "cfg.toml"
    path.write_text('num_envs = "16"\n')
    with pytest.raises(TrainerError, match=r"\(the default: num_envs = 64\)$"):
        load_train_config(path)


def test_values_are_converted_to_the_annotated_types(tmp_path: Path) -> None:
    path = tmp_path / "cfg.toml"
    path.write_text(
        'data_dir = "elsewhere"\nnum_envs = 8\ncompile = true\n[physics]\ncontrol_hz = 60\n'
        "table_size = [1, 1, 0.5]\n[ppo]\nhidden = [8, 16]\n[run]\nseed = 4\n"
    )
    cfg = load_train_config(path)
    assert cfg.env.data_dir == Path("elsewhere") and cfg.env.num_envs == 8 and cfg.env.compile
    # An integer where a number is expected is accepted, as a float (config.json stays typed).
    assert cfg.env.physics.control_hz == 60.0 and isinstance(cfg.env.physics.control_hz, float)
    assert cfg.env.physics.table_size == (1.0, 1.0, 0.5)
    assert cfg.ppo.hidden == (8, 16) and cfg.run.seed == 4
    # load_env_config reads the same file, ignoring [ppo] and [run].
    assert load_env_config(path).physics.control_hz == 60.0


def test_command_line_overrides_are_checked_and_name_the_option() -> None:
    names = {"total_steps": "--steps", "seed": "--seed", "num_envs": "--num-envs"}
    for section, values, expected in [
        ("run", {"total_steps": 0}, "--steps 0: must be >= 1"),
        ("run", {"seed": -1}, "--seed -1: must be >= 0"),
        ("env", {"num_envs": -3}, "--num-envs -3: must be >= 1"),
    ]:
        with pytest.raises(TrainerError) as exc:
            load_train_config(None, names=names, **{section: values})
        assert one_line(exc) == expected


def test_overrides_win_over_the_file(tmp_path: Path) -> None:
    path = tmp_path / "cfg.toml"
    path.write_text("num_envs = 8\ncompile = true\n[reward]\nkind = \"com\"\n")
    cfg = load_train_config(path, env={"num_envs": 2, "reward": {"kind": "none"}})
    assert cfg.env.num_envs == 2 and cfg.env.reward.kind == "none"
    assert cfg.env.compile  # not overridden: the file's value stays
    assert cfg.env.reward.c1 == 0.5  # a nested override keeps the section's other fields


def test_limits_hold_for_configs_made_in_code() -> None:
    # __post_init__ checks, so dataclasses.replace and direct construction are covered too.
    with pytest.raises(TrainerError, match="num_envs = 0: must be >= 1"):
        EnvConfig(num_envs=0)
    with pytest.raises(TrainerError, match="seed = -1: must be >= 0"):
        RunConfig(seed=-1)
    with pytest.raises(GeomprepError, match="resolution = 0: must be >= 2"):
        SDFParams(resolution=0)


def test_config_json_round_trip_and_bad_values(tmp_path: Path) -> None:
    cfg = load_train_config(env={"num_envs": 3, "data_dir": Path("d")}, ppo={"hidden": (8,)})
    path = tmp_path / "config.json"
    path.write_text(json.dumps(config_dict(cfg)))
    assert read_train_config(path) == cfg
    values = config_dict(cfg)
    values["run"]["checkpoint_every"] = 0
    path.write_text(json.dumps(values))
    with pytest.raises(TrainerError) as exc:
        read_train_config(path)
    assert one_line(exc).startswith(f"{path} [run] checkpoint_every = 0: must be >= 1")
    values["run"]["checkpoint_every"] = 1
    values["env"]["physics"]["substeps"] = "ten"
    path.write_text(json.dumps(values))
    with pytest.raises(TrainerError, match=r"\[env.physics\] substeps = \"ten\": expected an int"):
        read_train_config(path)
    path.write_text(json.dumps(values)[:40])  # a config.json cut short
    with pytest.raises(TrainerError, match="is unreadable") as exc:
        read_train_config(path)
    one_line(exc)
    with pytest.raises(TrainerError, match="not a run directory"):
        read_train_config(tmp_path / "none" / "config.json")


@pytest.mark.parametrize(
    "toml, expected",
    [
        ("[pc]\nsizes = 512", "[pc] sizes = 512: expected a list of integers"),
        ('[build]\njobs = "two"', '[build] jobs = "two": expected an integer'),
        ("[build]\njobs = -1", "[build] jobs = -1: must be >= 0"),
        ("[sdf]\nresolution = 0", "[sdf] resolution = 0: must be >= 2"),
        ('[sdf]\ncompression = "zip"', '[sdf] compression = "zip": must be one of "gzip", "lzf"'),
        ("[pc]\nsizes = [16, 0]", "[pc] sizes = [16, 0]: each element must be >= 1"),
        ("[mesh]\ndensity_kg_m3 = -1.0", "[mesh] density_kg_m3 = -1.0: must be > 0"),
        ("[sq]\nsurface_weight = inf", "[sq] surface_weight = inf: must be a finite number"),
        ("[decompose]\nmax_hulls = 0", "[decompose] max_hulls = 0: must be >= 1"),
        ("[sdf]\nresolutoin = 64", "[sdf]: unknown key 'resolutoin'"),
        ("[sfd]\nresolution = 64", "unknown section [sfd] (did you mean 'sdf'?)"),
    ],
)
def test_geomprep_config_errors(tmp_path: Path, toml: str, expected: str) -> None:
    path = tmp_path / "geomprep.toml"
    path.write_text(toml + "\n")
    with pytest.raises(GeomprepError) as exc:
        load_config(path)
    assert one_line(exc).startswith(str(path)) and expected in str(exc.value)


def test_config_file_not_utf8_is_one_line(tmp_path: Path) -> None:
    """A config saved as UTF-16 (as some editors do) used to end in a UnicodeDecodeError."""
    path = tmp_path / "cfg.toml"
    path.write_text("[ppo]\nlr = 0.001\n", encoding="utf-16")
    with pytest.raises(GeomprepError) as exc:
        load_config(path)
    assert one_line(exc) == f"config file {path} is not UTF-8 text (byte 0 cannot be read): " \
        "save it as UTF-8"
    with pytest.raises(TrainerError, match="is not UTF-8 text") as exc:
        load_train_config(path)
    one_line(exc)


def test_geomprep_config_converts(tmp_path: Path) -> None:
    path = tmp_path / "geomprep.toml"
    path.write_text("[mesh]\ndensity_kg_m3 = 800\n[pc]\nsizes = [16, 64]\n")
    cfg = load_config(path, data_dir=tmp_path)
    assert cfg.mesh == MeshParams(density_kg_m3=800.0) and cfg.pc.sizes == (16, 64)
    assert cfg.data_dir == tmp_path


@dataclass(frozen=True)
class _Inner(Checked):
    mode: Literal["a", "b"] = "a"
    weights: tuple[float, ...] = bounded((1.0,), ge=0)


@dataclass(frozen=True)
class _Outer(Checked):
    path: Path = Path("x")
    maybe: int | None = None
    inner: _Inner = field(default_factory=_Inner)


def test_generic_loader_literal_optional_and_nested_sections() -> None:
    built = build_dataclass(
        _Outer, {"path": "y", "maybe": 3, "inner": {"mode": "b", "weights": [1, 2]}}, "f.toml"
    )
    assert built == _Outer(Path("y"), 3, _Inner("b", (1.0, 2.0)))
    for values, expected in [
        ({"inner": {"mode": "c"}}, 'f.toml [inner] mode = "c": expected one of "a", "b"'),
        ({"maybe": "3"}, 'f.toml maybe = "3": expected an integer'),
        ({"inner": {"weights": [1, -1]}}, "f.toml [inner] weights = [1, -1]: each element"),
    ]:
        with pytest.raises(GeomprepError) as exc:
            build_dataclass(_Outer, values, "f.toml")
        assert one_line(exc).startswith(expected)
    # The caller's error type is raised.
    with pytest.raises(TrainerError):
        build_dataclass(TrainConfig, {"run": {"seed": "x"}}, "c.json", TrainerError)


def test_presets_load_and_hold_the_paper_schedule() -> None:
    """configs/*.toml are the named starting points README documents; paper.toml is the
    paper's schedule: 16,384 envs x 32 steps, minibatches of 32,768, 500 iterations."""
    from trainer.ppo import iteration_frames, minibatch_size

    root = Path(__file__).resolve().parents[1] / "configs"
    presets = {p.stem: load_train_config(p) for p in sorted(root.glob("*.toml"))}
    assert {"paper", "cpu", "cpu-table1", "cpu-bin"} <= set(presets)
    paper = presets["paper"]
    assert paper.env.num_envs == 16384 and paper.ppo.frames_per_env == 32
    assert paper.ppo.epochs == 5 and minibatch_size(paper) == 32768
    assert paper.run.total_steps // iteration_frames(paper) == 500
    assert paper.env.reward.h_bar_start == paper.env.reward.h_bar  # no curriculum
    assert presets["cpu"].env.reward.h_bar_start < presets["cpu"].env.reward.h_bar
    # cpu-table1 starts training episodes along scripted grasps: each of its objects has one.
    from trainer.grasps.families import BEST

    table1 = presets["cpu-table1"]
    assert table1.run.grasp_starts > 0 and table1.env.robot.hand_action == "relative"
    assert set(table1.env.objects.split(",")) == set(BEST)
    cpu_bin = presets["cpu-bin"].env
    assert cpu_bin.task == "bin" and cpu_bin.representation == "bbox"  # the paper's choice
    assert cpu_bin.reward.curriculum_per_object and cpu_bin.physics.sleep
