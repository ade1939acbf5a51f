"""What an object's resting frames show, shared by the object backends: its masked points while
it rests before the interactor first touches it, cleaned and fused, the height of the surface
around it and what it stands on (the ground or another object)."""

from __future__ import annotations

import functools
import itertools
from dataclasses import dataclass

import numpy as np
import trimesh
from scipy.spatial import ConvexHull

from rose_usd.core import se3
from rose_usd.core.pinhole import masked_world_points, pixels_of, view_counts
from rose_usd.errors import InputError
from rose_usd.geometry.contact import first_contact, ring_height
from rose_usd.layers.masks import INTERACTOR, read_masks
from rose_usd.layers.scene import support_heights
from rose_usd.layers.world import depth_is_sensor
from rose_usd.progress import progress
from rose_usd.stage_api import StageContext


def masked_points(
    depth: np.ndarray, mask: np.ndarray, rgb: np.ndarray, K: np.ndarray, world_from_cv: np.ndarray, erode_px: int = 1
):
    """World points and sRGB colors of the mask's pixels with depth (mask eroded by ``erode_px``:
    its border pixels mix the object's depth with what is behind it). Pixels at a depth
    discontinuity are not all left out as well: that shrinks the object more than it helps."""
    pts, (v, u) = masked_world_points(depth, mask, K, world_from_cv, erode_px=erode_px)
    return pts, rgb[v, u]


def rest_frames(
    ref_frame: int, n: int, sample, tolerance_m: float, *, scale_drift: bool = False
) -> list[tuple[int, float]]:
    """Frames from ``ref_frame`` on in which the object is still where it was then, each with the
    ratio of its depth there to the reference frame's (1 for a sensor).

    ``sample(t)`` gives (depth, mask, K, world_from_cv) of frame t (None when the object is not
    seen). The object's points of the reference frame are projected into frame t; where they
    land on the object's mask, the depth must agree within ``tolerance_m`` for most of them. Newly
    revealed parts (the top of a stack's lower object, once the upper one is lifted) do not count
    as motion, and a hand covering part of the object only leaves fewer points to compare.
    With ``scale_drift`` (depth that is not a sensor's: MegaSaM's scale varies by a few % from
    frame to frame), the frame's median depth ratio (within 6 %) is divided out first."""
    depth, mask, K, pose = sample(ref_frame)
    ref, _ = masked_points(depth, mask, np.zeros((*mask.shape, 3), np.uint8), K, pose)
    ref = ref[:: max(1, len(ref) // 3000)]
    frames = []
    for t in range(ref_frame, n):
        got = sample(t)
        if got is None:
            continue
        depth, mask, K, pose = got
        u, v, z = pixels_of(ref, pose, K, mask.shape[1], mask.shape[0])
        inside = u >= 0
        u, v, zz = u[inside], v[inside], z[inside]
        d = depth[v, u]
        on = mask[v, u] & (d > 0)
        ratio = float(np.median(d[on] / zz[on])) if scale_drift and on.sum() >= 30 else 1.0
        if abs(ratio - 1.0) > 0.06:
            break  # moved along the view (or the depth jumped): not the same rest
        d = d / np.float32(ratio)
        unhidden = ~((d > 0) & (d < zz - tolerance_m))  # nothing (a hand) in front of the point
        if unhidden.sum() < 30:
            continue  # hidden: nothing to compare
        on_mask = float(np.mean(mask[v[unhidden], u[unhidden]]))
        on = unhidden & on
        agree = float(np.mean(np.abs(d[on] - zz[on]) < tolerance_m)) if on.sum() >= 30 else 0.0
        if on_mask < 0.6 or agree < 0.3:
            break  # moved
        if on_mask >= 0.93 and agree >= 0.6:
            frames.append((t, ratio))
    return frames


@dataclass
class RestingCloud:
    """What the object's resting frames show: its cleaned world points above the support with
    their sRGB colors, the frames they came from, and its masks (None where barely visible)."""

    points: np.ndarray
    colors: np.ndarray
    frames: list[int]
    masks: list
    often: np.ndarray
    """Per point: seen about as often as the points around it (``seen_voxels``); a footprint is
    drawn around these, not around the depth noise's tail."""
    toward: np.ndarray
    """Per point: the mean unit direction from it to the cameras that saw it (which way a wall faces)."""
    ground: float = 0.0
    """The height of the surface around the object [m] (0 = the world's support plane)."""
    views: tuple = ()
    """(depth, K, world_from_cv) of up to 16 resting frames, spread over the rest: what the
    camera saw past (``free_space_carve``)."""


def spread_frames(frames: list[int], count: int) -> list[int]:
    """Up to ``count`` of ``frames``, spread evenly from the first to the last."""
    return [frames[i] for i in np.unique(np.linspace(0, len(frames) - 1, min(count, len(frames))).astype(int))]


def resting_clouds(ctx: StageContext, cameras, depth_of) -> dict[str, RestingCloud]:
    """Every object's points while it rests before the interactor first touches it (all objects
    first: one may stand on another). InputError when an object is never clearly seen."""
    case, cfg, n = ctx.case, ctx.config, ctx.time_info.n_frames
    drifts = not depth_is_sensor(ctx.stage)
    layer = read_masks(ctx.stage, n, (case.height, case.width))
    pads = support_heights(ctx.stage)
    hand_of = functools.partial(layer.mask, INTERACTOR) if layer.has(INTERACTOR) else (lambda t: None)
    clouds = {}
    for spec in case.config.objects:
        layer.require(spec.name)
        folder = ctx.out_dir / "masks" / spec.name  # named in messages only
        masks, per_frame, visible = [], [], np.zeros(n)
        for t in progress(range(n), f"object {spec.name}: masked depth", total=n):
            mask = layer.mask(spec.name, t)
            visible[t] = 0 if mask is None else mask.sum()
            masks.append(mask if visible[t] >= 50 else None)
        if not np.any(visible >= 50):
            raise InputError(
                f"object {spec.name!r} is never visible (every mask is empty)",
                path=folder,
                hint="check its masks (segment stage) or its prompt",
            )
        clear = np.flatnonzero(visible >= 0.5 * np.percentile(visible[visible >= 50], 90))

        def sample(t, masks=masks):
            return None if masks[t] is None else (depth_of(t), masks[t], cameras.K[t], cameras.world_from_cv[t])

        touched = first_contact(masks, hand_of, depth_of, n)
        rests = [
            (t, r)
            for t, r in rest_frames(int(clear[0]), n, sample, cfg.rest_tolerance_m, scale_drift=drifts)
            if t < touched
        ]
        if not rests:
            raise InputError(
                f"object {spec.name!r} is never clearly visible",
                path=folder,
                hint="check its masks (segment stage) or its prompt",
            )
        frames = [t for t, _ in rests]
        typical = float(np.median([r for _, r in rests]))
        carve_at = set(spread_frames(frames, 16))
        views = []  # the resting views that carve the fused points (their depth read once)
        for t, ratio in rests:  # every frame's depth brought to the rest's typical scale
            depth = depth_of(t) * np.float32(typical / ratio)
            pts, cols = masked_points(depth, masks[t], case.rgb(t), cameras.K[t], cameras.world_from_cv[t])
            toward = (cameras.world_from_cv[t][:3, 3] - pts).astype(np.float32)
            per_frame.append((pts, cols, toward / np.maximum(np.linalg.norm(toward, axis=1, keepdims=True), 1e-9)))
            if t in carve_at:
                views.append((depth, cameras.K[t], cameras.world_from_cv[t]))
        if spec.name in pads:  # the scene laid its collider flat at this height under the object
            ground = pads[spec.name]
        else:
            occluders = functools.partial(layer.occluders, spec.name, grow_px=3)
            ground = ring_height(occluders, [(t, typical / ratio) for t, ratio in rests], masks, depth_of, cameras)
        pts, cols, toward = (np.concatenate(parts) for parts in zip(*per_frame))
        pts, cols, toward, often = clean_cloud(pts, cols, toward, cfg.voxel_m, ground + cfg.support_gap_m)
        keep = free_space_carve(pts, views)
        pts, cols, toward, often = pts[keep], cols[keep], toward[keep], often[keep]
        if len(pts) < 200:
            raise InputError(
                f"object {spec.name!r}: only {len(pts)} points above the support in {len(frames)} resting frames",
                path=folder,
                hint="look at masks/sheet.jpg: a mask off the object wants a prompt (prompt = { frame = 0, box ="
                " [x0, y0, x1, y1] } in its [[objects]]), a video that moves no object wants objects = [] in"
                " rose.toml; else check the depth",
            )
        clouds[spec.name] = RestingCloud(pts, cols, frames, masks, often, toward, ground, tuple(views))
    return clouds


def free_space_carve(
    points: np.ndarray,
    views: list,
    *,
    tolerance_m: float = 0.004,
    fraction: float = 0.3,
    min_views: int = 2,
    window: int = 3,
) -> np.ndarray:
    """Which points no view sees through (a mask): free-space carving.

    A sensor's flying pixels at a silhouette land a few mm off the surface, a few per frame, and
    fused over a rest they make a dense wall that outlier removal keeps (a strip 5-30 mm above a
    box's top edge lifts an object stacked on it that high). A point is dropped when, in
    at least ``min_views`` views and ``fraction`` of the views it falls in, even the nearest depth
    of the ``window`` x ``window`` pixels around it lies beyond it by ``tolerance_m``: that view saw past it. Things
    in front (a hand) only make depth nearer. ``views``: (depth, K, world_from_cv) of frames in
    which the object rests."""
    if not len(points) or not views:
        return np.ones(len(points), bool)
    through, _, observed = view_counts(points, views, tol_m=tolerance_m, window=window)
    return ~((through >= min_views) & (through >= fraction * observed))


def support_height(
    points: np.ndarray, others: list[np.ndarray], *, ground: float = 0.0, margin_m: float = 0.01
) -> float:
    """What the object stands on: the top of another object under its footprint (a stack), else
    the surface around it (``ground``), but never above the object's lowest seen points (their
    1st percentile: a real sensor's flying pixels at the silhouette fall a centimetre below the
    table, and the single lowest put cups-rgbd's ball 8 mm into it). Another object's points
    count when they lie under the object's footprint (grown by ``margin_m``) and no higher than
    its lowest seen point plus ``margin_m``."""
    lowest = float(np.percentile(points[:, 2], 1.0))
    lo, hi = points[:, :2].min(axis=0) - margin_m, points[:, :2].max(axis=0) + margin_m
    best = ground
    for other in others:
        under = other[np.all((other[:, :2] >= lo) & (other[:, :2] <= hi), axis=1) & (other[:, 2] <= lowest + margin_m)]
        if len(under) >= 30:
            best = max(best, float(np.percentile(under[:, 2], 95)))
    return min(best, lowest)


def seen_voxels(
    points: np.ndarray, values: np.ndarray, voxel_m: float, *, keep_fraction: float = 0.1, reach: int = 2
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The points fused over many frames, one per ``voxel_m`` voxel (the mean of its points and of
    their ``values`` (N, k): colors, directions to the camera), and which of them are seen often:
    at least ``keep_fraction`` as often as the most seen voxel within ``reach`` voxels of them.
    Returns (points, mean values (float), often).

    A surface seen in many frames fills its voxels many times over; the depth noise's tail and the
    registration's jitter put a few points per frame a few millimeters off it. A plain voxel
    downsample gives both one point each, so the fused wall becomes a slab as thick as the noise's
    extremes, and a footprint drawn around it lies on its outside: an object comes out a few
    millimeters too wide on the sides the camera saw. A voxel of the tail is
    seen a fraction as often as its neighbors, so a height field's footprint is drawn around the
    often seen voxels only (``outline`` of ``solid_from_points``). Where every voxel around is seen
    at most 3 times (one frame's pixels), all count as often seen.

    ``keep_fraction`` 0.1, not more: a top face's far edge is seen less often than its middle
    (voxels partly covered, the sensor's dropouts at depth edges), and a higher fraction (0.35)
    pulls the sides seen only as such edges a few millimeters in. The rarely seen points stay in
    the cloud: dropping them makes a revolved profile worse."""
    # voxels as one integer each, on a grid padded by ``reach`` so a neighbor is an offset away
    key = np.floor(points / voxel_m).astype(np.int64)
    lo = key.min(axis=0) - reach
    dims = key.max(axis=0) + reach - lo + 1
    ids, owner, count = np.unique(
        ((key[:, 0] - lo[0]) * dims[1] + (key[:, 1] - lo[1])) * dims[2] + (key[:, 2] - lo[2]),
        return_inverse=True,
        return_counts=True,
    )
    owner = owner.ravel()
    mean = (
        np.column_stack([np.bincount(owner, weights=points[:, a], minlength=len(ids)) for a in range(3)])
        / count[:, None]
    )
    values = np.asarray(values, dtype=float).reshape(len(points), -1)
    value = (
        np.column_stack([np.bincount(owner, weights=values[:, a], minlength=len(ids)) for a in range(values.shape[1])])
        / count[:, None]
    )
    # the most seen voxel around each: every offset looked up in the (sorted) voxel ids
    most = count.copy()
    steps = range(-reach, reach + 1)
    for dx, dy, dz in itertools.product(steps, steps, steps):
        other = ids + (dx * dims[1] + dy) * dims[2] + dz
        j = np.minimum(np.searchsorted(ids, other), len(ids) - 1)
        hit = ids[j] == other
        most[hit] = np.maximum(most[hit], count[j[hit]])
    often = (count >= keep_fraction * most) | (most <= 3)  # up to 3 (one frame's pixels): nothing to compare
    return mean, value, often


def clean_cloud(
    points: np.ndarray, colors: np.ndarray, toward: np.ndarray, voxel_m: float, above_m: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Points higher than ``above_m`` (the table is left out), one per voxel (``seen_voxels``),
    outliers and stray clusters dropped. ``toward``: each point's unit direction to its camera.
    Returns (points, sRGB8 colors, mean unit directions to the cameras, often seen)."""
    import open3d as o3d

    def inliers(pts: np.ndarray) -> np.ndarray:  # Open3D's statistical outlier test, as indices
        _, kept = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts)).remove_statistical_outlier(
            nb_neighbors=16, std_ratio=2.0
        )
        return np.asarray(kept, dtype=np.int64)

    keep = points[:, 2] > above_m
    pts, values, often = seen_voxels(points[keep], np.column_stack([colors[keep], toward[keep]]), voxel_m)
    cols = np.clip(values[:, :3] + 0.5, 0, 255).astype(np.uint8)
    toward = values[:, 3:] / np.maximum(np.linalg.norm(values[:, 3:], axis=1, keepdims=True), 1e-12)
    kept = inliers(pts)
    if len(kept) > 50:  # keep the largest cluster (stray mask pixels on the background)
        labels = np.asarray(
            o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts[kept])).cluster_dbscan(eps=3 * voxel_m, min_points=4)
        )
        if labels.max() >= 0:
            kept = kept[labels == np.bincount(labels[labels >= 0]).argmax()]
    pts, cols, toward, often = pts[kept], cols[kept], toward[kept], often[kept]
    # an often seen voxel alone among the rarely seen ones (a flying pixels' strip, seen by few
    # frames but each time) is an outlier of the often seen
    marked = np.flatnonzero(often)
    if len(marked) > 50:
        often[:] = False
        often[marked[inliers(pts[marked])]] = True
    return pts, cols, toward, often


def level_rotation(vertices: np.ndarray, faces: np.ndarray, *, max_tilt_deg: float = 6.0) -> np.ndarray:
    """The small rotation (3, 3) that sets an up-aligned closed mesh on its stable resting face.

    A generated mesh's up axis is the network's guess: a bottom a degree or two off level makes
    Newton tip the object onto it, and the object moves while it should rest. The
    mesh rests on the face of its convex hull nearest its center of mass (the solid's) among
    those facing within ``max_tilt_deg`` of down, when the center of mass projects into that
    face (its coplanar hull triangles): that face is turned to face straight down. The identity
    when no such face exists (a round bottom rests where it stands)."""
    hull = ConvexHull(vertices)
    normals, offsets = hull.equations[:, :3], hull.equations[:, 3]
    com = trimesh.Trimesh(vertices, faces, process=False).center_mass
    down = np.flatnonzero(normals[:, 2] < -np.cos(np.radians(max_tilt_deg)))
    if not len(down):
        return np.eye(3)
    dist = -(normals[down] @ com + offsets[down])  # center of mass to each face's plane
    i = down[int(np.argmin(dist))]
    n = normals[i]
    foot = com + dist.min() * n  # the center of mass projected onto that plane
    same = np.flatnonzero(
        (normals @ n > np.cos(np.radians(0.5))) & (np.abs(offsets - offsets[i]) < 1e-4 * np.ptp(vertices, axis=0).max())
    )
    tris = vertices[hull.simplices[same]]
    inside = (trimesh.triangles.points_to_barycentric(tris, np.broadcast_to(foot, (len(same), 3))) >= -1e-9).all(axis=1)
    if not inside.any():
        return np.eye(3)
    return se3.turn_down(n, tiny=1e-12)
