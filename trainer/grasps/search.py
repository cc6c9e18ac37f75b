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
are then re-scored on fresh trials; the best of those is the result.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import torch

from trainer.grasps.keyframes import DIM, PARAMS, KeyframeGrasp, index
from trainer.grasps.runner import record_grasp
from trainer.tasks import GraspTask

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
    """Lifts of the best candidate in its final trials."""
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
    most lifts is the result. ``on_iteration`` gets each iteration's history row."""
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
    return SearchResult(finalists[best], counts[best], each, history)
