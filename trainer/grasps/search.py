"""A sampling search for a grasp where no hand-written family lifts an object: the
cross-entropy method (as MuJoCo MPC uses it) over the parameters of a keyframe grasp
(``keyframes.py``), each candidate scored on MuJoCo rollouts of the lift task from the task's
randomized initial states.

Each iteration draws ``population`` parameter vectors from a diagonal Gaussian (the current
mean is always one of them), runs each on ``trials`` envs at once (one batch of
``population * trials`` envs, fresh initial states every iteration, so a grasp that only works
from one pose scores low), and refits the Gaussian to the ``elite`` best. A trial scores 1 when
the target is lifted by h_bar and held (the task's success), plus up to 0.5 for its rise at the
end (partial credit that leads the search toward lifts). The parameters of the best candidates
are then re-scored on fresh trials; the best of those is the result, and its lift count is
taken once more on a batch of fresh trials (the count it won by would keep its luck).

Above the search: ``search_grasp`` runs it for one object of a config, ``make_entry`` turns its
result into what ``searched.py`` stores, and ``find_grasps`` gives each object of a list its
grasp for a config's hand and physics, searching and storing the ones nobody has searched
(``trainer grasp-search`` and the grasp starts of any object, ``trainer.training``).
"""

from __future__ import annotations

import dataclasses
import datetime
import json
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import torch

from trainer.config import EnvConfig
from trainer.grasps import searched
from trainer.grasps.keyframes import DIM, PARAMS, KeyframeGrasp, index, top_grasp_theta
from trainer.grasps.runner import episode_config, record_grasp
from trainer.tasks import GraspTask, make_env

INITIAL_STD = {
    "x": 0.03, "y": 0.03, "z": 0.02, "yaw": 0.3, "pitch": 0.3, "roll": 0.3,
    **{f"open{i}": 0.4 for i in range(5)}, **{f"closed{i}": 0.4 for i in range(5)},
    "drag_x": 0.02, "drag_y": 0.02, "drag_z": 0.01,
}
"""The search's initial standard deviation of each parameter (m, rad, action units)."""
MIN_STD = 0.05
"""Each parameter's std is kept >= this fraction of its initial std (the search keeps
exploring a little)."""
HAND = slice(index("open0"), index("closed4") + 1)


@dataclass
class SearchResult:
    """What a search found: the best parameters, their score on the final trials, and the
    history of every iteration."""

    theta: torch.Tensor
    """(D,) the best candidate's parameters."""
    lifted: int
    """Lifts of the best candidate in its final trials: a batch of fresh trials on every env,
    after the pick (so not the count it was picked by)."""
    final_trials: int
    history: list[dict] = field(default_factory=list)
    """Per iteration: ``iteration``, ``best`` and ``mean`` score, ``lift_rate`` (of all trials),
    ``elite_lift_rate``, ``seconds``."""

    def as_dict(self) -> dict[str, float]:
        """The parameters by name (``keyframes.PARAMS``), rounded to 4 decimals."""
        return {name: round(float(v), 4) for name, v in zip(PARAMS, self.theta, strict=True)}


def score(env: GraspTask, script: KeyframeGrasp) -> tuple[torch.Tensor, torch.Tensor]:
    """Run ``script`` once on every env (a reset first): (E,) score and (E,) bool lifted."""
    trajectory = record_grasp(env, script)
    z = trajectory.target_pos[..., 2]
    rise = (z[-1] - z[0]).clamp(0.0, 0.2) / 0.2
    return trajectory.lifted.float() + 0.5 * rise, trajectory.lifted


def cem(
    env: GraspTask, mean: torch.Tensor, population: int, trials: int, iterations: int,
    elite: int, seed: int = 0, final_candidates: int = 3, spread: float = 1.0,
    template: KeyframeGrasp | None = None, on_iteration: Callable[[dict], None] | None = None,
) -> SearchResult:
    """The cross-entropy search from ``mean`` (D,) on ``env`` (``population * trials`` envs,
    one target object; ``seed`` seeds the samples; ``spread`` scales ``INITIAL_STD``;
    ``template``: the keyframe grasp whose timing the candidates share). At the end the final
    mean and the ``final_candidates`` best-scored samples of all iterations are re-run side by
    side on fresh trials, ``env.num_envs // (final_candidates + 1)`` each; the one with the
    most lifts is the result, its ``lifted`` counted on one more batch of fresh trials (all
    ``env.num_envs`` envs). ``on_iteration`` gets each iteration's history row."""
    if env.num_envs != population * trials:
        raise ValueError(f"env has {env.num_envs} envs, the search needs {population * trials}")
    template = template or KeyframeGrasp()
    gen = torch.Generator().manual_seed(seed)
    std0 = spread * torch.tensor([INITIAL_STD[name] for name in PARAMS])
    std = std0.clone()
    mean = mean.clone().float()
    scored: list[tuple[float, torch.Tensor]] = []
    history = []
    for it in range(iterations):
        start = time.perf_counter()
        theta = mean + std * torch.randn(population, DIM, generator=gen)
        theta[0] = mean
        theta[:, HAND] = theta[:, HAND].clamp(-1.0, 1.0)
        per_env = theta.repeat_interleave(trials, 0)
        env_score, lifted = score(env, replace(template, theta=per_env))
        cand = env_score.view(population, trials).mean(1)
        order = cand.argsort(descending=True)
        elites = theta[order[:elite]]
        mean = elites.mean(0)
        std = elites.std(0).clamp_min(MIN_STD * std0)
        scored += [(float(cand[i]), theta[i].clone()) for i in order[:final_candidates]]
        row = {
            "iteration": it, "best": round(float(cand.max()), 3),
            "mean": round(float(cand.mean()), 3),
            "lift_rate": round(float(lifted.float().mean()), 3),
            "elite_lift_rate": round(float(lifted.view(population, trials)[order[:elite]]
                                           .float().mean()), 3),
            "seconds": round(time.perf_counter() - start, 1),
        }
        history.append(row)
        if on_iteration is not None:
            on_iteration(row)
    # Re-score the best candidates (and the final mean) on fresh trials, side by side.
    scored.sort(key=lambda s: -s[0])
    # (The mean of clamped elites needs no clamp of its own.)
    finalists = [mean] + [t for _, t in scored[:final_candidates]]
    each = env.num_envs // len(finalists)
    per_env = torch.cat([t.expand(each, DIM) for t in finalists]
                        + [finalists[0].expand(env.num_envs - each * len(finalists), DIM)])
    _, lifted = score(env, replace(template, theta=per_env))
    counts = [int(lifted[k * each:(k + 1) * each].sum()) for k in range(len(finalists))]
    best = max(range(len(finalists)), key=lambda k: counts[k])
    # The pick keeps its luck (the best of several counts overstates its grasp: the bowl's
    # 18/24 lifted 25/60 on fresh trials, results/graspability-all-2026-11-29/): count the
    # chosen grasp's lifts again, on every env, on trials the pick did not see.
    _, lifted = score(env, replace(template, theta=finalists[best].expand(env.num_envs, DIM)))
    return SearchResult(finalists[best], int(lifted.sum()), env.num_envs, history)


@dataclass(frozen=True)
class SearchSettings:
    """How hard one object's search looks (``trainer grasp-search``'s options, its defaults
    here): about 2-3 minutes of one core per object with these."""

    population: int = 24
    """Candidates per iteration."""
    trials: int = 4
    """Randomized trials per candidate (envs: ``population * trials``)."""
    iterations: int = 6
    elite: int = 5
    """The best candidates the Gaussian is refitted to."""
    seed: int = 0
    """Seeds the samples and the env's initial states."""
    spread: float = 1.0
    """Scales ``INITIAL_STD``."""

    def describe(self) -> str:
        """The search's size in words, with its cost where it is the default's."""
        cost = ", about 2-3 minutes of one core" if self == SearchSettings() else ""
        return (f"{self.population} candidates x {self.trials} trials, {self.iterations} "
                f"iterations{cost}")


def search_config(cfg: EnvConfig, name: str, settings: SearchSettings) -> EnvConfig:
    """The env a search for object ``name`` runs on: ``cfg``'s hand, physics and reward on the
    lift task with that object alone, ``population * trials`` envs, absolute hand actions and
    episodes as long as the script (``runner.episode_config``)."""
    # The lift task whatever cfg's: a bin of one object kind, or its context, would not build,
    # and the score is the lift task's success.
    lift = replace(cfg, task="lift", context="none", representation="com",
                   num_envs=settings.population * settings.trials, objects=name)
    return episode_config(lift, KeyframeGrasp())


def search_grasp(
    cfg: EnvConfig, name: str, settings: SearchSettings = SearchSettings(),
    start: torch.Tensor | None = None, on_iteration: Callable[[dict], None] | None = None,
) -> SearchResult:
    """The cross-entropy search (``cem``) of a grasp for object ``name`` with the hand and
    physics of ``cfg``, from ``start`` (D,) (default: the top grasp's parameters), on the env
    of ``search_config``, closed after."""
    env = make_env(search_config(cfg, name, settings), seed=settings.seed)
    try:
        return cem(env, top_grasp_theta() if start is None else start, settings.population,
                   settings.trials, settings.iterations, settings.elite, settings.seed,
                   spread=settings.spread, on_iteration=on_iteration)
    finally:
        env.close()


PER_HAND = ("config", "hand_and_physics")
"""What a data-directory entry (one per hand and physics) has beyond a file entry (whose
objects share the file's one ``config``)."""


def make_entry(
    cfg: EnvConfig, result: SearchResult, settings: SearchSettings, config: dict[str, Any],
    refine: bool = False, earlier: Sequence[dict[str, Any]] = (),
) -> dict[str, Any]:
    """The stored form of ``result`` (``searched.py``): its parameters and lifts, the search's
    settings and date, its history, the searches it continued (``earlier``, oldest first), the
    configuration it was searched with as written (``config``: ``load_env_config`` overrides)
    and ``cfg``'s hand and physics (``searched.hand_and_physics``)."""
    return {
        "theta": result.as_dict(), "lifted": result.lifted, "final_trials": result.final_trials,
        "search": {**dataclasses.asdict(settings), "refine": refine,
                   "date": datetime.date.today().isoformat()},
        "history": result.history,
        **({"earlier": list(earlier)} if earlier else {}),
        "config": config,
        "hand_and_physics": searched.hand_and_physics(cfg),
    }


def written_config(cfg: EnvConfig) -> dict[str, Any]:
    """``cfg``'s settings that differ from the defaults, as a config file would write them
    (sections as dicts; not the objects, env count or data directory): the ``config`` of an
    entry searched for a config that is not a file."""
    default = dataclasses.asdict(EnvConfig(task=cfg.task))
    out: dict[str, Any] = {}
    for key, value in dataclasses.asdict(cfg).items():
        if key in ("objects", "num_envs", "data_dir"):
            continue
        if isinstance(value, dict):
            changed = {k: v for k, v in value.items() if v != default[key][k]}
            if changed:
                out[key] = changed
        elif value != default[key]:
            out[key] = value
    return json.loads(json.dumps(out, default=str))


def find_grasps(
    cfg: EnvConfig, names: Sequence[str], settings: SearchSettings = SearchSettings(),
    echo: Callable[[str], None] = print,
) -> dict[str, dict[str, Any]]:
    """Object name -> its grasp for ``cfg``'s hand and physics, for each of ``names``: the data
    directory's, else the shipped seed's (``searched.grasp_for``), else searched now
    (``search_grasp`` with ``settings``, ``echo`` saying so before and after) and stored in the
    data directory (``searched.write_entry``), where every later run, ``trainer demo`` and
    ``trainer grasp`` find it."""
    found = {}
    for name in names:
        entry = searched.grasp_for(cfg, name)
        if entry is None:
            echo(f"no grasp for {name} with this hand and physics: searching "
                 f"({settings.describe()})")
            result = search_grasp(cfg, name, settings)
            config = written_config(search_config(cfg, name, settings))
            entry = make_entry(cfg, result, settings, config)
            path = searched.write_entry(cfg.data_dir, name, searched.hand_key(cfg), entry)
            echo(f"{name}: the grasp found lifted {result.lifted} of {result.final_trials} "
                 f"final trials; stored in {path}")
        found[name] = entry
    return found
