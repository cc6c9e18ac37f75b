"""The reward's balance, measured from rollouts: is resting the fingers on an object worth more
than lifting it? (issue 34, "Reward balance").

Two scripted policies per object, on the same initial states: *lift* (a grasp family's script,
by default the top grasp: approach, close, lift; the episode ends at the task's success, with
its one-off bonus c2) and *rest* (the same script with no lift, then holding the closed hand on
the object until the episode's ``max_steps``). ``--family NAME[:VARIANT]`` picks the script
from ``trainer.grasps.families.FAMILIES`` (e.g. ``pinch:press6``, the fingertip pinch that
lifts the flat objects); the variant's environment overrides apply. Per trial, the rewards
until its episode ends (success, the object off the table, or ``max_steps``), summed per term
and discounted with each ``--gammas`` value from the first action. Prints a table per object
and, as the ratio against the lift measured in the same run, the mean discounted return of rest
over lift: above 1 means PPO with that discount prefers resting to lifting.

    python bench/reward_balance.py --objects 077_rubiks_cube,013_apple --trials 10 \\
        [--family top] [--gammas 0.99,0.998] [--max-steps 300] [--data-dir data] [--config FILE] \\
        [--set KEY=VALUE ...] [--out FILE.csv]
"""

from __future__ import annotations

import argparse
import csv
import sys
from dataclasses import replace
from pathlib import Path

import torch
from tensordict import TensorDict

from geomgrasp.errors import UserError
from geomgrasp.files import atomic_path


def rollout_rewards(
    env, script,  # noqa: ANN001
) -> tuple[torch.Tensor, dict[str, torch.Tensor], torch.Tensor, torch.Tensor]:
    """Run ``script`` from a reset of every env; return (T, E) rewards with every step after an
    env's first done zeroed, the same for each reward term by name, (E,) bool lifted and (E,)
    the number of steps before the first done (inclusive)."""
    from trainer.tasks.terms import reward_output_key, reward_terms

    names = list(reward_terms(env.cfg.reward))
    env.reset()
    plan: dict = {}
    alive = torch.ones(env.num_envs, dtype=torch.bool)
    lifted = torch.zeros(env.num_envs, dtype=torch.bool)
    steps = torch.zeros(env.num_envs)
    rewards, terms = [], {n: [] for n in names}
    for step in range(script.total_steps):
        td = env.step(TensorDict({"action": script.action(env, step, plan)},
                                 batch_size=env.batch_size))["next"]
        mask = alive.to(torch.float32)
        steps += mask
        rewards.append(td["reward"][:, 0].cpu() * mask)
        for n in names:
            terms[n].append(td[reward_output_key(n)][:, 0].cpu() * mask)
        lifted |= td["success"][:, 0].cpu() & alive
        alive &= ~td["done"][:, 0].cpu()
    return torch.stack(rewards), {n: torch.stack(v) for n, v in terms.items()}, lifted, steps


def discounted(rewards: torch.Tensor, gamma: float) -> torch.Tensor:
    """(E,) the discounted return from the first step of (T, E) rewards."""
    weights = gamma ** torch.arange(rewards.shape[0], dtype=torch.float64)
    return (rewards.double() * weights[:, None]).sum(0)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--objects", default="077_rubiks_cube,013_apple,065-a_cups")
    parser.add_argument("--trials", type=int, default=10)
    parser.add_argument("--family", default="top",
                        help="grasp family[:variant] of trainer.grasps.families [top]")
    parser.add_argument("--gammas", default="0.99,0.998")
    parser.add_argument("--max-steps", type=int, default=300, help="episode length [300]")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--data-dir", type=Path, default=None)
    parser.add_argument("--config", type=Path, default=None)
    parser.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args(argv)
    try:
        run(args)
    except UserError as exc:
        print(f"error: {exc}", file=sys.stderr)
        sys.exit(1)


def run(args: argparse.Namespace) -> None:
    from trainer.config import dotted_overrides, load_env_config
    from trainer.config_keys import parse_sets
    from trainer.grasps.families import merge_overrides, variants
    from trainer.grasps.runner import script_config
    from trainer.objects import resolve_names
    from trainer.tasks import make_env

    gammas = [float(g) for g in args.gammas.split(",")]
    name, _, variant_name = args.family.partition(":")
    variant_name = variant_name or "base"
    variant = variants(name, [variant_name])[variant_name]
    lift = variant.script
    before_lift = lift.total_steps - lift.lift_steps - lift.hold_steps
    if before_lift >= args.max_steps:
        raise UserError(f"the {args.family} script closes only after {before_lift} actions; "
                        f"give --max-steps more than that")
    extra = merge_overrides(variant.env, dotted_overrides(parse_sets(args.sets)))
    if args.data_dir is not None:
        extra["data_dir"] = args.data_dir
    cfg = load_env_config(args.config, task="lift", context="none", representation="com",
                          max_steps=args.max_steps, **extra)
    cfg = script_config(cfg)  # the scripts' absolute hand actions; the reward is the same
    lift_end = lift.total_steps - lift.hold_steps
    if lift_end > args.max_steps:
        print(f"note: the {args.family} script lifts until action {lift_end}; episodes of "
              f"{args.max_steps} actions cut its lift short (give --max-steps {lift_end} or more "
              "to score the whole lift)", file=sys.stderr)
    names = resolve_names(args.objects, cfg.data_dir)
    cfg = replace(cfg, num_envs=args.trials * len(names), objects=",".join(names))
    rest = replace(lift, lift=0.0, lift_steps=0, hold_steps=args.max_steps - before_lift)
    results = {}
    for label, script in (("lift", lift), ("rest", rest)):
        env = make_env(cfg, seed=args.seed)  # the same initial states for both scripts
        try:
            rewards, terms, lifted, steps = rollout_rewards(env, script)
            ids = env.target_objects().cpu()
        finally:
            env.close()
        results[label] = (rewards, terms, lifted, steps, ids)
    rows = []
    rc = cfg.reward
    print(f"{args.family}; reward {rc.kind}: h_bar {rc.h_bar}, lift_clearance "
          f"{rc.lift_clearance}, c1 {rc.c1}, c2 {rc.c2}, c3 {rc.c3}, "
          f"eps_sdf {rc.eps_sdf}; episodes of {cfg.max_steps} actions, {args.trials} "
          "trials per object and script (the same initial states)")
    header = "| object | script | lifted | steps | " + " | ".join(
        f"sum {n}" for n in results["lift"][1]) + " | " + " | ".join(
        f"G(γ={g})" for g in gammas) + " |"
    print(header)
    print("|---|---|---:|---:|" + "---:|" * (len(results["lift"][1]) + len(gammas)))
    for k, name in enumerate(names):
        for label, (rewards, terms, lifted, steps, ids) in results.items():
            m = ids == k
            row = {"object": name, "script": label, "trials": int(m.sum()),
                   "lifted": int(lifted[m].sum()), "steps": round(steps[m].mean().item(), 1)}
            row.update({f"sum_{n}": round(v[:, m].sum(0).double().mean().item(), 1)
                        for n, v in terms.items()})
            row.update({f"return_{g}": round(discounted(rewards[:, m], g).mean().item(), 1)
                        for g in gammas})
            rows.append(row)
            print(f"| {name} | {label} | {row['lifted']}/{row['trials']} | {row['steps']} | "
                  + " | ".join(str(row[f"sum_{n}"]) for n in terms) + " | "
                  + " | ".join(str(row[f"return_{g}"]) for g in gammas) + " |")
    print("\nrest / lift, mean discounted return (the lift is the baseline, this run):")
    for name in names:
        lift_row, rest_row = (next(r for r in rows if r["object"] == name and r["script"] == s)
                              for s in ("lift", "rest"))
        ratios = ", ".join(
            f"γ {g}: {rest_row[f'return_{g}'] / lift_row[f'return_{g}']:.2f}x" for g in gammas)
        print(f"{name}: {ratios}")
    if args.out is not None:
        with atomic_path(args.out) as tmp, open(tmp, "w", newline="") as handle:
            writer = csv.DictWriter(handle, fieldnames=list(rows[0]))
            writer.writeheader()
            writer.writerows(rows)


if __name__ == "__main__":
    main()
