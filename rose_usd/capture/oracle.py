"""Oracle capture: cameras, intrinsics and gravity from a benchmark case's ground truth."""

from __future__ import annotations

import numpy as np

from rose_usd.capture.world import author_world
from rose_usd.core import se3
from rose_usd.errors import InputError
from rose_usd.stage_api import StageContext


def run(ctx: StageContext) -> None:
    case = ctx.case
    gt = case.gt
    K = case.K() if case.K_path is not None else gt.K
    if (gt.width, gt.height) != (case.width, case.height):
        raise InputError(
            f"ground truth is for {gt.width}x{gt.height} frames, the case has {case.width}x{case.height}",
            path=gt.root / "scene.json",
            hint="regenerate the case",
        )
    world_from_camera = gt.camera_poses()
    gravity = np.asarray(gt.gravity, dtype=float)
    # the ground truth is already in the contract's world frame; if its gravity were not -Z we
    # would rotate it there, so apply the general alignment (identity for our generator)
    align = se3.make_pose(se3.rotation_between(gravity, [0.0, 0.0, -1.0]), np.zeros(3))
    author_world(
        ctx,
        world_from_camera=align @ world_from_camera,
        K=K,
        world_from_input=align,
        gravity_source="oracle",
        scale_source="oracle",
        intrinsics_source="file" if case.K_path is not None else "oracle",
    )
