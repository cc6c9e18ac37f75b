"""Success per object of a lift run's policy with *sampled* actions (as in training), where
``trainer eval`` uses the Gaussian's mean: does sampling rescue the objects the mean fails?

    python results/gpu-h100-table1/sampled_eval.py RUN_DIR EPISODES_PER_OBJECT
"""

import dataclasses
import sys

from trainer.evaluation import run_episodes
from trainer.objects import resolve_names
from trainer.ppo import load_agent
from trainer.tasks import make_env

run, per_object = sys.argv[1], int(sys.argv[2])
cfg, agent = load_agent(run, None)
names = resolve_names(cfg.env.objects, cfg.env.data_dir)
env = make_env(dataclasses.replace(cfg.env, num_envs=per_object * len(names)), seed=12345)
success, length, ids = run_episodes(env, agent.actor, deterministic=False)
for k, name in enumerate(names):
    mine = ids == k
    lifted, episodes = int(success[mine].sum()), int(mine.sum())
    print(f"{name:22s}{lifted:3d}/{episodes}  mean length {float(length[mine].float().mean()):.0f}")
print(f"overall {float(success.float().mean()):.3f}")
