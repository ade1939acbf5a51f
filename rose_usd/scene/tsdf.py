"""The tsdf scene backend: fuse the static pixels, wrap them into a valid collider, color it.

1. **Fuse** every ``frame_stride``-th frame's metric depth into a TSDF volume (Open3D, CPU),
   keeping only static pixels: not an object or the interactor (their masks dilated by
   ``mask_margin_px``) and not nearer than the static world (geometry.background), so neither the
   object's resting place nor the hand leaves a ghost.
2. **Wrap** the fused surface with CGAL's 3D alpha wrapping (``alpha_m``, ``offset_m``): a
   closed, 2-manifold, consistently oriented, self-intersection-free shell around it and around
   a copy of it ``thickness_m`` lower (against gravity), so an open table top becomes a solid
   slab that a resting object cannot be pushed through. The wrap lies ``offset_m`` outside what
   it wraps, so it wraps the surface moved ``offset_m`` into the material (along the TSDF's
   normals): the table's collider top is the fused table, and a resting object is not lifted.
   Validity is then checked, never assumed: trimesh must find it watertight and consistently
   wound with positive volume, and CGAL must find no self-intersection.
3. **Budget**: while the wrap has more than ``max_triangles`` triangles, wrap again with a 1.5x
   larger alpha (coarser, and still valid: decimating the wrap with manifold3d can create
   self-intersections), re-checked.
   Under each object resting on the support before it is touched, the fused surface is replaced
   by a flat pad before the wrap (``support_pads``), and the wrap's top is set exactly at the
   pad's height after it (``flatten_pads``).
4. **Color**: each vertex gets the distance-weighted mean color of its 3 nearest fused points
   (the paper's rule). Each texel of a texture baked over xatlas UVs takes the median color of
   its projections into ``texture_frames`` frames that see it (static pixels, depth agreeing,
   facing the camera; ``FrameColors``), or the 3-NN rule where no frame sees it: the TSDF's
   colors are 8 mm voxel averages, the frames keep the surface's own detail. The colors hold the
   video's lighting, so the scene is lit by a unit ambient light.
"""

from __future__ import annotations

import functools
import tempfile
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from rose_usd.core import se3
from rose_usd.core.color import srgb8_to_linear
from rose_usd.core.pinhole import backproject, masked_world_points, view_counts
from rose_usd.core.runs import spread_frames
from rose_usd.errors import InputError
from rose_usd.geometry.background import StaticBackground
from rose_usd.geometry.contact import first_contact, ring_height
from rose_usd.geometry.texture import transfer_colors
from rose_usd.layers.masks import INTERACTOR, read_masks
from rose_usd.layers.world import metric_depth_reader, read_cameras
from rose_usd.progress import progress
from rose_usd.render.lighting import Lighting
from rose_usd.scene.author import author_scene
from rose_usd.scene.fused import (
    FrameColors,
    Fusion,
    SupportPad,
    _footprint,
    _mask_files,
    _read_frame_masks,
    _static_pixels,
    collider_record,
    fill_support_holes,
    lay_pads,
    textured_parts,
    wrap_collider,
)
from rose_usd.stage_api import StageContext
from rose_usd.usd.geom import MeshData


def seen_through(
    points: np.ndarray, depth_of, cameras, frames, *, tol_m: float = 0.02, rel: float = 0.03
) -> np.ndarray:
    """Points (N, 3) that more of ``frames`` see through (the depth at their pixel lies beyond
    them by more than ``tol_m`` + ``rel`` x depth) than see (depth within that of them)."""
    through, near, _ = view_counts(
        points, ((depth_of(t), cameras.K[t], cameras.world_from_cv[t]) for t in frames), tol_m=tol_m, rel=rel
    )
    return through > near


MIN_VIEWS = 3
"""Open3D's TSDF keeps a surface whose integration weight exceeds this (``extract_point_cloud``'s
default weight threshold; one frame adds weight 1 to a voxel it sees)."""
CARVE_ABOVE_M = 0.015
"""Carving never touches the support: only fused points this high above it [m]."""


def fuse_static(
    ctx: StageContext, *, voxel_m: float, frame_stride: int, margin_px: int, depth_max_m: float, carve_m: float
):
    """TSDF-fuse the static pixels. Returns the fused surface's points (V, 3), their linear colors
    (V, 3), their outward normals (V, 3), the number of frames fused and the number of points
    carved away."""
    case = ctx.case
    n = ctx.time_info.n_frames
    cameras = read_cameras(ctx.stage, n)
    depth_of = metric_depth_reader(ctx.stage, case, cache=24)
    background = StaticBackground(depth_of, cameras.world_from_cv, cameras.K, case.width, case.height)
    masks = _mask_files(ctx, n)
    volume = Fusion(voxel_m, depth_max_m)
    kernel = np.ones((2 * margin_px + 1, 2 * margin_px + 1), np.uint8)
    used = 0
    frames = range(0, n, frame_stride)
    object_points = []
    for t in progress(frames, "scene fuse", total=len(frames)):
        depth = depth_of(t).copy()
        frame_masks = _read_frame_masks(masks[t], case)
        for f, m in frame_masks:
            if f.parent.name != INTERACTOR:
                v, u = np.nonzero(m[::4, ::4] & (depth[::4, ::4] > 0))
                cam = backproject(4 * u, 4 * v, depth[4 * v, 4 * u], cameras.K[t])
                object_points.append(se3.transform_points(cameras.world_from_cv[t], cam))
        depth[~_static_pixels(t, depth, frame_masks, background, kernel)] = 0.0
        used += volume.add(depth, case.rgb(t), cameras.K[t], cameras.world_from_cv[t])
    points, colors01, normals = volume.oriented_points()
    # carve: fused surface above the support and within carve_m of where an object was seen is
    # a piece of an object its masks missed (the top of a can that never moves), not scene
    carved = 0
    objs = np.concatenate(object_points) if object_points else np.zeros((0, 3))
    objs = objs[objs[:, 2] > CARVE_ABOVE_M]
    if len(objs) and len(points):
        near = cKDTree(objs).query(points, distance_upper_bound=carve_m)[0] < carve_m
        near &= points[:, 2] > CARVE_ABOVE_M
        carved = int(near.sum())
        points, colors01, normals = points[~near], colors01[~near], normals[~near]
    # free space: a fused point that more frames see through (their depth lies well behind it)
    # than see it was there only for a while (a moving part its masks missed in a few frames)
    transient = seen_through(points, depth_of, cameras, range(0, n, max(1, n // 60)))
    carved += int(transient.sum())
    points, colors01, normals = points[~transient], colors01[~transient], normals[~transient]
    if len(points) < 100 and used <= MIN_VIEWS:
        raise InputError(
            f"the fused static volume is empty: {used} of the video's {n} frames fused (frame_stride"
            f" {frame_stride}), and a surface counts once more than {MIN_VIEWS} views saw it",
            path=case.folder,
            hint=f"give a longer video (at least {2 * MIN_VIEWS + 2} frames) or --set scene.tsdf.frame_stride=1",
        )
    if len(points) < 100:  # enough frames: what was there was masked or carved away
        raise InputError(
            f"the fused static volume is empty ({len(points)} points from {used} frames)",
            path=case.folder,
            hint="check the depth and the masks: every pixel may have been masked as moving",
        )
    colors = srgb8_to_linear(np.clip(colors01 * 255.0 + 0.5, 0, 255).astype(np.uint8))
    return points, colors, normals, used, carved


def sensor_frame_colors(ctx: StageContext, cfg) -> FrameColors | None:
    """The tsdf backend's texel colors: ``texture_frames`` frames of the world layer's depth."""
    if cfg.texture_frames <= 0:
        return None
    case, n = ctx.case, ctx.time_info.n_frames
    cameras = read_cameras(ctx.stage, n)
    depth_of = metric_depth_reader(ctx.stage, case, cache=4)
    background = StaticBackground(depth_of, cameras.world_from_cv, cameras.K, case.width, case.height)
    frames = spread_frames(n, cfg.texture_frames)
    return FrameColors(ctx, depth_of, frames, margin_px=cfg.mask_margin_px, background=background)


def support_pads(
    ctx: StageContext, *, margin_m: float, cell_m: float = 0.004, max_gap_m: float = 0.025, count: int = 8
) -> tuple[list[SupportPad], dict[str, str]]:
    """Where each object rests before the interactor first touches it, the support under it as a
    flat pad at the height the object stage stands it on (``geometry.contact.ring_height``).

    The table under a resting object is never seen while it rests, and what is fused there from
    other frames is what the depth makes of it: with MegaSaM's, bumps and slopes of several
    millimeters, on which Newton's object rocks or slides. The footprint is the convex hull of the
    object's seen points (its top seen from above covers it), grown by ``margin_m``. An object
    whose lowest seen points lie more than ``max_gap_m`` above the surface around it does not
    stand on it (held, or on another object) and gets no pad. (A real sensor's masks leave out
    an object's lowest centimetre: the segmenter takes only what stands above the support's depth
    noise, 11 mm on cups-rgbd, whose ball's lowest masked points are 16 mm above the ring.)
    Returns the pads and, per object without one, why."""
    case, n = ctx.case, ctx.time_info.n_frames
    cameras = read_cameras(ctx.stage, n)
    depth_of = metric_depth_reader(ctx.stage, case, cache=8)
    layer = read_masks(ctx.stage, n)
    hand_of = functools.partial(layer.mask, INTERACTOR) if layer.has(INTERACTOR) else (lambda t: None)
    pads, skipped = [], {}
    for spec in case.config.objects:
        masks = layer.track(spec.name)
        area = np.array([0 if m is None else int(m.sum()) for m in masks])
        masks = [m if a >= 50 else None for m, a in zip(masks, area, strict=True)]
        if not np.any(area >= 50):
            skipped[spec.name] = "never visible"
            continue
        touched = first_contact(masks, hand_of, depth_of, n)
        clear = np.flatnonzero(area >= max(50, 0.5 * np.percentile(area[area >= 50], 90)))
        frames = [int(t) for t in clear if t < touched]
        if not frames:
            skipped[spec.name] = "touched before it is clearly seen"
            continue
        occluders = functools.partial(layer.occluders, spec.name, grow_px=3)
        height = ring_height(occluders, [(t, 1.0) for t in frames], masks, depth_of, cameras, count=count)
        seen = []
        for t in [frames[i] for i in np.unique(np.linspace(0, len(frames) - 1, min(count, len(frames))).astype(int))]:
            seen.append(
                masked_world_points(depth_of(t), masks[t], cameras.K[t], cameras.world_from_cv[t], erode_px=2)[0]
            )
        pts = np.concatenate(seen)
        pts = pts[pts[:, 2] > height + 0.005]
        if len(pts) < 50:
            skipped[spec.name] = "too few points above the surface around it"
            continue
        gap = float(np.percentile(pts[:, 2], 2)) - height
        if gap > max_gap_m:
            skipped[spec.name] = (
                f"its lowest points are {1000 * gap:.0f} mm above the surface around it (held, or on another object)"
            )
            continue
        pads.append(SupportPad(spec.name, height, _footprint(pts[:, :2], margin_m, cell_m), cell_m))
    return pads, skipped


def run(ctx: StageContext) -> None:
    cfg = ctx.config.tsdf
    points, colors, normals, used, carved = fuse_static(
        ctx,
        voxel_m=cfg.voxel_m,
        frame_stride=cfg.frame_stride,
        margin_px=cfg.mask_margin_px,
        depth_max_m=cfg.depth_max_m,
        carve_m=cfg.carve_m,
    )
    pads, no_pad = support_pads(ctx, margin_m=cfg.pad_margin_m) if cfg.pad_margin_m > 0 else ([], {})
    points, colors, normals, padded = lay_pads(points, colors, normals, pads)
    filled = fill_support_holes(points)
    if len(filled):  # colored by their nearest fused neighbors, like any other point
        colors = np.concatenate([colors, transfer_colors(filled, points, colors)])
        points = np.concatenate([points, filled])
        normals = np.concatenate([normals, np.tile([0.0, 0.0, 1.0], (len(filled), 1))])
    wrapped = wrap_collider(points, normals, pads, cfg)
    vertices, faces = wrapped[:2]
    frame_colors = sensor_frame_colors(ctx, cfg)
    with tempfile.TemporaryDirectory() as tmp:
        parts, textured = textured_parts(ctx, vertices, faces, points, colors, frame_colors, cfg, Path(tmp))
        collision = MeshData(vertices=vertices, faces=faces)
        author_scene(ctx, parts, collision, Lighting.unlit(), support={p.name: p.height_m for p in pads})
    ctx.record(
        fused_frames=used,
        fused_points=int(len(points)),
        support_hole_points=int(len(filled)),
        carved_points=carved,
        **collider_record(pads, no_pad, padded, wrapped),
        **textured,
    )
