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

from pathlib import Path

import torch
from tensordict import TensorDictBase

from geomgrasp.rotations import quat_to_matrix
from trainer.session import EVAL_SEED, EvalSession, eval_parser
from trainer.tasks import GraspTask


def box_frame_offset(
    tips: torch.Tensor, obj_pos: torch.Tensor, obj_quat: torch.Tensor,
    bbox_center: torch.Tensor, bbox_rotation: torch.Tensor, bbox_extents: torch.Tensor,
) -> tuple[torch.Tensor, torch.Tensor]:
    """The pads' centroid relative to each env's object box: (distance from the box centre (E,),
    m; largest |coordinate| / half extent along its axis (E,)). tips (E, 5, 3) world; obj_pos
    (E, 3), obj_quat (E, 4) wxyz; bbox_center (E, 3), bbox_rotation (E, 3, 3) (axes as columns)
    and bbox_extents (E, 3) in the object's frame."""
    rot = quat_to_matrix(obj_quat)  # (E, 3, 3)
    centre = obj_pos + (rot @ bbox_center[..., None])[..., 0]
    axes = rot @ bbox_rotation  # the box's axes in the world, as columns
    local = (axes.transpose(1, 2) @ (tips.mean(1) - centre)[..., None])[..., 0]
    return local.norm(dim=-1), (local.abs() / (bbox_extents / 2)).amax(dim=-1)


def grasp_offsets(
    run_dir: Path, episodes_per_object: int = 50, iteration: int | None = None,
    objects: str | None = None, seed: int = EVAL_SEED,
) -> list[tuple[str, int, int, float, float]]:
    """Per object: (name, episodes, held, median distance (m), median fraction of the half
    extent); the medians are nan without a held episode."""
    session = EvalSession.load(run_dir, "cpu", iteration)
    names = session.names(objects)
    distances: list[torch.Tensor] = []  # per batch of envs, (E,) at each env's success
    fractions: list[torch.Tensor] = []

    def on_reset(env: GraspTask, td: TensorDictBase) -> None:
        distances.append(torch.full((env.num_envs,), float("nan")))
        fractions.append(torch.full((env.num_envs,), float("nan")))

    def on_episode(env: GraspTask, ended: torch.Tensor, mask: torch.Tensor) -> None:
        if not bool(mask.any()):  # the env in the state of the step some episodes succeeded
            return
        ids = env.target_objects().cpu()
        tips = env.kinematics.forward(env.backend.qpos).site_pos[:, 1:].cpu()
        obj_pos, obj_quat = (x.cpu() for x in env.target_pose())
        o = env.objects
        d, f = box_frame_offset(tips, obj_pos, obj_quat, o.bbox_center.cpu()[ids],
                                o.bbox_rotation.cpu()[ids], o.bbox_extents.cpu()[ids])
        distances[-1][mask], fractions[-1][mask] = d[mask], f[mask]

    success, _, ids = session.lift_episodes(names, episodes_per_object, seed,
                                            on_reset=on_reset, on_episode=on_episode)
    distance, fraction = torch.cat(distances), torch.cat(fractions)
    rows = []
    for k, name in enumerate(names):
        held = (ids == k) & success
        rows.append((name, int((ids == k).sum()), int(held.sum()),
                     float(distance[held].nanmedian()) if held.any() else float("nan"),
                     float(fraction[held].nanmedian()) if held.any() else float("nan")))
    return rows


def main(argv: list[str] | None = None) -> list[str]:
    args = eval_parser(__doc__.splitlines()[0]).parse_args(argv)
    rows = grasp_offsets(args.run_dir, args.episodes_per_object, args.iteration, args.objects,
                         args.seed)
    lines = ["| object | held / episodes | pads from the box centre (cm, median) "
             "| largest coordinate / half extent (median) |", "|---|---:|---:|---:|"]
    for name, episodes, held, dist, frac in rows:
        lines.append(f"| {name} | {held}/{episodes} | {100 * dist:.1f} | {frac:.2f} |")
    print("\n".join(lines))
    return lines


if __name__ == "__main__":
    main()
