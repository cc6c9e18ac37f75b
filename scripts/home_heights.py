"""Where ``[robot] home_above_objects`` starts the hand for each object: per object, in how many
settled initial states the hand at the base height touches it (turned to any of 16 yaws), and
the raised home heights' min / median / max (results/home-contact-2026-11-26/).

    python scripts/home_heights.py OBJECTS DATA_DIR [BASE_HEIGHT]
"""

from __future__ import annotations

import sys
import time
import warnings

import numpy as np


def main(argv: list[str]) -> list[str]:
    from trainer.config import load_env_config
    from trainer.tasks import make_env

    objects, data = argv[0], argv[1]
    base = float(argv[2]) if len(argv) > 2 else 0.14
    names = objects.split(",")
    cfg = load_env_config(num_envs=len(names), objects=objects, representation="bbox",
                          data_dir=data, nthread=1,
                          robot={"home_hand_height": base, "home_above_objects": True})
    start = time.time()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        env = make_env(cfg, seed=0)
    lines = [f"built in {time.time() - start:.1f} s",
             "object | touched at base | home height min / median / max (m)"]
    heights = env.home_height.numpy()
    for row, index in zip(env.layouts.tolist(), env.home_index.numpy(), strict=True):
        h = heights[index]
        lines.append(f"{env.objects.names[row[0]]} | {(index > 0).sum()} | "
                     f"{h.min():.2f} / {np.median(h):.2f} / {h.max():.2f}")
    env.close()
    return lines


if __name__ == "__main__":
    print("\n".join(main(sys.argv[1:])))
