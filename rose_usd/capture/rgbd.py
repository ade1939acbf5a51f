"""The rgbd capture backend: a depth sensor or phone LiDAR video.

Cameras: a static camera (most first-frame corners stay put, capture.static) keeps the first
frame's pose, and its depth is checked for a shift against the colour (geometry.registration,
applied and recorded in the world layer when found); a moving one is tracked by keyframe RGB-D
tracking with a pose graph (capture.tracking), with its photometric term on every keyframe when
the depth's silhouettes lie on the colour's edges (geometry.registration.edge_alignment: colour
registered to depth constrains what the depth leaves loose), else only where the geometry is
degenerate (a colour image off its depth biases it: 7-Scenes' Kinect). Gravity from the
support plane of the fused points, GeoCalib or an IMU (capture.gravity); the world origin under the
prompted object (capture.anchor). Sensor depth is metric: alpha = 1, beta = 0.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from rose_usd.capture.intrinsics import resolve_K
from rose_usd.capture.static import still_fraction
from rose_usd.capture.tracking import RgbdTracker, TrackingParams, can_bind_cpu, track_on_one_cpu
from rose_usd.capture.world import author_tracked_world, fused_points, locate
from rose_usd.core import se3
from rose_usd.core.runs import spread_frames
from rose_usd.errors import InputError
from rose_usd.geometry.registration import DepthShift, edge_alignment, find_depth_shift, shift_depth
from rose_usd.layers.world import cached_frames
from rose_usd.stage_api import StageContext

ALIGNMENT_FRAMES = 8
"""Frames, spread over the video, whose depth silhouettes are checked against the colour's edges."""


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
    n = case.n_frames
    valid = case.depth_valid()
    dropped = [int(t) for t in np.flatnonzero(~valid)]
    if dropped:
        ctx.warn(
            f"{len(dropped)} depth frame(s) hold no valid depth (a sensor dropout): {dropped[:10]}"
            f"{' ...' if len(dropped) > 10 else ''}; their cameras are interpolated from their neighbours"
        )
    depth_of = cached_frames(_nearest_valid(case.depth_m, valid), 64)

    still = still_fraction(case.rgb, n)
    shift = DepthShift(0, 0, 0.0, 0.0, 0)
    if still >= cfg.rgbd.static_fraction:
        poses = np.repeat(np.eye(4)[None], n, axis=0)
        keyframes = [t for t in range(0, n, max(1, n // 24)) if valid[t]] or [int(np.flatnonzero(valid)[0])]
        tracking = {"static_camera": True}
        shift = _registration(ctx, depth_of) if cfg.rgbd.depth_shift else shift
        if shift.applies:
            depth_of = cached_frames(lambda t: shift_depth(case.depth_m(t), shift.dx, shift.dy), 64)
    else:
        poses, keyframes, tracking = _track(ctx, K, params, depth_of, valid)
    points = fused_points(depth_of, keyframes, K, poses, depth_max_m=cfg.depth_max_m)
    gravity, support, world_from_track, how = locate(ctx, poses, points, depth_of, K)
    author_tracked_world(
        ctx,
        poses,
        K,
        world_from_track,
        gravity,
        k_source,
        scale_source="sensor",
        depth_shift_px=(shift.dx, shift.dy) if shift.applies else (0, 0),
    )
    ctx.record(
        **tracking,
        still_corners=round(still, 3),
        gravity=gravity.source,
        support_plane_inliers=support.inliers,
        planes=[{"inliers": p.inliers, "tilt_deg": round(p.angle_to_prior_deg, 2)} for p in gravity.planes],
        origin=how,
        depth_dropouts=dropped,
        depth_shift={
            "dx": shift.dx,
            "dy": shift.dy,
            "overlap": round(shift.overlap, 3),
            "overlap_unshifted": round(shift.overlap_unshifted, 3),
            "frames": shift.frames,
            "applied": shift.applies,
        },
    )


def _nearest_valid(depth_m, valid: np.ndarray):
    """Depth of frame t, or of the nearest frame with valid depth when t's dropped out (used
    where one frame's depth must stand for it: the prompt's anchor, the first view's center)."""
    good = np.flatnonzero(valid)

    def load(t: int) -> np.ndarray:
        return depth_m(t if valid[t] else int(good[np.argmin(np.abs(good - t))]))

    return load


def _fill_dropped(poses_valid: np.ndarray, frames: np.ndarray, n: int) -> np.ndarray:
    """Poses of all ``n`` frames from those of ``frames`` (sorted): interpolated between the valid
    frames around a dropped one, held before the first and after the last."""
    poses = np.repeat(np.eye(4)[None], n, axis=0)
    poses[frames] = poses_valid
    for t in range(n):
        if t in frames:
            continue
        after = int(np.searchsorted(frames, t))
        if after == 0:
            poses[t] = poses_valid[0]
        elif after == len(frames):
            poses[t] = poses_valid[-1]
        else:
            a, b = frames[after - 1], frames[after]
            poses[t] = se3.slerp_poses(poses_valid[after - 1], poses_valid[after], (t - a) / (b - a))
    return poses


def _track(ctx: StageContext, K: np.ndarray, params: TrackingParams, depth_of, valid: np.ndarray):
    """Poses of a moving camera by keyframe RGB-D tracking over the frames with valid depth, the
    others interpolated, the photometric term on every keyframe when the colour is registered to
    the depth: (poses, keyframes, what to record)."""
    case = ctx.case
    frames = np.flatnonzero(valid)
    alignment = edge_alignment(case.rgb, depth_of, frames[spread_frames(len(frames), ALIGNMENT_FRAMES)].tolist())
    if alignment.registered:
        params = replace(params, method="hybrid")
    if ctx.config.rgbd.repeatable and can_bind_cpu():
        result = track_on_one_cpu(case, frames.tolist(), K, params)
    else:
        result = RgbdTracker(K, case.width, case.height, params).track(
            len(frames), lambda i: (case.rgb(int(frames[i])), depth_of(int(frames[i])), None)
        )
    poses = _fill_dropped(result.world_from_camera, frames, case.n_frames)
    # the first camera is the tracking frame's origin even when its own depth dropped out
    poses = np.einsum("ij,njk->nik", se3.invert(poses[0]), poses)
    keyframes = [int(frames[k]) for k in result.keyframes]
    low = int(np.sum(result.fitness < params.min_fitness))
    if low:
        ctx.warn(
            f"{low} frame(s) overlap their keyframe poorly (fitness < {params.min_fitness}); "
            "their poses are less certain"
        )
    record = {
        "static_camera": False,
        "keyframes": len(result.keyframes),
        "photometric_keyframes": result.hybrid_keyframes,
        "normal_spread": None if result.normal_spread is None else round(result.normal_spread, 3),
        "keyframe_edges": len(result.keyframe_edges),
        "fitness_min": round(float(result.fitness.min()), 3),
        "fitness_mean": round(float(result.fitness.mean()), 3),
        "colour_registration": {
            "dx": alignment.dx,
            "dy": alignment.dy,
            "edge_distance_px": round(alignment.at_zero_px, 3),
            "typical_px": round(alignment.typical_px, 3),
            "frames": alignment.frames,
            "registered": alignment.registered,
        },
    }
    return poses, keyframes, record


def _registration(ctx: StageContext, depth_of) -> DepthShift:
    """The depth-to-colour shift of a static camera's video (geometry.registration), with a
    warning when it is applied."""
    case = ctx.case
    shift = find_depth_shift(case.rgb, depth_of, case.n_frames)
    if shift.applies:
        ctx.warn(
            f"depth/ does not line up with rgb/: what moves sits ({-shift.dx}, {-shift.dy}) px apart in the two"
            f" (its depth and colour overlap {shift.overlap_unshifted:.2f}, {shift.overlap:.2f} shifted), so every"
            f" stage reads the depth shifted by ({shift.dx}, {shift.dy}) px (the world layer records it;"
            " `--set capture.rgbd.depth_shift=false` takes depth/ as it is)"
        )
    return shift
