"""How well an object's fitted mesh covers its masks on a real clip, where no true pose is known:
the IoU of its rendered silhouette (at its trajectory poses, through the recovered cameras) with
its masks, outside the interactor's."""

from __future__ import annotations

import numpy as np

from rose_usd.core import se3
from rose_usd.core.pinhole import silhouette
from rose_usd.layers.masks import INTERACTOR, read_masks
from rose_usd.layers.objects import default_pose, visual_mesh
from rose_usd.layers.trajectory import object_poses
from rose_usd.layers.world import read_cameras

CARRIED_WINDOW = 5
"""A frame is in a carry when the object moves within this many frames of it (``silhouette_ious``)."""


def carried_frames(poses: np.ndarray) -> np.ndarray:
    """Frames (bool (n,)) within ``CARRIED_WINDOW`` of one where the object moves: between the
    frames before and after it, by more than 2 mm or 2 deg (in the hand, not resting)."""
    n = len(poses)
    moving = np.zeros(n, bool)
    for t in range(1, n - 1):
        step = se3.invert(poses[t - 1]) @ poses[t + 1]
        moving[t] = np.linalg.norm(step[:3, 3]) > 0.002 or se3.rotation_angle_deg(step[:3, :3]) > 2.0
    return np.convolve(moving, np.ones(2 * CARRIED_WINDOW + 1), "same") > 0


def silhouette_ious(stage, case, name: str) -> dict:
    """IoU of the object's rendered silhouette with its masks outside the interactor's, over every
    frame with a mask, over those in which the object is off its frame-0 pose by more than 1 cm
    or 5 deg ("held": moved from where it started), and over those in a carry ("carried",
    ``carried_frames``: what issue 27 calls held)."""
    n = case.n_frames
    poses, cams = object_poses(stage, name, n), read_cameras(stage, n)
    carried, in_carry = carried_frames(poses), []
    masks = read_masks(stage, n, (case.height, case.width))
    mesh = visual_mesh(stage, name)
    local = se3.transform_points(se3.invert(default_pose(stage, name)), mesh.vertices)  # its default pose's
    every, held = [], []
    for t in range(n):
        m = masks.mask(name, t)
        if m is None or m.sum() < 50:
            continue
        hand = masks.mask(INTERACTOR, t) if masks.has(INTERACTOR) else None
        keep = ~hand if hand is not None else np.ones_like(m)
        sil = silhouette(
            se3.transform_points(poses[t], local), mesh.faces, cams.world_from_cv[t], cams.K[t], case.width, case.height
        )
        iou = float(np.count_nonzero(sil & m & keep) / max(np.count_nonzero((sil | m) & keep), 1))
        every.append(iou)
        moved = se3.invert(poses[0]) @ poses[t]
        if np.linalg.norm(moved[:3, 3]) > 0.01 or se3.rotation_angle_deg(moved[:3, :3]) > 5.0:
            held.append(iou)
        if carried[t]:
            in_carry.append(iou)

    def stats(values):
        return {"frames": len(values), "mean": float(np.mean(values)) if values else None,
                "median": float(np.median(values)) if values else None}  # fmt: skip

    return {"all": stats(every), "held": stats(held), "carried": stats(in_carry)}
