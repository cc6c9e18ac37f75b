"""What the point-cloud encoder costs in a PPO iteration, and the exact fast pooling against the
plain one, same run.

    python bench/pointnet_update.py [--repr pc32,pc128,pc512] [--envs 256] [--repeats 5]
                                    [--threads 1] [--set ppo.pointnet_hidden=[16,32,64] ...]

For each point-cloud representation, one minibatch of the run's size (``trainer.ppo``'s rule:
1,024 frames at 256 envs) of random observations: PPO's clipped loss (TorchRL's
``ClipPPOLoss``, as the update calls it) and its backward (``update``); the policy and the
value without autograd (``no-grad``: collection and GAE's values, as ``trainer.ppo`` runs them
since 2026-11-30: with the shared encoder the value reads the policy's encoding). Three
variants:

- ``plain``: the per-point MLP over every point in one pass, then ``max(dim=-2)``;
- ``fast``: ``trainer.models.max_pooled_points`` (chunks that stay in cache; with more points
  than channels, the backward through each channel's argmax point only): equal in values and
  gradients (tests/test_ppo.py);
- ``fast + shared``: ``[ppo] shared_encoder``, one encoder for both networks, run once per
  minibatch: a different network, measured as an arm of its own.

Prints milliseconds per minibatch (median of ``--repeats``), the seconds of network work per
iteration they make (``epochs`` x minibatches updates; the no-grad passes of collection and
GAE) and the speed-up over ``plain``, same run.
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable

import torch
from tensordict import TensorDict
from torchrl.objectives import ClipPPOLoss

from trainer import models
from trainer.config import load_train_config
from trainer.config_keys import parse_sets
from trainer.models import Agent
from trainer.ppo import iteration_frames, minibatch_size
from trainer.tasks.spec import observation_spec


def plain_pooling(layers: torch.nn.Sequential, points: torch.Tensor) -> torch.Tensor:
    """The baseline: the per-point MLP over every point in one pass, then the max."""
    return layers(points).max(dim=-2).values


def median_ms(fn: Callable[[], None], repeats: int) -> float:
    fn()  # warm-up
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return 1000 * statistics.median(times)


def measure(agent: Agent, proprio: torch.Tensor, cloud: torch.Tensor, repeats: int) -> tuple[float, float]:  # noqa: E501
    """(update ms, no-grad ms): PPO's loss on one minibatch and its backward, as the update runs
    it; the policy and the value in reward units without autograd (collection and GAE)."""
    with torch.no_grad():
        data = agent.actor(TensorDict({"proprio": proprio, "object": cloud}, [len(proprio)]))
    data["advantage"] = torch.randn(len(proprio), 1)
    data["value_target"] = torch.randn(len(proprio), 1)
    data = data.exclude(Agent.ENCODED)
    loss = ClipPPOLoss(agent.actor, agent.critic, entropy_coeff=0.0)

    def update() -> None:
        agent.zero_grad(set_to_none=True)
        out = loss(data)
        (out["loss_objective"] + out["loss_critic"]).backward()

    def no_grad() -> None:
        with torch.no_grad():  # (as the rollout: the policy as it collects, then GAE's values)
            agent.state_values(agent.actor(data.select(*agent.obs_keys)))

    return median_ms(update, repeats), median_ms(no_grad, repeats)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repr", default="pc32,pc128,pc512")
    parser.add_argument("--envs", type=int, default=256)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--threads", type=int, default=1, help="torch threads")
    parser.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE",
                        help="a configuration key, e.g. ppo.pointnet_hidden=[16,32,64]")
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    sets = parse_sets(args.sets, training=True)
    print(f"{'repr':>6} {'variant':>14} {'update ms':>10} {'no-grad ms':>11} "
          f"{'s/iteration':>12} {'vs plain':>9}")
    variants = (("plain", plain_pooling, False), ("fast", models.max_pooled_points, False),
                ("fast + shared", models.max_pooled_points, True))
    for rep in args.repr.split(","):
        seconds = {}
        for name, pooling, shared in variants:
            cfg = load_train_config(env={"representation": rep, "num_envs": args.envs},
                                    sets={**sets, "ppo.shared_encoder": shared})
            spec = observation_spec(cfg.env, num_envs=args.envs)["observation"]
            torch.manual_seed(0)
            agent = Agent(spec, cfg.ppo)
            batch = minibatch_size(cfg)
            frames = iteration_frames(cfg)
            updates = cfg.ppo.epochs * -(-frames // batch)
            # A no-grad pass runs both networks on a minibatch: collection runs the policy on
            # the rollout, GAE the value on it (``trainer.ppo.rollout_values``: its next
            # observations only where an episode ended, a few percent, left out here).
            no_grad_passes = frames / batch
            proprio = torch.randn(batch, spec["proprio"].shape[-1])
            cloud = torch.randn(batch, *spec["object"].shape[1:])
            saved = models.max_pooled_points
            models.max_pooled_points = pooling
            try:
                up, ng = measure(agent, proprio, cloud, args.repeats)
            finally:
                models.max_pooled_points = saved
            seconds[name] = (updates * up + no_grad_passes * ng) / 1000
            print(f"{rep:>6} {name:>14} {up:>10.1f} {ng:>11.1f} {seconds[name]:>12.2f} "
                  f"{seconds['plain'] / seconds[name]:>8.2f}x", flush=True)
    print(f"s/iteration: {cfg.ppo.epochs} epochs x minibatches of {batch} frames (update) + "
          f"GAE and collection (no-grad) at {args.envs} envs x {cfg.ppo.frames_per_env} steps; "
          "vs plain: the speed-up over plain, same run.")


if __name__ == "__main__":
    main()
