"""The object representations of the paper, computed in torch from the object pose and the
object's geomprep artifacts (see ``ObjectSet``). All outputs are in the world frame, metres.

| name   | shape     | content |
|--------|-----------|---------|
| com    | (E, 9)    | centre of mass position, orientation (6-d: first two rotation columns) |
| bbox   | (E, 10)   | box centre, box orientation quaternion (w, x, y, z; w >= 0), full extents |
| sq     | (E, 11)   | eps1, eps2, a1, a2, a3, extrinsic xyz Euler angles, centre |
| pcN    | (E, N, 3) | N surface points (N = 32, 128, 512) |
| sdf    | (E, 5)    | signed distance of the 5 fingertips to the surface (negative inside) |
"""

from __future__ import annotations

import torch

from geomgrasp.rotations import (
    euler_xyz_to_matrix,
    matrix_to_euler_xyz,
    matrix_to_quat,
    quat_to_matrix,
    rotation_6d,
)
from trainer.objects import ObjectSet


def representation_shape(name: str) -> tuple[int, ...]:
    """Per-environment shape of a representation."""
    if name.startswith("pc"):
        return (int(name[2:]), 3)
    return {"com": (9,), "bbox": (10,), "sq": (11,), "sdf": (5,)}[name]


def object_representation(
    name: str,
    objects: ObjectSet,
    ids: torch.Tensor,
    obj_pos: torch.Tensor,
    obj_quat: torch.Tensor,
    fingertips: torch.Tensor,
) -> torch.Tensor:
    """The representation ``name`` for E environments.

    ids: (E,) object ids; obj_pos (E, 3) and obj_quat (E, 4) (w, x, y, z): the object frame in
    the world; fingertips: (E, 5, 3) fingertip positions (used by ``sdf`` only).
    """
    rot = quat_to_matrix(obj_quat)
    if name == "com":
        return torch.cat([obj_pos, rotation_6d(rot)], dim=-1)
    if name == "bbox":
        center = obj_pos + (rot @ objects.bbox_center[ids][..., None])[..., 0]
        box_rot = rot @ objects.bbox_rotation[ids]
        return torch.cat([center, matrix_to_quat(box_rot), objects.bbox_extents[ids]], dim=-1)
    if name == "sq":
        params = objects.sq_params[ids]
        sq_rot = euler_xyz_to_matrix(params[:, 5:8])
        center = obj_pos + (rot @ params[:, 8:11, None])[..., 0]
        return torch.cat([params[:, :5], matrix_to_euler_xyz(rot @ sq_rot), center], dim=-1)
    if name.startswith("pc"):
        local = objects.points[ids, : int(name[2:])]
        return local @ rot.transpose(1, 2) + obj_pos[:, None, :]
    if name == "sdf":
        if objects.sdf is None:
            raise ValueError("the SDF grids were not loaded")
        return objects.sdf.query(fingertips, obj_pos, obj_quat, ids)
    raise ValueError(f"unknown representation {name!r}")
