"""The rgbd capture backend: a depth sensor or phone LiDAR video.

Cameras by keyframe RGB-D tracking with a pose graph (capture.tracking); gravity from the
support plane of the fused points, GeoCalib or an IMU (capture.gravity); the world origin under the
prompted object (capture.anchor). Sensor depth is metric: alpha = 1, beta = 0.
"""

from __future__ import annotations

import numpy as np

from rose_usd.capture.intrinsics import resolve_K
from rose_usd.capture.tracking import RgbdTracker, TrackingParams
from rose_usd.capture.world import author_tracked_world, fused_points, locate
from rose_usd.errors import InputError
from rose_usd.layers.world import cached_frames
from rose_usd.stage_api import StageContext


def run(ctx: StageContext) -> None:
    case = ctx.case
    if not case.has_depth:
        raise InputError(
            "the rgbd backend needs depth/", path=case.folder, hint="add depth maps or choose --backend capture=megasam"
        )
    K, k_source, warning = resolve_K(case, fov_guess_deg=ctx.config.fov_guess_deg)
    if warning:
        ctx.warn(warning)
    cfg = ctx.config
    downscale = max(1, int(round(case.width / cfg.rgbd.track_width)))
    params = TrackingParams(downscale=downscale, keyframe_every=cfg.rgbd.keyframe_every, depth_max_m=cfg.depth_max_m)
    depth_of = cached_frames(case.depth_m, 64)

    n = case.n_frames
    result = RgbdTracker(K, case.width, case.height, params).track(n, lambda t: (case.rgb(t), depth_of(t), None))
    poses = result.world_from_camera
    points = fused_points(depth_of, result.keyframes, K, poses, depth_max_m=cfg.depth_max_m)
    gravity, support, world_from_track, how = locate(ctx, poses, points, depth_of, K)
    low = int(np.sum(result.fitness < params.min_fitness))
    if low:
        ctx.warn(
            f"{low} frame(s) overlap their keyframe poorly (fitness < {params.min_fitness}); "
            "their poses are less certain"
        )
    author_tracked_world(ctx, poses, K, world_from_track, gravity, k_source, scale_source="sensor")
    ctx.record(
        keyframes=len(result.keyframes),
        photometric_keyframes=result.hybrid_keyframes,
        normal_spread=None if result.normal_spread is None else round(result.normal_spread, 3),
        keyframe_edges=len(result.keyframe_edges),
        fitness_min=round(float(result.fitness.min()), 3),
        fitness_mean=round(float(result.fitness.mean()), 3),
        gravity=gravity.source,
        support_plane_inliers=support.inliers,
        planes=[{"inliers": p.inliers, "tilt_deg": round(p.angle_to_prior_deg, 2)} for p in gravity.planes],
        origin=how,
    )
