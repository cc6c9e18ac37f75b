import sys, time
import numpy as np
from trainer.config import load_env_config
from trainer.tasks import make_env
T = "029_plate,032_knife,062_dice,072-a_toy_airplane,073-g_lego_duplo,007_tuna_fish_can,013_apple,053_mini_soccer_ball,065-a_cups,077_rubiks_cube"
objs = sys.argv[1] if len(sys.argv) > 1 and sys.argv[1] != "-" else T
data = sys.argv[2] if len(sys.argv) > 2 else "data"
base = float(sys.argv[3]) if len(sys.argv) > 3 else 0.14
cfg = load_env_config(num_envs=len(objs.split(",")), objects=objs, representation="bbox", data_dir=data, nthread=1,
                      robot={"home_hand_height": base, "home_above_objects": True})
t = time.time()
env = make_env(cfg, seed=0)
print(f"built in {time.time()-t:.1f} s")
h = env.home_height.numpy()
print("object | touched at base | home height min / median / max (m)")
for row, idx in zip(env.layouts.tolist(), env.home_index.numpy()):
    hh = h[idx]
    print(f"{env.objects.names[row[0]]} | {(idx > 0).sum()} | {hh.min():.2f} / {np.median(hh):.2f} / {hh.max():.2f}")
