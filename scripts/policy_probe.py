"""What a trained policy does with its target over an episode: every N actions, averaged over
envs, the palm's height, the lowest fingertip pad's, how many pads are within 2 cm of the
target's surface, their summed distance to it, the target's centre rise and lowest-point rise,
the palm's horizontal distance to it, and the hand's servo targets. A policy that reaches,
rests or tips shows it here without a video (results/cpu-lift-clearance-2026-11-26/: the tuna
can held tipped 1.7 cm for 150 actions).

    python scripts/policy_probe.py RUN_DIR [--envs 32] [--every 10] [--sample] [--seed 7]
"""

from __future__ import annotations

import argparse
import dataclasses
import warnings
from pathlib import Path

import torch

COLUMNS = ("palm_z", "lowest_pad_z", "pads_near", "pad_distance", "centre_rise", "lowest_rise",
           "palm_xy_distance")


def probe(run_dir: Path, envs: int = 32, sample: bool = False,
          seed: int = 7) -> tuple[list[dict[str, float | list[float]]], float]:
    """One episode in ``envs`` envs of the run's last checkpoint (deterministic unless
    ``sample``): per action, the mean of each of ``COLUMNS`` (m; ``pads_near`` a count) and
    ``hand`` (the 5 servo targets, rad); and the success rate."""
    from trainer.evaluation import run_episodes
    from trainer.tasks import make_env
    from trainer.training.checkpoint import load_agent

    cfg, agent = load_agent(run_dir)
    env_cfg = dataclasses.replace(cfg.env, num_envs=envs, compile=False)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        env = make_env(env_cfg, seed=seed)
    rows: list[dict[str, float | list[float]]] = []
    start_low: list[torch.Tensor] = []
    reset = env.reset

    def reset_and_note(*args, **kwargs):  # noqa: ANN002, ANN003, ANN202
        """The env's reset, noting each target's lowest point right after it."""
        out = reset(*args, **kwargs)
        pos, quat = env.target_pose()
        start_low[:] = [env.lowest_point(pos, quat, env.target_objects())]
        return out

    env.reset = reset_and_note

    def on_step() -> None:
        pos, quat = env.target_pose()
        ids = env.target_objects()
        low = env.lowest_point(pos, quat, ids)
        tips = env.kinematics.forward(env.backend.qpos).site_pos[:, 1:]  # (E, 5, 3)
        if env.objects.sdf is not None:
            distance = env.objects.sdf.query(tips, pos, quat, ids)
        else:
            distance = torch.full_like(tips[..., 0], float("nan"))
        palm = env.state["palm_pos"]
        values = (palm[:, 2], tips[..., 2].amin(-1), (distance < 0.02).sum(-1).float(),
                  distance.clamp_min(0).sum(-1), pos[:, 2] - env.state["start_height"],
                  low - start_low[0], (palm[:, :2] - pos[:, :2]).norm(dim=-1))
        row: dict[str, float | list[float]] = {
            name: float(v.float().mean()) for name, v in zip(COLUMNS, values, strict=True)
        }
        row["hand"] = env.state["ctrl"][:, env.robot.hand.actuators].mean(0).tolist()
        rows.append(row)

    success, _, _ = run_episodes(env, agent.actor, deterministic=not sample, on_step=on_step)
    env.close()
    return rows, float(success.float().mean())


def main(argv: list[str] | None = None) -> list[str]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("run_dir", type=Path)
    parser.add_argument("--envs", type=int, default=32)
    parser.add_argument("--every", type=int, default=10)
    parser.add_argument("--sample", action="store_true")
    parser.add_argument("--seed", type=int, default=7)
    args = parser.parse_args(argv)
    rows, success = probe(args.run_dir, args.envs, args.sample, args.seed)
    lines = [f"success {success:.3f} ({args.envs} envs, "
             f"{'sampled' if args.sample else 'deterministic'} actions)",
             "action " + " ".join(COLUMNS) + " hand_targets"]
    for i in [*range(0, len(rows), args.every), len(rows) - 1]:
        row = rows[i]
        hand = " ".join(f"{x:.2f}" for x in row["hand"])  # type: ignore[union-attr]
        lines.append(f"{i} " + " ".join(f"{row[c]:.3f}" for c in COLUMNS) + f" [{hand}]")
    print("\n".join(lines))
    return lines


if __name__ == "__main__":
    main()
