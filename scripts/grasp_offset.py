"""Where a run's policy holds each object: the fingertip pads' centroid in the object's box frame
at the step each episode succeeds (lifted and held), over ``trainer eval``'s episodes.

A plate is held at its rim, 12-13 cm from its box centre; the question this answers is which
source agents hold their own objects away from the centre, too. Per object it prints the held
episodes, the median distance of the pads' centroid from the box centre (cm) and the median of
its largest coordinate as a fraction of the box's half extent along that axis (0: the centre,
1: a face of the box). Same seed, envs and deterministic policy as
``trainer eval RUN --episodes-per-object N``.

    python scripts/grasp_offset.py RUN_DIR [--episodes-per-object 50] [--iteration N]
                                   [--objects 072-a_toy_airplane]
"""

from __future__ import annotations

import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))  # eval_upright beside it


def box_frame_offset(
    tips: torch.Tensor, obj_pos: torch.Tensor, obj_quat: torch.Tensor,
    bbox_center: torch.Tensor, bbox_rotation: torch.Tensor, bbox_extents: torch.Tensor,
) -> tuple[torch.Tensor, torch.Tensor]:
    """The pads' centroid relative to each env's object box: (distance from the box centre (E,),
    m; largest |coordinate| / half extent along its axis (E,)). tips (E, 5, 3) world; obj_pos
    (E, 3), obj_quat (E, 4) wxyz; bbox_center (E, 3), bbox_rotation (E, 3, 3) (axes as columns)
    and bbox_extents (E, 3) in the object's frame."""
    from geomgrasp.rotations import quat_to_matrix

    rot = quat_to_matrix(obj_quat)  # (E, 3, 3)
    centre = obj_pos + (rot @ bbox_center[..., None])[..., 0]
    axes = rot @ bbox_rotation  # the box's axes in the world, as columns
    local = (axes.transpose(1, 2) @ (tips.mean(1) - centre)[..., None])[..., 0]
    return local.norm(dim=-1), (local.abs() / (bbox_extents / 2)).amax(dim=-1)


def grasp_offsets(
    run_dir: Path, episodes_per_object: int = 50, iteration: int | None = None,
    objects: str | None = None, seed: int = 12345,
) -> list[tuple[str, int, int, float, float]]:
    """Per object: (name, episodes, held, median distance (m), median fraction of the half
    extent); the medians are nan without a held episode."""
    from eval_upright import eval_env

    from trainer.evaluation import run_episodes

    names, env, agent = eval_env(run_dir, episodes_per_object, iteration, objects, seed)
    distance = torch.full((env.num_envs,), float("nan"))
    fraction = torch.full((env.num_envs,), float("nan"))

    def at_success(mask: torch.Tensor) -> None:  # the env in the state of the successful step
        ids = env.target_objects().cpu()
        tips = env.kinematics.forward(env.backend.qpos).site_pos[:, 1:].cpu()
        obj_pos, obj_quat = (x.cpu() for x in env.target_pose())
        o = env.objects
        d, f = box_frame_offset(tips, obj_pos, obj_quat, o.bbox_center.cpu()[ids],
                                o.bbox_rotation.cpu()[ids], o.bbox_extents.cpu()[ids])
        distance[mask], fraction[mask] = d[mask], f[mask]

    success, _, ids = run_episodes(env, agent.actor, True, at_success=at_success)
    env.close()
    rows = []
    for k, name in enumerate(names):
        held = (ids == k) & success
        rows.append((name, int((ids == k).sum()), int(held.sum()),
                     float(distance[held].nanmedian()) if held.any() else float("nan"),
                     float(fraction[held].nanmedian()) if held.any() else float("nan")))
    return rows


def main() -> None:
    from eval_upright import eval_arguments

    args = eval_arguments(__doc__.splitlines()[0])
    rows = grasp_offsets(args.run_dir, args.episodes_per_object, args.iteration, args.objects,
                         args.seed)
    print("| object | held / episodes | pads from the box centre (cm, median) "
          "| largest coordinate / half extent (median) |")
    print("|---|---:|---:|---:|")
    for name, episodes, held, dist, frac in rows:
        print(f"| {name} | {held}/{episodes} | {100 * dist:.1f} | {frac:.2f} |")


if __name__ == "__main__":
    main()
