"""Authoring layers/world.usda: the world prim, physics scene and the camera track.
Every capture backend ends here, so all of them write the same layer."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from pxr import Gf, UsdGeom, Vt

from rose_usd.capture.anchor import NothingStands, anchor_from_prompt, anchor_from_view_center, object_anchor
from rose_usd.capture.gravity import (
    gravity_from_geocalib,
    gravity_from_imu,
    gravity_from_planes,
    refine_with_planes,
    support_plane_for,
    world_from_tracking,
)
from rose_usd.case.config import Prompt
from rose_usd.core import se3
from rose_usd.core.pinhole import backproject
from rose_usd.errors import InputError
from rose_usd.stage_api import StageContext
from rose_usd.usd import paths, schema, tokens
from rose_usd.usd.camera import author_camera, check_K, gf_matrix
from rose_usd.usd.physics import author_physics_scene


def author_world(
    ctx: StageContext,
    *,
    world_from_camera: np.ndarray,
    K: np.ndarray,
    world_from_input: np.ndarray,
    gravity_source: str,
    scale_source: str,
    scale_alpha: float = 1.0,
    scale_beta: float = 0.0,
    scale_residual: float = 0.0,
    gravity_uncertainty_deg: float = 0.0,
    intrinsics_source: str = "file",
    depth_shift_px: tuple[int, int] = (0, 0),
    metric_depth: bool = True,
    scale_uncertainty: float = 0.0,
    scale_cues: list[tuple[str, float, float]] | None = None,
) -> None:
    """Write the world layer.

    Args:
        world_from_camera: OpenCV camera poses in the gravity-aligned metric world, (N, 4, 4) [m].
        K: (3, 3) or (N, 3, 3) intrinsics [px].
        world_from_input: transform from the input frame to the world (4, 4).
        depth_shift_px: (dx, dy) sensor depth pixel (x, y) shows colour pixel (x + dx, y + dy).
        metric_depth: whether later stages get metric depth per frame (False: RGB only).
        scale_uncertainty: relative one-sigma of the metric scale.
        scale_cues: (cue token, meters per reconstruction unit, relative sigma) of every scale cue
            measured (RGB only), the chosen one among them.
    """
    n = ctx.time_info.n_frames
    if len(world_from_camera) != n:
        raise ValueError(f"author_world: {len(world_from_camera)} camera poses for {n} frames")
    Ks = np.asarray(K, dtype=float)
    for k in Ks.reshape(-1, 3, 3):
        check_K(k, ctx.case.width, ctx.case.height)
    if ctx.case.fps_assumed:
        ctx.warn(
            f"no frame rate given (fps in rose.toml, or a video file's): {ctx.case.fps:g} fps assumed;"
            " the trajectory's speeds and the robot's pace follow it"
        )
    stage = ctx.stage
    world = UsdGeom.Xform.Define(stage, paths.WORLD)
    prim = world.GetPrim()
    prim.ApplyAPI(schema.WORLD_API)
    prim.GetAttribute(tokens.WORLD_GRAVITY_SOURCE).Set(gravity_source)
    prim.GetAttribute(tokens.WORLD_GRAVITY_UNCERTAINTY_DEG).Set(float(gravity_uncertainty_deg))
    prim.GetAttribute(tokens.WORLD_WORLD_FROM_INPUT).Set(gf_matrix(world_from_input))
    prim.GetAttribute(tokens.WORLD_SCALE_SOURCE).Set(scale_source)
    prim.GetAttribute(tokens.WORLD_SCALE_ALPHA).Set(float(scale_alpha))
    prim.GetAttribute(tokens.WORLD_SCALE_BETA).Set(float(scale_beta))
    prim.GetAttribute(tokens.WORLD_SCALE_RESIDUAL).Set(float(scale_residual))
    if not metric_depth:
        prim.GetAttribute(tokens.WORLD_METRIC_DEPTH).Set(False)
    if scale_uncertainty:
        prim.GetAttribute(tokens.WORLD_SCALE_UNCERTAINTY).Set(float(scale_uncertainty))
    if scale_cues:
        prim.GetAttribute(tokens.WORLD_SCALE_CUES).Set(Vt.TokenArray([c[0] for c in scale_cues]))
        prim.GetAttribute(tokens.WORLD_SCALE_CUE_VALUES).Set(Vt.DoubleArray([float(c[1]) for c in scale_cues]))
        prim.GetAttribute(tokens.WORLD_SCALE_CUE_SIGMAS).Set(Vt.DoubleArray([float(c[2]) for c in scale_cues]))
    if tuple(depth_shift_px) != (0, 0):
        prim.GetAttribute(tokens.WORLD_DEPTH_SHIFT_PX).Set(Gf.Vec2i(*(int(v) for v in depth_shift_px)))
    author_physics_scene(stage, paths.PHYSICS_SCENE)
    UsdGeom.Scope.Define(stage, paths.CAMERAS)
    author_camera(
        stage,
        paths.CAMERA,
        world_from_camera,
        Ks,
        ctx.case.width,
        ctx.case.height,
        intrinsics_source=intrinsics_source,
        clipping_range_m=(0.01, 100.0),
    )


def author_tracked_world(
    ctx: StageContext, poses: np.ndarray, K: np.ndarray, world_from_track: np.ndarray, gravity, k_source: str, **more
) -> None:
    """Write the world layer from cameras tracked in their own frame (``poses``) and the world
    ``locate`` found; ``more`` holds author_world's scale_* and depth_shift_px arguments."""
    author_world(
        ctx,
        world_from_camera=np.einsum("ij,njk->nik", world_from_track, poses),
        K=K,
        world_from_input=world_from_track,
        gravity_source=gravity.source,
        gravity_uncertainty_deg=gravity.uncertainty_deg,
        intrinsics_source=k_source,
        **more,
    )


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


def prompted_objects(ctx: StageContext) -> list:
    """The objects (``ObjectSpec``) with a prompt on a frame of the video: ``capture.prompts`` (the
    command line's ``--prompt``) over rose.toml's, in rose.toml's order."""
    specs = {s.name: s for s in ctx.case.config.objects}
    for item in ctx.config.prompts:
        name = item.name or (next(iter(specs)) if len(specs) == 1 else "")
        if name not in specs:
            raise InputError(
                f"capture.prompts item {str(item)!r} names no object of rose.toml",
                path=ctx.case.settings_file,
                hint=f"objects: {', '.join(specs) or 'none'}",
            )
        specs[name] = replace(specs[name], prompt=item.prompt)
    return [s for s in specs.values() if s.prompt is not None and 0 <= s.prompt.frame < ctx.case.n_frames]


def prompts_source(ctx: StageContext):
    """What an error about a prompt names: the command line's (``capture.prompts``) when there are
    any, else the case's rose.toml."""
    return "capture.prompts (--prompt)" if ctx.config.prompts else ctx.case.settings_file


def locate(
    ctx: StageContext, poses: np.ndarray, points: np.ndarray, depth_of, K: np.ndarray, *, plane_floor_deg: float = 0.1
):
    """Gravity, the support plane and the world frame (tracking -> world), and how the origin was found."""
    case = ctx.case
    spec = next(iter(prompted_objects(ctx)), None)
    anchor = None
    if spec is not None and 0 <= spec.prompt.frame < len(poses):
        prompt = spec.prompt
        try:
            anchor = object_anchor(prompt, depth_of(prompt.frame), K, poses[prompt.frame])
        except NothingStands as e:
            raise InputError(
                f"nothing stands on the surface inside the prompt box of {spec.name!r} on frame {prompt.frame} ({e})",
                path=prompts_source(ctx),
                hint="draw the box around the object on a frame where it is visible",
            ) from None
    if anchor is not None:
        gravity, support = choose_gravity(
            ctx, poses, points, anchor, plane_floor_deg=plane_floor_deg, upside_down_check=True
        )
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


def choose_gravity(
    ctx: StageContext,
    poses: np.ndarray,
    points: np.ndarray,
    anchor: np.ndarray | None,
    *,
    plane_floor_deg: float = 0.1,
    anchor_min_height_m: float = 0.005,
    upside_down_check: bool = False,
):
    """Gravity by the configured method, and the support plane (the one under ``anchor``, a point
    on the object, when given). ``auto``: the IMU; else GeoCalib fused with the support plane
    (plane sigma at least ``plane_floor_deg``); else the support plane alone, checked for an
    upside-down camera when ``upside_down_check`` (the anchor is on a prompted object)."""
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
        est = gravity_from_planes(
            points,
            poses,
            anchor=anchor,
            anchor_min_height_m=anchor_min_height_m,
            upside_down_check=upside_down_check,
        )
    support = (
        est.support
        if est.support is not None
        else support_plane_for(est.up, points, poses, anchor, anchor_min_height_m)
    )
    return est, support
