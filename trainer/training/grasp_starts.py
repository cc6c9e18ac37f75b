"""Training episodes that start from a scripted grasp (``[run] grasp_starts``; not the paper's).

Why: on the CPU the objects that are not learned alone (the tuna can, the plate, the knife, a
dice seed) all end with the hand resting on or beside the object, thumb open, nothing lifted
(results/cpu-tuna-plate-2026-11-26/): the per-step contact term pays that rest, and a lift lies
past a closing of the hand that the policy never tries. A scripted grasp lifts every Table I
object (``trainer.grasps.families.BEST``). Starting a fraction of the training episodes from
states along such a grasp, up to the hand closed around the object, lets PPO meet the lift's
bonus from where it is a few actions away, and value the states before it (a reverse
curriculum from one demonstration per env). Evaluation never starts there; the episodes that
did are left out of every training success rate and of the lift curriculum.

Recording: the run's own task (its config, its ``num_envs``; only ``max_steps`` long enough for
the script), reset ``rounds`` times from the run's ``grasp_starts`` random stream, runs each
object's best family (on its target, in the bin); every ``stride`` actions up to the end of the
script's closing the state of each env is kept, and of those only the envs whose trial then
lifted its object. An env of the training task restarts from one of its own index's states
(the same object and layout).

Any object: the family "best" runs each object's hand-written best family (``BEST``) where it
has one, else its searched grasp for the run's hand and physics (``search.find_grasps``: the
data directory's or the shipped one, else searched now, a few minutes per object, and stored
for every later run). What a recording depends on is summed up in a key (``starts_key``); the
starts of a key are kept in the data directory (``cached_starts_path``), so that a run with
the same configuration and seed loads them instead of recording them again (``ppo``).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import torch
from tensordict import TensorDict

from trainer.config import EnvConfig, TrainConfig, without_neutral
from trainer.grasps.families import BEST, best_variants, variants
from trainer.grasps.keyframes import KeyframeGrasp
from trainer.grasps.runner import episode_config, run_scripted_grasp
from trainer.grasps.search import SearchSettings, find_grasps
from trainer.objects import task_names
from trainer.randomness import RandomStreams
from trainer.tasks import make_env
from trainer.tasks.starts import TASK_STATE_KEYS, GraspStarts

STARTS_FORMAT = 1
"""The version of what the recorder does; raised when a change to it changes the states it
records from the same inputs, so that no cached recording of the older code is loaded."""
STARTS_STORE = Path("grasps") / "starts"
"""The folder of the cached recordings in a data directory (one ``<key>.pt`` per key)."""
STRIDE = 10
"""Actions between two kept states of a scripted grasp."""
UNRECORDED_FIELDS = ("representation", "context", "observe_fingertips", "observe_hand_targets",
                     "reward.kind", "reward.contact_shaping")
"""Env fields (dotted below ``env``) a recording does not depend on, left out of its key: what
the policy observes and which shaping term the reward sums. The script's actions, the physics,
the resets and the success test (its lift curriculum, hold test and clearance) read none of
them, so runs of one seed that differ only there share one recording (the comparison's seven
arms of seed 0 had recorded seven identical files, results/cpu-comparison-2026-11-29/)."""


def object_grasps(
    cfg: EnvConfig, family_name: str = "best", search: SearchSettings | None = None,
    echo: Callable[[str], None] = print,
) -> dict[str, dict[str, Any]]:
    """Object name -> the grasp the recorder runs on it with ``family_name`` (``family``:
    ``FAMILY[:VARIANT]``, with "best" each object's ``BEST`` entry, else "searched"), for every
    object of ``cfg``; a searched grasp's ``theta`` too (the parameters the family runs for
    ``cfg``'s hand and physics), found or searched now and stored (``find_grasps`` with
    ``search``, default ``SearchSettings()``; ``echo`` says what it searches)."""
    names = task_names(cfg)
    specs = {n: BEST.get(n, "searched") if family_name == "best" else family_name
             for n in names}
    keyframed = [n for n, spec in specs.items() if spec.partition(":")[0] == "searched"]
    found = find_grasps(cfg, keyframed, search or SearchSettings(), echo)
    return {n: {"family": spec, **({"theta": found[n]["theta"]} if n in found else {})}
            for n, spec in specs.items()}


def starts_key(cfg: TrainConfig, grasps: dict[str, dict[str, Any]]) -> str:
    """A short hash of what a run's recorded grasp starts depend on: the recorder's version,
    the env config (not where its data directory is, nor fields at a neutral default, nor the
    ``UNRECORDED_FIELDS``), the run's seed and streams, the ``grasp_start_*`` settings and each
    object's grasp (``object_grasps``)."""
    env = without_neutral({k: v for k, v in dataclasses.asdict(cfg.env).items()
                           if k != "data_dir"})
    for dotted in UNRECORDED_FIELDS:
        section, _, name = dotted.rpartition(".")
        (env[section] if section else env).pop(name, None)
    payload = {
        "format": STARTS_FORMAT, "stride": STRIDE, "env": env, "seed": cfg.run.seed,
        "random_streams": cfg.run.random_streams, "family": cfg.run.grasp_start_family,
        "rounds": cfg.run.grasp_start_rounds, "phase": cfg.run.grasp_start_phase,
        "grasps": grasps,
    }
    text = json.dumps(payload, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def cached_starts_path(cfg: TrainConfig, grasps: dict[str, dict[str, Any]]) -> Path:
    """``DATA_DIR/grasps/starts/<starts_key>.pt``: where the starts of a run of ``cfg`` whose
    objects get ``grasps`` are kept for the next run of the same key."""
    return Path(cfg.env.data_dir) / STARTS_STORE / f"{starts_key(cfg, grasps)}.pt"


def record_grasp_starts(
    cfg: EnvConfig, streams: RandomStreams, family_name: str = "best", rounds: int = 2,
    stride: int = STRIDE, phase: str = "approach",
    on_progress: Callable[[int, int], None] | None = None,
    search: SearchSettings | None = None, echo: Callable[[str], None] = print,
) -> GraspStarts:
    """Run each object's best scripted grasp (``family_name`` "best": its ``BEST`` family, or
    for an object without one its searched grasp, searched now with ``search`` where nobody
    has (``object_grasps``, ``echo`` saying so); or one ``FAMILY[:VARIANT]`` for every
    object) ``rounds`` times on every env of the task built
    from ``cfg`` (``max_steps`` raised for the script; its resets drawn from the
    ``grasp_starts`` stream of ``streams``; in the bin the script grasps each episode's target
    in its clutter, and a start restores every object of the bin and the target slot) and keep
    the states along it (every ``stride`` actions: from the first ``stride`` actions to the end
    of the closing with ``phase`` "approach", the closing window with "closing", from the start
    of the closing to the end of the script, its lift included, with "lift") of the trials that
    lifted. The script runs in this task's physics (with absolute hand actions, whatever
    ``robot.hand_action``): a family's own ``load_env_config`` overrides (``Variant.env``) are
    not applied. ``on_progress(done, total)`` is called after every scripted action with the
    actions run so far and in all."""
    names = task_names(cfg)
    grasps = object_grasps(cfg, family_name, search, echo)
    if family_name == "best":
        families = [(v.script, objs) for v, objs in best_variants(
            names, searched=[n for n in names if "theta" in grasps[n]]).values()]
    else:
        name, _, variant_name = family_name.partition(":")
        variant = variants(name, [variant_name or "base"])[variant_name or "base"]
        families = [(variant.script, names)]
    parts = []
    total, done = rounds * sum(script.total_steps for script, _ in families), 0
    for script, family_objects in families:
        if isinstance(script, KeyframeGrasp):
            # The envs of the objects another family serves run it too (their trials are
            # discarded): a searched grasp needs a row for each object of the task.
            script = script.covering(names)
        # (episode_config: absolute hand actions, whatever the run's mode)
        env = make_env(episode_config(cfg, script), seed=streams)
        env.use_reset_generator(streams.torch("grasp_starts", env.device))
        wanted = torch.tensor([names.index(n) for n in family_objects], device=env.device)
        mine = torch.isin(env.target_objects(), wanted)  # (E,) the envs this family serves
        first = stride if phase == "approach" else script.close_window[0]
        last = script.total_steps if phase == "lift" else script.close_window[1]
        steps = sorted({*range(first, last, stride), last})
        keys = [k for k in TASK_STATE_KEYS if k in env.state.keys()]  # noqa: SIM118
        captures, lifted = [], []
        for _ in range(rounds):
            states: list[tuple[torch.Tensor, torch.Tensor, TensorDict, torch.Tensor]] = []

            def capture(step: int, env=env, steps=steps, states=states, keys=keys) -> None:
                nonlocal done
                done += 1
                if on_progress is not None:
                    on_progress(done, total)
                # on_step(step) runs after action `step`: the state after step + 1 actions.
                if step + 1 in steps:
                    states.append((env.backend.qpos.clone(), env.backend.qvel.clone(),
                                   env.state.select(*keys).clone(), env.lift_height()))

            ok = run_scripted_grasp(env, script, on_step=capture)
            captures.append(states)
            lifted.append(ok & mine)
        env.close()
        parts.append(_stack(mine, captures, torch.stack(lifted, 1)))
    return _merge(parts)


def _stack(mine: torch.Tensor, captures: list, lifted: torch.Tensor) -> GraspStarts:
    """One family's captures ``captures[round][capture] = (qpos, qvel, task state)`` as a
    ``GraspStarts`` over every env, valid only on the envs it serves (``mine`` (E,)) whose
    round lifted (``lifted`` (E, R)); ``captures[round][capture][3]`` (E,) is the target's
    lift."""
    def field(i: int) -> torch.Tensor:  # (E, R, C, ...): item i of every capture
        return torch.stack([torch.stack([c[i] for c in states], 1) for states in captures], 1)

    q, v, t, lift = (field(i) for i in range(4))
    E, R, C = q.shape[:3]
    valid = (lifted & mine[:, None])[:, :, None].expand(E, R, C).reshape(E, R * C)
    return GraspStarts(q.reshape(E, R * C, -1), v.reshape(E, R * C, -1), t.reshape(E, R * C),
                       valid, lifted, lift.reshape(E, R * C))


def _merge(parts: list[GraspStarts]) -> GraspStarts:
    """The families' ``GraspStarts`` as one: each env takes the captures of the family that
    serves it (the only one valid there); families with fewer captures are padded with invalid
    copies of their last."""
    S = max(p.qpos.shape[1] for p in parts)

    def pad(x: torch.Tensor) -> torch.Tensor:
        extra = S - x.shape[1]
        return x if extra == 0 else torch.cat([x, x[:, -1:].expand(-1, extra, *x.shape[2:])], 1)

    out = None
    for p in parts:
        valid = torch.cat([p.valid, p.valid.new_zeros(p.valid.shape[0], S - p.valid.shape[1])], 1)
        task = p.task if p.task.shape[1] == S else torch.cat(
            [p.task, p.task[:, -1:].expand(p.task.shape[0], S - p.task.shape[1])], 1)
        assert p.lift is not None  # (recorded here, always kept)
        padded = GraspStarts(pad(p.qpos), pad(p.qvel), task, valid, p.lifted, pad(p.lift))
        if out is None:
            out = GraspStarts(padded.qpos.clone(), padded.qvel.clone(), padded.task.clone(),
                              padded.valid.clone(), padded.lifted.clone(), padded.lift.clone())
            continue
        serves = padded.valid.any(1)  # (a family's captures are valid only where it serves)
        out.qpos[serves], out.qvel[serves] = padded.qpos[serves], padded.qvel[serves]
        out.task[serves] = padded.task[serves]
        out.valid[serves], out.lifted[serves] = padded.valid[serves], padded.lifted[serves]
        assert out.lift is not None and padded.lift is not None
        out.lift[serves] = padded.lift[serves]
    assert out is not None
    return out
