"""Evaluation of a trained policy: deterministic actions (the Gaussian's mean), a fixed number
of episodes per object, success counted per object (the paper's Table I), and rollout videos.
"""

from __future__ import annotations

import csv
import dataclasses
from pathlib import Path

import torch
from tensordict import TensorDictBase
from torchrl.envs.utils import ExplorationType, set_exploration_type, step_mdp

from geomprep.store import atomic_path
from trainer.env import GraspEnv
from trainer.errors import TrainerError
from trainer.objects import resolve_names
from trainer.ppo import RunDir, load_agent


@dataclasses.dataclass(frozen=True)
class EvalResult:
    """Per object (in the order of ``names``): episodes run and successes."""

    names: list[str]
    episodes: list[int]
    successes: list[int]

    @property
    def overall(self) -> float:
        return sum(self.successes) / max(1, sum(self.episodes))

    def rate(self, k: int) -> float:
        return self.successes[k] / max(1, self.episodes[k])


def run_episodes(
    env: GraspEnv, actor: torch.nn.Module, deterministic: bool = True, on_step=None  # noqa: ANN001
) -> tuple[torch.Tensor, torch.Tensor]:
    """One episode in every env from a fresh reset; returns (success (E,) bool, length (E,)).
    Envs that finish early keep stepping (nothing is reset) but their outcome is frozen."""
    E = env.num_envs
    success = torch.zeros(E, dtype=torch.bool)
    length = torch.zeros(E, dtype=torch.long)
    finished = torch.zeros(E, dtype=torch.bool)
    mode = ExplorationType.DETERMINISTIC if deterministic else ExplorationType.RANDOM
    td: TensorDictBase = env.reset()
    with torch.no_grad(), set_exploration_type(mode):
        for _ in range(env.cfg.max_steps):
            td = env.step(actor(td))
            if on_step is not None:
                on_step()
            done = td["next", "done"][:, 0].cpu() & ~finished
            success |= done & td["next", "success"][:, 0].cpu()
            length[~finished] += 1
            finished |= done
            if finished.all():
                break
            td = step_mdp(td)
    return success, length


def evaluate(
    run_dir: Path,
    episodes_per_object: int = 10,
    objects: str | None = None,
    seed: int = 12345,
    max_envs: int = 1024,
    device: str | None = None,
) -> EvalResult:
    """Evaluate the run's last checkpoint on its object set (or ``objects``), on ``device``
    (default: the run's); writes ``eval/per_object.csv`` and ``eval/table.md`` in the run
    directory."""
    if episodes_per_object < 1:
        raise TrainerError(f"episodes_per_object must be >= 1, got {episodes_per_object}")
    cfg, agent = load_agent(run_dir, device)
    names = resolve_names(objects or cfg.env.objects, cfg.env.data_dir)
    episodes = [0] * len(names)
    successes = [0] * len(names)
    # Objects in batches of envs: each batch runs episodes_per_object episodes of each object.
    per_batch = max(1, max_envs // episodes_per_object)
    for start in range(0, len(names), per_batch):
        chunk = names[start : start + per_batch]
        env_cfg = dataclasses.replace(
            cfg.env, objects=",".join(chunk), num_envs=episodes_per_object * len(chunk)
        )
        env = GraspEnv(env_cfg, seed=seed + start)
        success, _ = run_episodes(env, agent.actor)
        ids = env.env_object.cpu()
        for k in range(len(chunk)):
            episodes[start + k] += int((ids == k).sum())
            successes[start + k] += int(success[ids == k].sum())
        env.close()
    result = EvalResult(names, episodes, successes)
    write_eval(RunDir(Path(run_dir)), result, cfg.env.representation)
    return result


def write_eval(run: RunDir, result: EvalResult, representation: str) -> None:
    out = run.path / "eval"
    out.mkdir(parents=True, exist_ok=True)
    with atomic_path(out / "per_object.csv") as tmp, open(tmp, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["object", "episodes", "successes", "success_rate"])
        for k, name in enumerate(result.names):
            writer.writerow([name, result.episodes[k], result.successes[k], f"{result.rate(k):.4f}"])  # noqa: E501
    lines = [f"| object | {representation} |", "|---|---:|"]
    lines += [f"| {n} | {result.rate(k):.2f} |" for k, n in enumerate(result.names)]
    lines.append(f"| **all ({sum(result.episodes)} episodes)** | **{result.overall:.2f}** |")
    with atomic_path(out / "table.md") as tmp:
        tmp.write_text("\n".join(lines) + "\n")
