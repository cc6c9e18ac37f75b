"""Tosses or holds? For the successes under the literal criterion (any rise by h_bar,
``[reward] hold_tips = 0``), how far are the hand's keypoints (palm, 5 fingertip pads) from the
target's surface (its SDF) at the step of success? (README.md here, "Tosses are not lifts".)

    python results/cpu-table1/held.py script                        # the scripted top grasp
    python results/cpu-table1/held.py runs/t1ns-bbox 053_mini_soccer_ball,013_apple 16
"""

import dataclasses
import sys
from pathlib import Path

import torch
from tensordict import TensorDict
from torchrl.envs.utils import ExplorationType, set_exploration_type, step_mdp

from trainer.config import EnvConfig, load_env_config
from trainer.ppo import load_agent
from trainer.scripted import ScriptedGrasp, scripted_action
from trainer.tasks import GraspTask, make_env

SCRIPTED = "077_rubiks_cube,013_apple,065-a_cups,073-g_lego_duplo,007_tuna_fish_can"


def literal(cfg: EnvConfig) -> EnvConfig:
    """``cfg`` with any rise by h_bar a success (what is measured here is whether it is held)."""
    return dataclasses.replace(cfg, reward=dataclasses.replace(cfg.reward, hold_tips=0))


def keypoint_distances(env: GraspTask) -> torch.Tensor:
    """(E, 6) distances (m, >= 0) of the palm keypoint and the 5 pads to the target's surface."""
    qpos = env.backend.qpos
    obj_pos, obj_quat = env.target_pose(qpos)
    sites = env.kinematics.forward(qpos).site_pos
    return env.objects.sdf.query(sites, obj_pos, obj_quat, env.target_objects()).clamp_min(0)


def summarize(name: str, rows: list[torch.Tensor]) -> None:
    if not rows:
        print(f"{name}: no successes")
        return
    tips = torch.stack(rows)[:, 1:]
    held = ((tips < 0.02).sum(1) >= 2).float().mean().item()
    nearest = tips.min(1).values.median().item()
    print(f"{name}: {len(rows)} successes, two or more pads within 2 cm: {held:.0%}, "
          f"nearest pad median {100 * nearest:.1f} cm")


def run(env: GraspTask, act, steps: int) -> list[torch.Tensor]:  # noqa: ANN001
    td, done, rows = env.reset(), torch.zeros(env.num_envs, dtype=torch.bool), []
    for step in range(steps):
        td = env.step(act(td, step))
        new = td["next", "success"][:, 0] & ~done
        rows += list(keypoint_distances(env)[new])
        done |= td["next", "done"][:, 0]
        td = step_mdp(td)
    return rows


if sys.argv[1] == "script":
    cfg = load_env_config(num_envs=100, objects=SCRIPTED, data_dir="data", representation="com")
    env, script, plan = make_env(literal(cfg), seed=0), ScriptedGrasp(), {}
    rows = run(env, lambda td, step: TensorDict(
        {"action": scripted_action(env, script, step, plan)}, batch_size=env.batch_size),
        script.total_steps)
    summarize("scripted top grasp", rows)
else:
    run_dir, objects, tries = Path(sys.argv[1]), sys.argv[2], int(sys.argv[3])
    train_cfg, agent = load_agent(run_dir, "cpu")
    base = dataclasses.replace(train_cfg.env, backend="cpu", device="cpu", data_dir=Path("data"))
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        for name in objects.split(","):
            env = make_env(literal(dataclasses.replace(base, objects=name, num_envs=tries)), 7)
            summarize(f"{run_dir} {name}", run(env, lambda td, step: agent.actor(td),
                                                base.max_steps))
            env.close()
