"""The rgbd capture backend: a depth sensor or phone LiDAR video.

Cameras by keyframe RGB-D tracking with a pose graph (capture.tracking); gravity from the
support plane of the fused points, GeoCalib or an IMU (capture.gravity); the world origin under the
prompted object (capture.anchor). Sensor depth is metric: alpha = 1, beta = 0.
"""

from __future__ import annotations

import numpy as np

from rose_usd.capture.anchor import anchor_from_prompt, anchor_from_view_center
from rose_usd.capture.depth import cached_frames
from rose_usd.capture.gravity import (
    gravity_from_geocalib,
    gravity_from_imu,
    gravity_from_planes,
    refine_with_planes,
    support_plane_for,
    world_from_tracking,
)
from rose_usd.capture.intrinsics import resolve_K
from rose_usd.capture.tracking import RgbdTracker, TrackingParams
from rose_usd.capture.world import author_world
from rose_usd.case.config import Prompt
from rose_usd.core import se3
from rose_usd.core.pinhole import backproject
from rose_usd.errors import InputError
from rose_usd.stage_api import StageContext


def fused_points(
    load_depth,
    frames: list[int],
    K: np.ndarray,
    poses: np.ndarray,
    *,
    stride_px: int = 4,
    voxel_m: float = 0.01,
    depth_max_m: float = 3.0,
) -> np.ndarray:
    """Back-projected depth of ``frames`` in the tracking frame, voxel-downsampled."""
    import open3d as o3d

    chunks = []
    for t in frames:
        depth = load_depth(t)
        sub = depth[::stride_px, ::stride_px]
        v, u = np.nonzero((sub > 0) & (sub < depth_max_m))
        z = sub[v, u]
        u, v = u * stride_px, v * stride_px
        chunks.append(se3.transform_points(poses[t], backproject(u, v, z, K)))
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.concatenate(chunks)))
    return np.asarray(cloud.voxel_down_sample(voxel_m).points)


def choose_gravity(
    ctx: StageContext,
    poses: np.ndarray,
    points: np.ndarray,
    anchor: np.ndarray | None,
    *,
    plane_floor_deg: float = 0.1,
    anchor_min_height_m: float = 0.005,
):
    """Gravity by the configured method, and the support plane (the one under ``anchor``, a point
    on the object, when given). ``auto``: the IMU; else GeoCalib fused with the support plane
    (plane sigma at least ``plane_floor_deg``); else the support plane alone."""
    method = ctx.config.gravity.value
    folder = ctx.case.folder
    imu, geocalib = folder / "imu" / "gravity.txt", folder / "perception" / "geocalib.json"
    auto = method == "auto"
    if auto:
        method = "imu" if imu.is_file() else "geocalib" if geocalib.is_file() else "plane"
    if method == "imu":
        if not imu.is_file():
            raise InputError(
                "gravity = imu but there is no imu/gravity.txt", path=folder, hint="add it or choose gravity = plane"
            )
        est = gravity_from_imu(imu, poses)
    elif method == "geocalib":
        if not geocalib.is_file():
            raise InputError(
                "gravity = geocalib but there is no perception/geocalib.json",
                path=folder,
                hint="add it or choose gravity = plane",
            )
        est = gravity_from_geocalib(geocalib, poses)
        if auto:
            est = refine_with_planes(
                est, points, poses, anchor=anchor, floor_deg=plane_floor_deg, anchor_min_height_m=anchor_min_height_m
            )
    else:
        est = gravity_from_planes(points, poses, anchor=anchor, anchor_min_height_m=anchor_min_height_m)
    support = (
        est.support
        if est.support is not None
        else support_plane_for(est.up, points, poses, anchor, anchor_min_height_m)
    )
    return est, support


def locate(
    ctx: StageContext, poses: np.ndarray, points: np.ndarray, depth_of, K: np.ndarray, *, plane_floor_deg: float = 0.1
):
    """Gravity, the support plane and the world frame (tracking -> world), and how the origin was found."""
    case = ctx.case
    prompt = next((o.prompt for o in case.config.objects if o.prompt is not None), None)
    anchor = None
    if prompt is not None and 0 <= prompt.frame < len(poses):
        anchor = anchor_from_prompt(prompt, depth_of(prompt.frame), K, poses[prompt.frame])
    if anchor is not None:
        gravity, support = choose_gravity(ctx, poses, points, anchor, plane_floor_deg=plane_floor_deg)
    else:
        # no object to stand on the support: the support is the plane the first view centers on
        # (a casual video frames the table, while a floor may fill more of the fused points)
        center = Prompt(frame=0, point=(case.width / 2.0, case.height / 2.0))
        look = anchor_from_prompt(center, depth_of(0), K, poses[0])
        gravity, support = choose_gravity(
            ctx, poses, points, look, plane_floor_deg=plane_floor_deg, anchor_min_height_m=-0.03
        )
    how = "prompt"
    if anchor is None:
        anchor = anchor_from_view_center(support, K, case.width, case.height, poses[0])
        how = "view-center"
        ctx.warn("no usable object prompt: the world origin is where the first view's center meets the support plane")
    return gravity, support, world_from_tracking(gravity.up, support, anchor, poses[0]), how


def author_tracked_world(
    ctx: StageContext, poses: np.ndarray, K: np.ndarray, world_from_track: np.ndarray, gravity, k_source: str, **scale
) -> None:
    """Write the world layer from cameras tracked in their own frame (``poses``) and the world
    ``locate`` found; ``scale`` holds author_world's scale_* arguments."""
    author_world(
        ctx,
        world_from_camera=np.einsum("ij,njk->nik", world_from_track, poses),
        K=K,
        world_from_input=world_from_track,
        gravity_source=gravity.source,
        gravity_uncertainty_deg=gravity.uncertainty_deg,
        intrinsics_source=k_source,
        **scale,
    )


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
    downscale = max(1, int(round(case.width / cfg.track_width)))
    params = TrackingParams(downscale=downscale, keyframe_every=cfg.keyframe_every, depth_max_m=cfg.depth_max_m)
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
