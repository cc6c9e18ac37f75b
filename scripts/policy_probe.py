"""What a trained policy does with its target over an episode: every N actions, averaged over
envs, the palm's height, the lowest fingertip pad's, how many pads are within 2 cm of the
target's surface, their summed distance to it, the target's centre rise and lowest-point rise,
the palm's horizontal distance to it, the policy's action std (mean over the 6 pose actions and
over the 5 hand actions: it varies only with ``[ppo] state_dependent_std``), and the hand's
servo targets. A policy that reaches,
rests or tips shows it here without a video (results/cpu-lift-clearance-2026-11-26/: the tuna
can held tipped 1.7 cm for 150 actions). Then what the episode earned, averaged over envs up to
each one's end: the reward's terms summed and the return discounted with each ``--gammas``
value, comparable with ``bench/reward_balance.py``'s scripted lift and rest (``--h-bar``: the
lift target to score against, e.g. the curriculum's 0.03 m; default the run's).

    python scripts/policy_probe.py RUN_DIR [--envs 32] [--every 10] [--sample] [--seed 7]
                                   [--h-bar M] [--gammas 0.99,0.998] [--grasp-starts]

``--grasp-starts``: every env whose scripted grasp (the run's ``grasp_start_family``, one trial
per env) lifted starts from one of its states (``[run] grasp_starts``), the others home; the
rows then average over those envs only, and the success line says how many there were.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch
from tensordict import TensorDictBase

from trainer.randomness import RandomStreams
from trainer.session import EvalSession
from trainer.tasks import GraspTask
from trainer.tasks.terms import reward_output_key, reward_terms
from trainer.training.grasp_starts import record_grasp_starts

COLUMNS = ("palm_z", "lowest_pad_z", "pads_near", "pad_distance", "centre_rise", "lowest_rise",
           "palm_xy_distance", "std_pose", "std_hand")


def probe(run_dir: Path, envs: int = 32, sample: bool = False, seed: int = 7,
          h_bar: float | None = None, gammas: tuple[float, ...] = (0.99, 0.998),
          grasp_starts: bool = False,
          ) -> tuple[list[dict[str, float | list[float]]], float, dict[str, float]]:
    """One episode in ``envs`` envs of the run's last checkpoint (deterministic unless
    ``sample``): per action, the mean of each of ``COLUMNS`` (m; ``pads_near`` a count; the stds
    in action units) and
    ``hand`` (the 5 servo targets, rad); the success rate; and the episode's earnings, means over
    envs up to each one's end: ``steps``, ``sum_<term>`` per reward term, ``return`` and
    ``G_<gamma>`` (discounted from the first action). ``h_bar``: the lift target (m) the
    reward and success use [the run's ``reward.h_bar``]. ``grasp_starts``: the envs start
    along their scripted grasps where one lifted, and everything is averaged over those envs
    (the earnings' ``envs`` says how many)."""
    session = EvalSession.load(run_dir, h_bar=h_bar)
    env = session.env(envs, seed, compile=False, quiet=True)
    env_cfg = env.cfg
    chosen = torch.ones(envs, dtype=torch.bool)
    if grasp_starts:
        starts = record_grasp_starts(env_cfg, RandomStreams(seed),
                                     session.cfg.run.grasp_start_family, rounds=1,
                                     phase=session.cfg.run.grasp_start_phase)
        env.set_grasp_starts(starts, 1.0, torch.Generator().manual_seed(seed))
        chosen = starts.valid.any(1).cpu()
    rows: list[dict[str, float | list[float]]] = []
    start_low: list[torch.Tensor] = []
    names = list(reward_terms(env_cfg.reward))
    alive = torch.ones(envs, dtype=torch.bool)
    earned: dict[str, list[torch.Tensor]] = {"reward": [], **{n: [] for n in names}}

    def on_reset(env: GraspTask, td: TensorDictBase) -> None:
        """Each target's lowest point right after the reset."""
        pos, quat = env.target_pose()
        start_low[:] = [env.lowest_point(pos, quat, env.target_objects())]

    def on_step(env: GraspTask, step: int, td: TensorDictBase) -> None:
        """Each env's reward and its terms until its episode's end, then the row of means."""
        nxt = td["next"]
        mask = (alive & chosen).to(torch.float32)
        earned["reward"].append(nxt["reward"][:, 0].cpu() * mask)
        for n in names:
            earned[n].append(nxt[reward_output_key(n)][:, 0].cpu() * mask)
        alive.mul_(~nxt["done"][:, 0].cpu())
        scale = td["scale"].cpu()  # the action std the policy would sample with
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
                  low - start_low[0], (palm[:, :2] - pos[:, :2]).norm(dim=-1),
                  scale[:, :6].mean(-1), scale[:, 6:].mean(-1))
        row: dict[str, float | list[float]] = {
            name: float(v[chosen].float().mean()) for name, v in zip(COLUMNS, values, strict=True)
        }
        row["hand"] = env.state["ctrl"][chosen][:, env.robot.hand.actuators].mean(0).tolist()
        rows.append(row)

    success, length, _ = session.run(env, deterministic=not sample, on_reset=on_reset,
                                     on_step=on_step)
    env.close()
    rewards = torch.stack(earned["reward"]).double()[:, chosen]  # (T, E chosen)
    returns = {"envs": float(chosen.sum()), "steps": float(length[chosen].float().mean()),
               "return": float(rewards.sum(0).mean())}
    returns.update({f"sum_{n}": float(torch.stack(earned[n])[:, chosen].sum(0).mean())
                    for n in names})
    weights = torch.arange(rewards.shape[0], dtype=torch.float64)
    returns.update({f"G_{g}": float((rewards * (g ** weights)[:, None]).sum(0).mean())
                    for g in gammas})
    return rows, float(success[chosen].float().mean()), returns


def main(argv: list[str] | None = None) -> list[str]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("run_dir", type=Path)
    parser.add_argument("--envs", type=int, default=32)
    parser.add_argument("--every", type=int, default=10)
    parser.add_argument("--sample", action="store_true")
    parser.add_argument("--seed", type=int, default=7)
    parser.add_argument("--h-bar", type=float, default=None)
    parser.add_argument("--gammas", default="0.99,0.998")
    parser.add_argument("--grasp-starts", action="store_true")
    args = parser.parse_args(argv)
    gammas = tuple(float(g) for g in args.gammas.split(","))
    rows, success, returns = probe(args.run_dir, args.envs, args.sample, args.seed,
                                   args.h_bar, gammas, args.grasp_starts)
    envs = (f"{returns['envs']:.0f} of {args.envs} envs from grasp starts"
            if args.grasp_starts else f"{args.envs} envs")
    lines = [f"success {success:.3f} ({envs}, "
             f"{'sampled' if args.sample else 'deterministic'} actions)",
             "action " + " ".join(COLUMNS) + " hand_targets"]
    for i in [*range(0, len(rows), args.every), len(rows) - 1]:
        row = rows[i]
        hand = " ".join(f"{x:.2f}" for x in row["hand"])  # type: ignore[union-attr]
        lines.append(f"{i} " + " ".join(f"{row[c]:.3f}" for c in COLUMNS) + f" [{hand}]")
    lines.append("earned (mean over envs, to each episode's end): "
                 + ", ".join(f"{k} {v:.1f}" for k, v in returns.items()))
    print("\n".join(lines))
    return lines


if __name__ == "__main__":
    main()
