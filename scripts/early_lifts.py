"""What the untrained policy's low "lifts" are: run a task's initial policy (the home posture as
mean, Gaussian noise of std 0.6, as a run starts) with a low lift target and report, for each
held success, how far the target turned and rose from its reset pose. A lift tilts little; a
tipped object turns a lot and barely rises (results/cpu-perobject-2026-11-26/, the airplane).

    python scripts/early_lifts.py OBJECT DATA_DIR [--envs 256] [--steps 150] [--h-bar 0.03]
        [--lift-clearance 0.01]

``--lift-clearance`` counts a success only once the object's lowest point has also risen that
far (``[reward] lift_clearance``): what that leaves of the untrained policy's "lifts".
"""

from __future__ import annotations

import argparse
import warnings

import torch

from geomgrasp.rotations import matrix_to_axis_angle, quat_to_matrix

HOME_ACTION = (0.0,) * 6 + (1.0, -1.0, -1.0, -1.0, -1.0)  # configs/cpu.toml's init_action_mean
STD = 0.6


def tilt_degrees(before: torch.Tensor, after: torch.Tensor) -> torch.Tensor:
    """(n,) angle (degrees) between orientations ``before`` and ``after`` (n, 4) (w, x, y, z)."""
    relative = quat_to_matrix(before).transpose(-1, -2) @ quat_to_matrix(after)
    return torch.rad2deg(matrix_to_axis_angle(relative).norm(dim=-1))


def early_lifts(obj: str, data_dir: str, envs: int, steps: int, h_bar: float,
                seed: int = 0, lift_clearance: float = 0.0) -> list[tuple[int, float, float]]:
    """(step, tilt (deg), rise (m)) of each episode's first held success."""
    from tensordict import TensorDict

    from trainer.config import load_env_config
    from trainer.tasks import make_env

    cfg = load_env_config(num_envs=envs, objects=obj, representation="bbox", data_dir=data_dir,
                          nthread=1, max_steps=steps,
                          robot={"home_hand_height": 0.14, "home_above_objects": True},
                          reward={"lift_clearance": lift_clearance})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        env = make_env(cfg, seed=seed)
    env.set_lift_target(h_bar)
    generator = torch.Generator().manual_seed(seed)
    mean = torch.tensor(HOME_ACTION)
    env.reset()
    pos0, quat0 = (x.clone() for x in env.target_pose())
    events = []
    for step in range(steps):
        action = (mean + STD * torch.randn(envs, 11, generator=generator)).clamp(-1, 1)
        td = env.step(TensorDict({"action": action}, batch_size=[envs]))
        pos, quat = env.target_pose()
        success = td["next", "success"][:, 0]
        if success.any():
            tilt = tilt_degrees(quat0[success], quat[success])
            rise = pos[success, 2] - pos0[success, 2]
            events += [(step, float(t), float(r)) for t, r in zip(tilt, rise, strict=True)]
        done = td["next", "done"][:, 0]
        if done.any():  # a success ends the episode: restart those envs, note their new pose
            env.reset(TensorDict({"_reset": done[:, None]}, batch_size=[envs]))
            pos, quat = env.target_pose()
            pos0[done], quat0[done] = pos[done], quat[done]
    env.close()
    return events


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("object")
    parser.add_argument("data_dir")
    parser.add_argument("--envs", type=int, default=256)
    parser.add_argument("--steps", type=int, default=150)
    parser.add_argument("--h-bar", type=float, default=0.03)
    parser.add_argument("--lift-clearance", type=float, default=0.0)
    args = parser.parse_args(argv)
    events = early_lifts(args.object, args.data_dir, args.envs, args.steps, args.h_bar,
                         lift_clearance=args.lift_clearance)
    print(f"held successes at {args.h_bar} m (lift_clearance {args.lift_clearance:g} m) in "
          f"{args.steps} steps x {args.envs} envs: "
          f"{len(events)}")
    if events:
        tilts = sorted(e[1] for e in events)
        rises = sorted(e[2] for e in events)
        print(f"tilt (deg) min {tilts[0]:.0f} median {tilts[len(tilts) // 2]:.0f} max "
              f"{tilts[-1]:.0f}; over 20 deg: {sum(t > 20 for t in tilts)}; rise (m) median "
              f"{rises[len(rises) // 2]:.3f} max {rises[-1]:.3f}")


if __name__ == "__main__":
    main()
