"""A training run's whole state (``TrainState``) and the checkpoint files that hold it.

A checkpoint holds the networks, optimizer, normalizers, every random generator, the episode
counters, the lift curriculum and the whole simulation state of every env, so a resumed run
continues exactly as if it had never stopped (``tests/test_ppo.py`` checks this bit for bit).
Checkpoints are written atomically; an unreadable ``last.pt`` falls back to the newest
readable ``iter_NNNNNN.pt``.

The file is one ``torch.save``-d dict; ``TrainState.state_dict`` writes, and
``load_state_dict`` reads, the same keys as every checkpoint written so far (older ones lack
``h_bar``, ``target_outcomes``, ``object_outcomes``: defaults stand in)."""

from __future__ import annotations

import dataclasses
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from geomgrasp.files import atomic_path
from trainer.config import AGENT_PARTS, TrainConfig, check_device
from trainer.errors import TrainerError
from trainer.models import Agent
from trainer.tasks import GraspTask, observation_spec
from trainer.training.curriculum import LiftCurriculum
from trainer.training.outcomes import EpisodeStats
from trainer.training.run_dir import RunDir

CHECKPOINT_KEYS = (
    "iteration", "wall_time_s", "agent", "optimizer", "shuffle_rng", "torch_rng", "outcomes",
    "episode_return", "episode_length", "env",
)
"""Keys every checkpoint has (a file without them is not one; the curriculum's are optional)."""


@dataclass
class TrainState:
    """Everything a run carries from one iteration to the next: ``iteration`` (done so far),
    ``wall_time_s`` (s of training so far), the agent (networks and normalizers) and its
    optimizer, the minibatch-order generator ``shuffle``, the episode counters, the lift
    curriculum and the envs (their simulation, task state and generator).

    The global torch generator (actions are drawn from it) is written by ``state_dict`` but set
    by ``restore_global_rng``, apart: a resumed run sets it after the collector's set-up, which
    draws from it (and the envs' snapshot is applied at the collector's first reset, so
    ``load_state_dict`` comes before that)."""

    agent: Agent
    optimizer: torch.optim.Optimizer
    shuffle: torch.Generator
    episodes: EpisodeStats
    curriculum: LiftCurriculum
    env: GraspTask
    iteration: int = 0
    wall_time_s: float = 0.0

    def state_dict(self) -> dict[str, Any]:
        device = self.env.device
        episodes = self.episodes.state_dict()
        # In the key order of the checkpoints written so far.
        return {
            "iteration": self.iteration,
            "wall_time_s": self.wall_time_s,
            "agent": self.agent.state_dict(),
            "optimizer": self.optimizer.state_dict(),
            "shuffle_rng": self.shuffle.get_state(),
            "torch_rng": torch.get_rng_state(),
            **({"cuda_rng": torch.cuda.get_rng_state(device)} if device.type == "cuda" else {}),
            "outcomes": episodes.pop("outcomes"),
            **self.curriculum.state_dict(),
            **episodes,
            "env": self.env.snapshot(),
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Everything but the global generator (``restore_global_rng``); the envs return to
        their snapshot at their next full reset."""
        self.agent.load_state_dict(state["agent"])
        self.optimizer.load_state_dict(state["optimizer"])
        self.shuffle.set_state(state["shuffle_rng"])
        self.episodes.load_state_dict(state)
        self.curriculum.load_state_dict(state)
        self.iteration, self.wall_time_s = state["iteration"], state["wall_time_s"]
        self.env.restore_on_next_reset(state["env"])


def restore_global_rng(state: dict[str, Any], device: torch.device) -> None:
    """Set torch's global generator(s) (the CPU one, and ``device``'s if it is a GPU and the
    checkpoint has it) to a checkpoint's."""
    torch.set_rng_state(state["torch_rng"])
    if device.type == "cuda" and "cuda_rng" in state:
        torch.cuda.set_rng_state(state["cuda_rng"], device)


def write_checkpoint(run: RunDir, state: dict[str, Any]) -> None:
    """``state`` (a ``TrainState.state_dict``) as the checkpoint of its iteration and as
    ``last.pt``."""
    run.checkpoints.mkdir(parents=True, exist_ok=True)
    with atomic_path(run.checkpoint(state["iteration"])) as tmp:
        torch.save(state, tmp)
    with atomic_path(run.last) as tmp:
        torch.save(state, tmp)


def load_last_checkpoint(run: RunDir, map_location: str | None = None) -> dict[str, Any]:
    """The state in ``last.pt`` or, if that is missing or unreadable (a truncated, empty or
    corrupt file), in the newest readable ``iter_NNNNNN.pt``; a fallback is reported on
    stderr."""
    candidates = [run.last, *sorted(run.checkpoints.glob("iter_*.pt"), reverse=True)]
    unreadable = []
    for path in candidates:
        if not path.is_file():
            continue
        state = read_checkpoint(path, map_location)
        if isinstance(state, str):
            unreadable.append(f"{path.name} ({state})")
            continue
        if unreadable:
            print(
                f"warning: {run.checkpoints}: unreadable {', '.join(unreadable)}; using "
                f"{path.name} (iteration {state['iteration']})", file=sys.stderr, flush=True,
            )
        return state
    if unreadable:
        raise TrainerError(
            f"{run.checkpoints}: no readable checkpoint ({', '.join(unreadable)}): start the run "
            f"again with --overwrite"
        )
    raise TrainerError(f"{run.path}: no checkpoint yet ({run.last}): train it with trainer run")


def load_checkpoint_of(run: RunDir, iteration: int) -> dict[str, Any]:
    """The state of the checkpoint of ``iteration``, exactly that one (on the CPU)."""
    path = run.checkpoint(iteration)
    if not path.is_file():
        kept = run.checkpoint_iterations()
        listed = ", ".join(map(str, kept)) if len(kept) <= 4 else (
            f"{kept[0]}, {kept[1]}, ..., {kept[-1]}")
        have = f"it has iterations {listed}" if kept else "it has none"
        raise TrainerError(f"{run.path}: no checkpoint of iteration {iteration} ({have})")
    state = read_checkpoint(path, map_location="cpu")  # whatever device it was trained on
    if isinstance(state, str):
        raise TrainerError(f"{path}: unreadable ({state})")
    return state


def read_checkpoint(path: Path, map_location: str | None) -> dict[str, Any] | str:
    """The state in the checkpoint file ``path``, or why it is not one (a reason, not raised:
    ``load_last_checkpoint`` then tries the next file)."""
    try:
        state = torch.load(path, weights_only=False, map_location=map_location)
    except Exception as exc:  # noqa: BLE001 (whatever torch.load raises, the file is bad)
        # An EOFError must not escape: click would turn it into "aborted", as for Ctrl-C.
        return type(exc).__name__
    if not isinstance(state, dict) or any(k not in state for k in CHECKPOINT_KEYS):
        return "not a checkpoint"
    return state


def init_agent_from(agent: Agent, source: Path) -> str:
    """Load into ``agent`` the networks and normalizers of the checkpoint ``source`` (a file, or
    a run directory: its last readable checkpoint) (``[run] init_agent``); returns a line for the
    run's log. An agent of another shape (representation, task, network sizes) is a one-line
    error naming the first tensor that differs; an agent without context starts one with
    (``with_context_added``)."""
    source = Path(source)
    if source.is_dir():
        state = load_last_checkpoint(RunDir(source), map_location="cpu")
    elif source.is_file():
        read = read_checkpoint(source, map_location="cpu")
        if isinstance(read, str):
            raise TrainerError(f"init_agent {source}: unreadable ({read}): name a checkpoint "
                               f"file (runs/NAME/checkpoints/iter_NNNNNN.pt) or a run directory")
        state = read
    else:
        raise TrainerError(f"init_agent {source}: no such checkpoint file or run directory")
    own, theirs = agent.state_dict(), state["agent"]
    grafted, note = with_context_added(own, theirs), (
        ", a policy without context: its context encoder new, silent at the start")
    if grafted is None:
        grafted, note = theirs, ""
        for name in sorted(set(own) | set(theirs)):
            mine = tuple(own[name].shape) if name in own else "absent"
            its = tuple(theirs[name].shape) if name in theirs else "absent"
            if mine != its:
                raise TrainerError(
                    f"init_agent {source}: its agent does not fit this run's ({name}: {its} "
                    f"there, {mine} here): start from a run with the same representation, task "
                    f"and [ppo] network sizes"
                )
    agent.load_state_dict(grafted)
    return f"agent: initialised from {source} (iteration {state['iteration']}){note}"


def with_context_added(
    own: dict[str, torch.Tensor], theirs: dict[str, torch.Tensor],
) -> dict[str, torch.Tensor] | None:
    """``theirs`` (the state dict of an agent that sees no context, a lift policy say) grafted
    onto ``own`` (the same agent with ``context``), or None if ``own`` adds no context to
    ``theirs`` or differs from it otherwise.

    Every tensor they share is theirs; the context's encoder and normalizer keep ``own``'s
    fresh values; each first body layer takes their weights for the inputs they had and 0 for
    the context features appended after them (``Encoder.forward``'s order). The grafted agent
    computes exactly what theirs computed, whatever the context holds, and those zero weights
    train from the first update: a bin run with context starts from the same policy as its
    pair without, so the pair measures the context alone."""
    new_parts = [name for name in own if name not in theirs]
    if not new_parts or any("context" not in name.split(".") for name in new_parts):
        return None
    if any(name not in own for name in theirs):
        return None
    # the context encoder's output width: the rows of its last linear layer
    layers = [(int(name.split(".")[-2]), own[name].shape[0]) for name in new_parts
              if ".encoder.context." in name and name.endswith(".weight")]
    if not layers:
        return None
    context_width = max(layers)[1]
    merged = dict(own)
    for name, their_value in theirs.items():
        mine = own[name]
        if mine.shape == their_value.shape:
            merged[name] = their_value
        elif (name.endswith("body.0.weight") and mine.dim() == 2
              and mine.shape[0] == their_value.shape[0]
              and mine.shape[1] - their_value.shape[1] == context_width):
            widened = torch.zeros_like(mine)
            widened[:, : their_value.shape[1]] = their_value
            merged[name] = widened
        else:
            return None
    return merged


def agent_part(key: str) -> str:
    """The ``AGENT_PARTS`` entry an agent state-dict key belongs to (the same tensor appears
    under several keys, every one of them classed alike)."""
    names = key.split(".")
    if "log_std" in names:
        return "action_std"
    if {"obs_norm", "value_norm", "norm"} & set(names):
        return "normalizers"
    return "networks"


def copy_agent_parts(source: Agent, target: Agent, parts: tuple[str, ...] = AGENT_PARTS) -> None:
    """Copy ``parts`` (of ``AGENT_PARTS``) of ``source``'s state into ``target`` (two agents of
    one shape); the rest of ``target`` stays as it is."""
    theirs = source.state_dict()
    merged = {
        key: theirs[key] if agent_part(key) in parts else value
        for key, value in target.state_dict().items()
    }
    target.load_state_dict(merged)


def load_agent(
    run_dir: Path, device: str | None = None, iteration: int | None = None
) -> tuple[TrainConfig, Agent]:
    """A trained run's config and agent (networks + normalizers, in eval mode) from its last
    readable checkpoint (or that of ``iteration``; 0: the agent the run started from,
    ``start_agent``), on ``device`` (default: the run's), which the returned config names."""
    run = RunDir(Path(run_dir))
    cfg = run.load_config()
    if device is not None:
        cfg = dataclasses.replace(cfg, env=dataclasses.replace(cfg.env, device=device))
    check_device(
        cfg.env.device, f"device {cfg.env.device!r} of {run.path}", "pass --device cpu"
    )
    agent = Agent(observation_spec(cfg.env, 1)["observation"], cfg.ppo)
    if iteration == 0:
        start_agent(agent, run, cfg)
    else:
        if iteration is None:
            state = load_last_checkpoint(run, map_location="cpu")  # whatever device it trained on
        else:
            state = load_checkpoint_of(run, iteration)
        agent.load_state_dict(state["agent"])
    agent.eval()
    return cfg, agent.to(cfg.env.device)


def agent_source(cfg: TrainConfig, run: RunDir) -> Path | str:
    """Where the run ``run`` of config ``cfg`` takes its first agent from: its warmup run
    (``[run] warmup_objects``), else its ``init_agent`` ("": a fresh agent)."""
    return run.warmup if cfg.run.warmup_steps else cfg.run.init_agent


def start_agent(agent: Agent, run: RunDir, cfg: TrainConfig) -> None:
    """Load into ``agent`` the agent the run ``run`` (of config ``cfg``) started training from:
    its warmup's or its ``init_agent``'s, as ``trainer.ppo.build_parts`` loaded it (unseen
    features silenced where the run did). What a run's training added is measured against it
    (e.g. a bin run from a lift policy). A run that started from a fresh agent, or from only
    some parts of another, has no such agent to load: a one-line error."""
    source = agent_source(cfg, run)
    if not source:
        raise TrainerError(f"{run.path} started from a fresh agent (no init_agent or warmup): "
                           "iteration 0 has no agent to load; pass --iteration 1 or later")
    if set(cfg.run.init_agent_parts) != set(AGENT_PARTS):
        raise TrainerError(f"{run.path} took only the {' and '.join(cfg.run.init_agent_parts)} "
                           f"of {source}; the rest started fresh: iteration 0 has no agent to "
                           "load; pass --iteration 1 or later")
    init_agent_from(agent, Path(source))
    if cfg.run.init_agent_unseen == "silence":
        agent.silence_unseen_features()
