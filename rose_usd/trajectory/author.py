"""Authoring layers/trajectory.usda: time samples of each object's pose ops (the object stage's
default stays frame 0, which Newton reads), per-frame confidence, and TUM files. Every trajectory
backend ends here."""

from __future__ import annotations

import numpy as np
from pxr import Usd, UsdGeom

from rose_usd.core import se3
from rose_usd.errors import StageError
from rose_usd.io.tum import write_tum
from rose_usd.layers.objects import default_pose
from rose_usd.stage_api import StageContext
from rose_usd.usd import paths, schema, tokens
from rose_usd.usd.physics import set_pose_ops


def author_trajectory(
    ctx: StageContext, name: str, world_from_object: np.ndarray, confidence: np.ndarray, source: str
) -> None:
    """Time-sample ``world_from_object`` (N, 4, 4) and ``confidence`` (N,) on the object prim."""
    n = ctx.time_info.n_frames
    if world_from_object.shape != (n, 4, 4) or confidence.shape != (n,):
        raise ValueError(f"author_trajectory: expected {n} poses and confidences")
    prim = ctx.stage.GetPrimAtPath(paths.object_path(name))
    if not prim:
        raise StageError(
            f"object {name!r} has no prim in the stage", hint="run the object stage first (rose-usd run object ...)"
        )
    xform = UsdGeom.Xformable(prim)
    for t in range(n):
        set_pose_ops(xform, world_from_object[t], Usd.TimeCode(t))
    prim.ApplyAPI(schema.TRAJECTORY_API)
    conf = prim.GetAttribute(tokens.TRAJECTORY_CONFIDENCE)
    for t in range(n):
        conf.Set(float(confidence[t]), Usd.TimeCode(t))
    prim.GetAttribute(tokens.TRAJECTORY_SOURCE).Set(source)
    write_tum(
        ctx.side_dir("trajectory") / f"{name}.tum",
        np.arange(n) / ctx.time_info.fps,
        world_from_object,
        header=f"world_from_object of {name} (rose_usd trajectory stage, source {source})",
    )


def from_default_pose(ctx: StageContext, name: str, world_from_object: np.ndarray) -> np.ndarray:
    """The poses re-expressed so that frame 0 is the object stage's default pose (which rested
    the object on the scene, e.g. lifted it out of the table by a few millimeters): the motion
    since frame 0 in the world, W_t W_0^-1, applied to the default pose. The correction is on the
    object side, W_t (W_0^-1 D): the two may disagree on the object frame (a can's yaw is
    arbitrary), and a world-side correction D W_0^-1 would turn the whole path about the world
    origin by that disagreement."""
    default = default_pose(ctx.stage, name)
    offset = np.linalg.inv(world_from_object[0]) @ default
    return np.einsum("nij,jk->nik", world_from_object, offset)


def fill_gaps(poses: np.ndarray, present: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Poses (N, 4, 4) with the missing ones interpolated (SE(3) slerp between the nearest present
    frames) or held at the ends; and the confidence per frame (1 read, 0.5 interpolated, 0 held)."""
    have = np.flatnonzero(present)
    out = poses.copy()
    confidence = np.where(present, 1.0, 0.0)
    for t in np.flatnonzero(~present):
        after = have[have > t]
        before = have[have < t]
        if len(before) and len(after):
            a, b = before[-1], after[0]
            out[t] = se3.slerp_poses(poses[a], poses[b], (t - a) / (b - a))
            confidence[t] = 0.5
        else:
            out[t] = poses[before[-1] if len(before) else after[0]]
    return out, confidence
