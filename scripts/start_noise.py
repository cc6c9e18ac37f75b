"""How much exploration noise a run's grasp starts survive: every env whose scripted grasp
lifted starts from one of its recorded states (the run's ``grasp_starts.pt``, ``[run]
grasp_starts``), and a fixed Gaussian policy acts from there for one episode: hand pose still for
``--hold`` actions, then the palm up at mean action ``--lift``, the five hand actions at mean
``--close`` (with relative hand actions, > 0 closes), each action plus noise of the given std.
Prints, per noise setting, how often the first episode succeeded (the run's curriculum start
target, ``reward.h_bar_start``, unless ``--h-bar``) and rose by 1 cm, and the ratio of its
success rate to the first setting's (give the noise-free one first: the baseline).

A PPO policy explores with exactly this kind of noise, so a grasp whose success falls to zero
under the untrained policy's std (``[ppo] init_log_std``) is one PPO sees succeed only by luck
(results/cpu-exploration-noise-2026-11-27/: the plate's rim pinch 0.24 -> 0.00 at std 0.61).

    python scripts/start_noise.py RUN_DIR [--sigma 0/0 --sigma 0.6/0.6 ...] [--hold 20]
                                  [--lift 0.5] [--close 0.3] [--hand-step RAD] [--seed 0]

A ``--sigma`` is ``POSE/HAND`` (one std for the 6 hand-pose actions, one for the 5 hand actions)
or 11 values ``a/b/.../k``; ``--hand-step`` overrides ``robot.hand_relative_step``.
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import torch
from tensordict import TensorDictBase

from trainer.config import ACTION_DIM
from trainer.randomness import RandomStreams
from trainer.session import EvalSession
from trainer.tasks import GraspTask
from trainer.tasks.starts import GraspStarts
from trainer.training.run_dir import RunDir

POSE_DIM = 6  # the hand-pose actions come first (trainer.robots.base), then the hand's
LIFT_ACTION = 2  # the hand pose's z (up) action


def parse_sigma(text: str) -> torch.Tensor:
    """``POSE/HAND`` or 11 stds separated by ``/`` -> (11,) stds."""
    try:
        values = [float(v) for v in text.split("/")]
    except ValueError:
        values = []
    if len(values) == 2:
        return torch.tensor([values[0]] * POSE_DIM + [values[1]] * (ACTION_DIM - POSE_DIM))
    if len(values) == ACTION_DIM and min(values) >= 0:
        return torch.tensor(values)
    raise SystemExit(f"--sigma {text}: write POSE/HAND (e.g. 0.6/0.6) or {ACTION_DIM} stds a/b/...")


def survive(run_dir: Path, sigmas: list[torch.Tensor], hold: int = 20, lift: float = 0.5,
            close: float = 0.3, hand_step: float | None = None, h_bar: float | None = None,
            seed: int = 0) -> tuple[int, list[dict[str, float]]]:
    """The number of envs with a grasp start, and per std in ``sigmas`` (each (11,)) the share
    of those envs whose first episode succeeded (``success``) and whose target rose by 1 cm at
    some point (``rose``), and per target object the share that succeeded (``success:NAME``),
    the same envs, starts and noise draws for every setting."""
    run = RunDir(run_dir)
    if not run.grasp_starts.exists():
        raise SystemExit(f"{run_dir} has no grasp_starts.pt: pass a run trained with "
                         "[run] grasp_starts > 0 (it records them when it starts)")
    session = EvalSession.load(run_dir, h_bar=h_bar, policy=False)
    cfg = session.cfg.env
    robot = cfg.robot if hand_step is None else dataclasses.replace(
        cfg.robot, hand_relative_step=hand_step)
    starts = GraspStarts.load(run.grasp_starts)
    names = session.names()
    rows = []
    for sigma in sigmas:
        env = session.env(cfg.num_envs, RandomStreams(seed), compile=False, robot=robot,
                          quiet=True)
        env.set_grasp_starts(starts, 1.0, torch.Generator().manual_seed(seed))
        policy = FixedGaussian(sigma, hold, lift, close, cfg.num_envs, seed + 1)
        success, _, target = session.run(env, actor=policy, **policy.hooks())
        env.close()
        chosen = policy.chosen
        row = {"success": float(success[chosen].float().mean()),
               "rose": float(policy.rose[chosen].float().mean())}
        for i, name in enumerate(names):
            mine = chosen & (target == i)
            if mine.any():
                row[f"success:{name}"] = float(success[mine].float().mean())
        rows.append(row)
    return int(chosen.sum()), rows


class FixedGaussian:
    """The fixed Gaussian policy of one noise setting (the actor of ``EvalSession.run``: hand
    pose still for ``hold`` actions, then the palm up at mean ``lift``, the hand at mean
    ``close``, each action plus noise of std ``sigma`` (11,) drawn from ``seed``), and what the
    first episodes did (its hooks): ``chosen`` (E,) the envs that start from a grasp, ``rose``
    (E,) those whose target rose by 1 cm before their episode ended."""

    def __init__(self, sigma: torch.Tensor, hold: int, lift: float, close: float, envs: int,
                 seed: int) -> None:
        self.sigma, self.hold, self.lift, self.close = sigma, hold, lift, close
        self.noise = torch.Generator().manual_seed(seed)
        self.actions = 0
        self.live = torch.ones(envs, dtype=torch.bool)
        self.rose = torch.zeros(envs, dtype=torch.bool)
        self.chosen = torch.zeros(envs, dtype=torch.bool)

    def __call__(self, td: TensorDictBase) -> TensorDictBase:
        action = torch.randn(td.shape[0], ACTION_DIM, generator=self.noise) * self.sigma
        action[:, POSE_DIM:] += self.close
        if self.actions >= self.hold:
            action[:, LIFT_ACTION] += self.lift
        td["action"] = action.clamp(-1.0, 1.0).to(td.device)
        self.actions += 1
        return td

    def hooks(self) -> dict[str, object]:
        return {"on_reset": self.on_reset, "on_step": self.on_step,
                "on_episode": self.on_episode}

    def on_reset(self, env: GraspTask, td: TensorDictBase) -> None:
        self.chosen[:] = td["grasp_start"][:, 0].cpu()

    def on_step(self, env: GraspTask, step: int, td: TensorDictBase) -> None:
        self.rose |= self.live & (td["next", "lift_height"][:, 0].cpu() >= 0.01)

    def on_episode(self, env: GraspTask, ended: torch.Tensor, success: torch.Tensor) -> None:
        self.live &= ~ended


def main(argv: list[str] | None = None) -> list[str]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("run_dir", type=Path)
    parser.add_argument("--sigma", action="append", default=None,
                        help="POSE/HAND stds (repeatable; the first is the baseline)")
    parser.add_argument("--hold", type=int, default=20)
    parser.add_argument("--lift", type=float, default=0.5)
    parser.add_argument("--close", type=float, default=0.3)
    parser.add_argument("--hand-step", type=float, default=None)
    parser.add_argument("--h-bar", type=float, default=None)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    texts = args.sigma or ["0/0", "0.6/0.6"]
    envs, rows = survive(args.run_dir, [parse_sigma(t) for t in texts], hold=args.hold,
                         lift=args.lift, close=args.close, hand_step=args.hand_step,
                         h_bar=args.h_bar, seed=args.seed)
    base = rows[0]["success"]
    lines = [f"{envs} envs from grasp starts; hold {args.hold} actions, then lift {args.lift:g}; "
             f"hand {args.close:+g}" + (f"; hand step {args.hand_step:g} rad"
                                        if args.hand_step is not None else ""),
             "sigma (pose/hand) | success | rose 1 cm | success / first"]
    for text, row in zip(texts, rows, strict=True):
        ratio = f"{row['success'] / base:.2f}" if base > 0 else "-"
        lines.append(f"{text} | {row['success']:.3f} | {row['rose']:.3f} | {ratio}")
    objects = [k.split(":", 1)[1] for k in rows[0] if k.startswith("success:")]
    if len(objects) > 1:
        lines.append("success per object: object | " + " | ".join(texts))
        lines += [f"{name} | " + " | ".join(f"{r[f'success:{name}']:.3f}" for r in rows)
                  for name in objects]
    print("\n".join(lines))
    return lines


if __name__ == "__main__":
    main()
