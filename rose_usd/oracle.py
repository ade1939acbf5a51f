"""What every oracle backend shares: ground truth expressed in the stage's world frame.

When capture ran a real backend, its world differs from the ground truth's by a rigid transform
(arbitrary yaw and origin, plus its errors). Oracle backends of later stages place the ground
truth in *that* world, registered by the camera poses, so any mix of real and oracle backends
composes into one consistent stage and isolates the real backends' errors.
"""

from __future__ import annotations

import numpy as np

from rose_usd.core.metrics import align_poses
from rose_usd.stage_api import StageContext
from rose_usd.usd import paths
from rose_usd.usd.camera import read_camera
from rose_usd.usd.stage import layer_file, read_provenance


def world_from_gt(ctx: StageContext) -> np.ndarray:
    """Transform (4, 4) from the ground truth's world to the stage's world (identity when capture
    itself was the oracle)."""
    prov = read_provenance(layer_file(ctx.out_dir, "world")) or {}
    if prov.get("backend") == "oracle":
        return np.eye(4)
    track = read_camera(ctx.stage, paths.CAMERA, ctx.time_info.n_frames)
    return align_poses(ctx.case.gt.camera_poses(), track.world_from_cv)
