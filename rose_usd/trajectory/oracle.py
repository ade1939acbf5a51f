"""Oracle trajectory: ground-truth object poses of a benchmark case, confidence 1, starting from
the object stage's frame-0 pose (which may have rested the object on the scene)."""

from __future__ import annotations

import numpy as np

from rose_usd.oracle import world_from_gt
from rose_usd.stage_api import StageContext
from rose_usd.trajectory.author import author_trajectory, from_default_pose


def run(ctx: StageContext) -> None:
    gt = ctx.case.gt
    to_world = world_from_gt(ctx)
    tracks = {
        spec.name: np.einsum("ij,njk->nik", to_world, gt.object_poses(spec.name)) for spec in ctx.case.config.objects
    }
    for name, poses in tracks.items():
        author_trajectory(ctx, name, from_default_pose(ctx, name, poses), np.ones(len(poses)), "oracle")
