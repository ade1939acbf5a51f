"""The ``silhouette`` trajectory backend: the object stage's mesh tracked against its masks by
render and compare, for videos without depth (capture ``sfm``).

1. **Start.** Frame 0's pose is the object stage's default pose (fitted to the resting
   silhouettes and rested on the scene). Where that pose holds the object clear (``settle_m``)
   of the support and of any object under it (in the hand at the start), a free fit from it is
   taken when it matches the first mask better by ``start_gain`` (deepac-cat-rgb: the default
   24 deg off the truth, the fit 1.6).
2. **Hold.** An object rests while the mask does not say otherwise: when the last pose's
   silhouette still overlaps the frame's mask (outside the interactor and other objects, which may
   hide it) within ``hold_drop`` of the IoU it had when it was set, the pose holds. A hand over a
   resting object hides part of its mask, not the overlap of the rest.
3. **Track.** Otherwise the 6-DoF pose is fitted to the mask (Nelder-Mead on the silhouette IoU,
   ``geometry.silhouette.fit_free``, ``maxfev`` evaluations) from the last pose and from a
   constant-velocity prediction, the better kept, a pose below the support plane penalized
   (``SINK_COST_PER_M``); an object resting on the support is also refitted standing on it, its
   tilt kept (``_slid``), which is kept unless the free fit is better by ``LIFT_MARGIN`` (pushed or
   turned in place, not lifted); a given mesh's (not a proxy's) is then refined with its outline asked
   onto the frame's edges (``edge_weight``, ``geometry.silhouette.fit_edges``: deepac-cat-rgb's
   poses within 1 cm and 5 deg of the truth in 26 of 31 frames, 21 on the mask alone). A frame
   whose mask is missing or too small, or whose best IoU is under ``min_iou``, or whose fit moves
   the object faster than ``max_speed_m_s`` since its last tracked frame, or swells its
   silhouette over twice the mask (``SWELL``), is lost: the pose holds (confidence 0), and frames
   lost between tracked ones are interpolated on SE(3) (confidence 0.5). The color posterior is
   left out where it would pull the object toward the camera (``NEARER``) or lights so much
   around it that the first pose overlaps it poorly (``BROAD``).
4. **Rest on the support.** When the object holds still again for ``settle_frames`` frames with its
   lowest point within ``settle_m`` of the support, it is set down: turned onto its nearest stable
   face (the convex hull's face nearest its center of mass facing down), lowered onto the support,
   and its position and yaw refitted standing (``fit_standing``), for the rest of the hold.

Confidence is the silhouette IoU of the pose (0 lost, 0.5 interpolated). A convex mesh's
silhouette, and a proxy's (a category primitive: a mug's handle loop is not worth its triangles),
is its projected hull's.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable

import cv2
import numpy as np
import trimesh
from scipy.spatial import ConvexHull

from rose_usd.core import se3
from rose_usd.core.pinhole import project, projected_box, silhouette
from rose_usd.core.raster import fill_convex
from rose_usd.geometry.mesh import decimate
from rose_usd.geometry.silhouette import (
    ColorPosterior,
    View,
    crop_view,
    fit_edges,
    fit_free,
    fit_standing,
    iou,
    is_convex,
)
from rose_usd.layers.masks import read_masks
from rose_usd.layers.objects import default_pose, is_proxy, visual_mesh
from rose_usd.layers.scene import support_heights
from rose_usd.layers.world import read_cameras
from rose_usd.progress import progress
from rose_usd.stage_api import StageContext
from rose_usd.trajectory.author import author_trajectory, fill_gaps
from rose_usd.trajectory.colour_turns import colour_consistent
from rose_usd.trajectory.rests import rest_poses, stable_down


def run(ctx: StageContext) -> None:
    cfg, case, n = ctx.config.silhouette, ctx.case, ctx.time_info.n_frames
    cameras = read_cameras(ctx.stage, n)
    layer = read_masks(ctx.stage, n, (case.height, case.width))
    pads = support_heights(ctx.stage)
    meshes = {spec.name: visual_mesh(ctx.stage, spec.name) for spec in case.config.objects}  # at their defaults
    facts, tracks = {}, {}
    for spec in case.config.objects:
        layer.require(spec.name)
        default = default_pose(ctx.stage, spec.name)
        mesh = meshes[spec.name]
        local = se3.transform_points(se3.invert(default), mesh.vertices)
        # a proxy's silhouette is its hull's (a mug's handle loop is not worth its triangles), and
        # its outline is not asked onto the image's edges: it is the object's shape only roughly
        proxy = is_proxy(ctx.stage, spec.name)
        convex = proxy or is_convex(local, mesh.faces)
        own = dataclasses.replace(cfg, edge_weight=0.0) if proxy else cfg
        if convex:  # its silhouette is its projected hull: the hull's vertices are all it takes
            hull = ConvexHull(local)
            remap = np.full(len(local), -1)
            remap[hull.vertices] = np.arange(len(hull.vertices))
            v, f = local[hull.vertices], remap[hull.simplices]
        else:
            tm = trimesh.Trimesh(local, mesh.faces, process=False)
            if len(tm.faces) > cfg.max_faces:
                tm = decimate(tm, cfg.max_faces, check=False)
            v, f = np.asarray(tm.vertices, float), np.asarray(tm.faces, np.int64)
        support_z = float(pads.get(spec.name, 0.0))
        others = [m.vertices for other, m in meshes.items() if other != spec.name]
        air = not _resting(mesh.vertices, others, support_z, cfg.settle_m)
        poses, conf, record = _track(ctx, spec.name, v, f, default, layer, cameras, support_z, own, convex, in_air=air)
        poses, record["colour_turns"] = colour_consistent(
            ctx.stage, spec.name, poses, layer.track(spec.name), cameras, case.rgb
        )
        record.update(convex=convex, edge_weight=own.edge_weight)
        tracks[spec.name] = (poses, conf)
        facts[spec.name] = record
    for name, rests in rest_poses(ctx, {name: poses for name, (poses, _) in tracks.items()}, measured=False).items():
        facts[name]["rests"] = rests
    for name, (poses, conf) in tracks.items():
        author_trajectory(ctx, name, poses, conf, "silhouette")
    ctx.record(objects=facts)


def _projected_box(pose: np.ndarray, v: np.ndarray, cameras, t: int, width: int, height: int):
    """The bounding box (x0, y0, x1, y1) of the posed mesh's projected vertices, clipped to the image."""
    return projected_box(se3.transform_points(pose, v), cameras.world_from_cv[t], cameras.K[t], width, height)


def _target(mask, posterior, color_weight: float):
    """What the silhouette is compared with: the mask, or (with a color posterior) a blend of the
    two: color_weight x (2 P(object | color) - 1, clipped to [0, 1]) + the rest x the mask."""
    if posterior is None:
        return mask, None
    # P(object | color) above even odds, stretched to [0, 1]: the surroundings' colors that the
    # object shares (a table's speckle) weigh nothing instead of a little everywhere
    soft = color_weight * np.clip(2.0 * posterior - 1.0, 0.0, 1.0)
    if mask is not None:
        soft = soft + (1.0 - color_weight) * mask.astype(np.float32)
    return soft >= 0.5, soft


def _view(layer, name, t, mask, cameras, cfg, *, soft=None, box=None, segmented=None, rgb=None) -> View:
    """The view of the target ``mask`` (and ``soft``) at frame t, cropped around ``box`` (the
    projected pose) joined by the ``segmented`` mask's box where it is near, else around ``mask``;
    with the frame's edges where ``rgb`` is given and ``edge_weight`` is on."""
    ignore = layer.occluders(name, t, mask.shape, grow_px=2)
    if box is not None and segmented is not None and segmented.any():
        ys, xs = np.nonzero(segmented)
        mbox = (xs.min(), ys.min(), xs.max() + 1, ys.max() + 1)
        # the mask joins the crop only where it is near the prediction (not a track run off
        # elsewhere); the posterior's target does not: it may hold look-alikes all over the frame
        if mbox[0] < box[2] + (box[2] - box[0]) and mbox[2] > box[0] - (box[2] - box[0]):
            box = (min(box[0], mbox[0]), min(box[1], mbox[1]), max(box[2], mbox[2]), max(box[3], mbox[3]))
    return crop_view(
        mask,
        ignore,
        cameras.K[t],
        cameras.world_from_cv[t],
        frame=t,
        max_side=cfg.max_side_px,
        box=box,
        soft=soft,
        gray=cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY) if rgb is not None and cfg.edge_weight > 0 else None,
    )


FIRST_IOU_FLOOR = 0.05
"""When the object's first pose overlaps its first mask less (an object fit that failed), the
confidences are the IoUs themselves, not relative to the first one."""


def _track(ctx, name, v, f, default, layer, cameras, support_z, cfg, convex, *, in_air: bool = False):
    """The object's poses (n, 4, 4, world), their confidence (n,) and what to record, frame by
    frame from ``default``: held, refitted, set down or lost (see the module's steps)."""
    n, case = ctx.time_info.n_frames, ctx.case
    mask_of = functools.partial(layer.mask, name)
    poses = np.repeat(default[None], n, axis=0)
    present = np.zeros(n, bool)
    conf = np.zeros(n)
    pose, ref_iou, velocity = default.copy(), None, np.eye(4)
    still, settled = 0, False
    fitted = held = lost = set_down = searched = kept_down = 0
    rejected = dict.fromkeys(("low", "fast", "swollen"), 0)
    last_seen, started_free = 0, False
    colors, base, first = None, None, None
    for t in progress(range(n), f"trajectory {name}: silhouettes", total=n):
        mask = mask_of(t)
        has_mask = mask is not None and mask.sum() >= cfg.min_pixels
        if colors is None and cfg.color_weight > 0 and has_mask:
            colors = _color_model(case, layer, name, t, mask, pose, v, f, cameras, cfg, convex)
            if colors is not None and not _posterior_agrees(
                colors, case, layer, name, t, mask, pose, v, f, cameras, cfg, convex
            ):
                colors = False  # the mask alone, for the whole video
        rgb = case.rgb(t)
        posterior = colors(rgb) if colors else None
        box = _projected_box(pose, v, cameras, t, case.width, case.height)
        if not has_mask and (posterior is None or box is None):
            poses[t], lost = pose, lost + 1
            continue
        if mask is None:
            mask = np.zeros((case.height, case.width), bool)
        binary, soft = _target(mask if has_mask else None, posterior, cfg.color_weight)
        near, segmented = (box if posterior is not None else None), (mask if has_mask else None)
        view = _view(layer, name, t, binary, cameras, cfg, soft=soft, box=near, segmented=segmented, rgb=rgb)
        now = iou([view], se3.transform_points(pose, v), f, convex=convex)
        if ref_iou is None and has_mask and in_air:
            held_up = _held_up(v, f, view, pose, now, cfg, convex)
            if held_up is not None:
                (pose, now), started_free = held_up, True
        if ref_iou is None:
            ref_iou, first, base = now, now, (now if now >= FIRST_IOU_FLOOR else 1.0)
        floor = cfg.min_iou * base
        if now >= max(floor, ref_iou - cfg.hold_drop * base):
            poses[t], conf[t], present[t], last_seen = pose, min(1.0, now / base), True, t
            held, still = held + 1, still + 1
            velocity = np.eye(4)
            if not settled and still >= cfg.settle_frames:
                down = _set_down(view, v, f, pose, support_z, cfg, convex)
                if down is not None:
                    pose, ref_iou = down
                    poses[t] = pose
                    settled, set_down = True, set_down + 1
            continue
        best, turned = _refit(v, f, view, pose, velocity, ref_iou, cfg, convex)
        searched += turned
        slid = _slid(view, v, f, pose, support_z, cfg, convex, best[0])
        if slid is not None and slid[1] >= best[1] - LIFT_MARGIN:  # pushed or turned on the support
            best, kept_down = slid, kept_down + 1
        reach = cfg.max_speed_m_s * (t - last_seen) / ctx.time_info.fps
        why = _why_lost(best, pose, floor, reach, has_mask and (v, f, cameras, t, case, mask, layer, name, convex))
        if why:
            poses[t], lost, rejected[why] = pose, lost + 1, rejected[why] + 1
            continue
        last_seen = t
        velocity = best[0] @ se3.invert(pose)
        pose, ref_iou = best[0], best[1]
        poses[t], conf[t], present[t] = pose, min(1.0, best[1] / base), True
        fitted, still, settled = fitted + 1, 0, False
    counts = {
        "held": held,
        "fitted": fitted,
        "lost": lost,
        "too_fast": rejected["fast"],
        "swollen": rejected["swollen"],
        "set_down": set_down,
        "turn_searches": searched,
        "kept_on_support": kept_down,
        "started_free": started_free,
    }
    return _finish(poses, present, conf, counts, bool(colors), first)


START_FEV = 3
"""The first frame's free fit (``_held_up``) runs this many times ``maxfev`` evaluations a start: it
runs once, from a pose that may be far off (a box turned 20 deg: 10.9 deg left at 160, 1.9 at 400)."""


LIFT_MARGIN = 0.02
"""Silhouette IoU by which a free 6-DoF refit of an object resting on the support must beat it
slid and turned on the support to be taken: a box turned in place under a hand fits a tilted pose
in the air as well as standing (default rotate-box-s204, rgb: tipped 50 deg, 4 cm up). At 0.01
realistic unstack-can-s300's base was lifted off (path error 0.57 -> 6.74 cm); at 0.03 the
carried cube of visp-cube-hand-rgb overlapped its masks less (mean IoU 0.742; 0.755 at 0.02, 0.759
without the standing refit)."""


TURN_GAIN = 0.005
"""Silhouette IoU by which a resting object's slide on the support must gain to leave the free
refit's yaw, and then to turn from its own: a mug pushed along (its handle half hidden) fits a few
degrees more turned frame after frame by a hair, and its yaw drifted 70 deg where the truth turned
14 (default push-mug-s203, rgb), while one turned in the hand is turned by the free refit."""


def _resting(world: np.ndarray, others: list[np.ndarray], support_z: float, gap_m: float) -> bool:
    """Whether an object at its default pose (world vertices) rests: its lowest point within
    ``gap_m`` of the support, or of the top of another object under it (a stack)."""
    low = float(world[:, 2].min())
    if low <= support_z + gap_m:
        return True
    lo, hi = world[:, :2].min(axis=0), world[:, :2].max(axis=0)
    for other in others:
        under = np.all(other[:, :2].min(axis=0) < hi) and np.all(other[:, :2].max(axis=0) > lo)
        if under and abs(low - float(other[:, 2].max())) <= gap_m:
            return True
    return False


def _held_up(v, f, view: View, pose, posed_iou: float, cfg, convex: bool):
    """For an object whose default ``pose`` is in the air (the object stage saw it held at the
    start, ``_resting``), the first frame's pose fitted free from it, as (pose, IoU), when that
    matches the view better by ``start_gain``; else None. An object resting at the start keeps its
    standing fit: the support tells its depth better than a silhouette does."""
    longer = dataclasses.replace(cfg, maxfev=START_FEV * cfg.maxfev)
    (fitted, score), _ = _refit(v, f, view, pose, np.eye(4), posed_iou, longer, convex)
    gain = _score(view, v, f, fitted, score, cfg, convex) - _score(view, v, f, pose, posed_iou, cfg, convex)
    return (fitted, score) if gain > cfg.start_gain else None


def _score(view: View, v, f, pose, pose_iou: float, cfg, convex: bool) -> float:
    """What a fit maximizes: its IoU less ``edge_weight`` times its outline's distance from edges."""
    if cfg.edge_weight <= 0:
        return pose_iou
    return pose_iou - cfg.edge_weight * view.edge_cost(se3.transform_points(pose, v), f, convex=convex)


def _why_lost(best: tuple, pose: np.ndarray, floor: float, reach: float, swell_args) -> str | None:
    """Why a refit (pose, IoU) is not taken from ``pose``: "low" (its IoU under ``floor``), "fast"
    (it moved more than ``reach`` [m]) or "swollen" (``_swollen(pose, *swell_args)``, where
    given); None when it is taken."""
    if best[1] < floor:
        return "low"
    if np.linalg.norm(best[0][:3, 3] - pose[:3, 3]) > reach:
        return "fast"
    return "swollen" if swell_args and _swollen(best[0], *swell_args) else None


SWELL = 2.0
"""A fit whose silhouette, outside what may hide the object, covers more than this many times the
frame's mask is lost: a broad color target (a clear pen's body on a wooden desk) pulls the track
toward the camera, where the silhouette swells over the target, while the mask keeps its size."""


def _swollen(pose, v, f, cameras, t, case, mask, layer, name, convex) -> bool:
    """Whether the posed object's silhouette, outside the frame's occluders, exceeds ``SWELL``
    times its mask (or reaches behind the camera)."""
    cam = se3.transform_points(se3.invert(cameras.world_from_cv[t]), se3.transform_points(pose, v))
    if cam[:, 2].min() <= 1e-3:
        return True
    sil = _frame_silhouette(pose, v, f, cameras, t, case, convex)
    seen = np.count_nonzero(sil & ~layer.occluders(name, t, mask.shape, grow_px=2))
    return seen > SWELL * max(np.count_nonzero(mask), 1)


def _frame_silhouette(pose, v, f, cameras, t, case, convex: bool) -> np.ndarray:
    """The posed object's silhouette in the whole frame t: a convex mesh's projected hull, else
    the mesh's."""
    if convex:
        return _hull_mask(pose, v, cameras, t, case)
    world = se3.transform_points(pose, v)
    return silhouette(world, f, cameras.world_from_cv[t], cameras.K[t], case.width, case.height, closed=True)


def _color_model(case, layer, name, t, mask, pose, v, f, cameras, cfg, convex) -> ColorPosterior | None:
    """The object's color posterior learned in frame ``t`` where the posed silhouette meets its
    mask (against the pixels around it), or None when too few pixels are inside."""
    sil = _frame_silhouette(pose, v, f, cameras, t, case, convex)
    inside, around = ColorPosterior.regions(sil & mask, layer.occluders(name, t, mask.shape, grow_px=2))
    if inside.sum() >= cfg.min_pixels:
        return ColorPosterior(case.rgb(t), inside, around)
    return None


NEARER = (0.7, 0.85)
"""The color posterior is followed only where, in the frame it was learned in, the blended target
scores the posed silhouette above the same object brought nearer the camera (to these fractions of
its depth): where the surroundings share the object's colors (a printed box on a checked cloth)
the target is broad, a larger silhouette overlaps more of it, and a track that follows it comes
toward the camera."""


BROAD = 0.75
"""The color posterior is followed only where, in the frame it was learned in, the blended target
scores the posed silhouette at least this fraction of what the mask alone does: a can whose
colors the cloth and clutter around it share (realistic lift-can: 0.47 of the mask's 0.985) lights
a target so broad that no pose overlaps it well, and every refit is lost."""


def _posterior_agrees(colors, case, layer, name, t, mask, pose, v, f, cameras, cfg, convex) -> bool:
    """Whether the blended target (color posterior and mask) is not broad (``BROAD``), prefers the
    posed object to the same object brought nearer the camera (``NEARER``), and a fit to it from
    the pose does not swell over the mask (``SWELL``: a clear pen's body takes the desk's colors,
    and a refit comes toward the camera, turned far from the pose, which the nearer poses alone
    do not reach)."""
    binary, soft = _target(mask, colors(case.rgb(t)), cfg.color_weight)
    box = _projected_box(pose, v, cameras, t, mask.shape[1], mask.shape[0])
    view = _view(layer, name, t, binary, cameras, cfg, soft=soft, box=box, segmented=mask)
    eye = cameras.world_from_cv[t][:3, 3]

    def score(k: float) -> float:
        moved = pose.copy()
        moved[:3, 3] = eye + k * (pose[:3, 3] - eye)
        return iou([view], se3.transform_points(moved, v), f, convex=convex)

    posed = score(1.0)
    alone = _view(layer, name, t, mask, cameras, cfg, box=box, segmented=mask)
    if posed < BROAD * iou([alone], se3.transform_points(pose, v), f, convex=convex):
        return False
    if posed <= max(score(k) for k in NEARER):
        return False
    (fitted, _), _ = _refit(v, f, view, pose, np.eye(4), posed, cfg, convex)
    return not _swollen(fitted, v, f, cameras, t, case, mask, layer, name, convex)


SINK_COST_PER_M = 10.0
"""Added to a refit's 1 - IoU per meter its object reaches below the support plane (z = 0): a thin
object's silhouette hardly tells its depth, and a pen closed on by fingers sank 10 cm into the desk."""


def _sinking(v: np.ndarray) -> Callable[[np.ndarray], float]:
    """The cost of a pose (4, 4) that puts the object's vertices ``v`` below z = 0."""

    def cost(pose: np.ndarray) -> float:
        return SINK_COST_PER_M * max(0.0, -float((v @ pose[2, :3] + pose[2, 3]).min()))

    return cost


def _refit(v, f, view: View, pose, velocity, ref_iou: float, cfg, convex: bool) -> tuple[tuple, int]:
    """The best 6-DoF fit (pose, IoU) to the view from the last pose, its constant-velocity
    prediction and the pose recentered on the mask, kept above the support plane (``_sinking``), and
    whether (1) or not (0) it searched turned starts because that fit fell under
    ``turn_search_below`` of ``ref_iou``."""
    sink = _sinking(v)
    best = None

    def fit(start):
        nonlocal best
        got, score = fit_free(
            v, f, [view], start, maxfev=cfg.maxfev, step_deg=4.0, step_shift=0.01, convex=convex, cost_extra=sink
        )
        if best is None or score - sink(got) > best[1] - sink(best[0]):
            best = (got, score)

    for start in (pose, velocity @ pose, _recentered(view, pose, v)):
        fit(start)
    turned = 0
    if best[1] < cfg.turn_search_below * ref_iou:
        # a fast turn (deepac-cat-rgb: 27 deg in one frame) is out of the simplex's reach:
        # start again from the best pose turned by +-turn_search_deg about each camera axis
        for start in _turned(best[0], view, np.radians(cfg.turn_search_deg)):
            fit(start)
        turned = 1
    return fit_edges(v, f, [view], best[0], cfg.edge_weight, maxfev=cfg.maxfev, convex=convex, cost_extra=sink), turned


def _finish(poses, present, conf, counts: dict, color_model: bool, first):
    """The tracked poses with the lost frames between tracked ones interpolated (confidence 0.5),
    their confidence and the record; all held at the start (confidence 0) when none was tracked."""
    n = len(poses)
    if not present.any():
        return poses, np.zeros(n), {"tracked": 0}
    filled, fill_conf = fill_gaps(poses, present)
    conf = np.where(present, conf, fill_conf)
    return (
        filled,
        conf,
        {
            **counts,
            "color_model": color_model,
            "score_first": None if first is None else round(float(first), 4),
            "confidence_mean": round(float(conf[present].mean()), 4),
        },
    )


def _hull_mask(pose, v, cameras, t, case) -> np.ndarray:
    """A convex mesh's silhouette in the whole frame: its projected vertices' hull."""
    cam = se3.transform_points(se3.invert(cameras.world_from_cv[t]), se3.transform_points(pose, v))
    uv = np.column_stack(project(cam, cameras.K[t]))
    return fill_convex(cv2.convexHull(uv.astype(np.float32)).reshape(-1, 2), case.width, case.height)


def _turned(pose: np.ndarray, view: View, angle: float) -> list[np.ndarray]:
    """The pose turned by +-``angle`` about each of the view's camera axes, about its own origin."""
    out = []
    cam_rot = view.world_from_cv[:3, :3]
    for axis in np.eye(3):
        for sign in (1.0, -1.0):
            turn = cam_rot @ cv2.Rodrigues(sign * angle * axis)[0] @ cam_rot.T
            out.append(se3.make_pose(turn @ pose[:3, :3], pose[:3, 3]))
    return out


def _recentered(view: View, pose: np.ndarray, v: np.ndarray) -> np.ndarray:
    """The pose moved, at its depth, so that its center projects onto the mask's centroid: a
    start from which the silhouette overlaps the mask again after a fast move."""
    ys, xs = np.nonzero(view.mask & ~view.ignore)
    if not len(xs):
        return pose
    cam_from_world = se3.invert(view.world_from_cv)
    center = se3.transform_points(cam_from_world @ pose, v.mean(axis=0)[None])[0]
    k = view.K
    target = np.array([(xs.mean() - k[0, 2]) / k[0, 0], (ys.mean() - k[1, 2]) / k[1, 1], 1.0]) * center[2]
    shift = view.world_from_cv[:3, :3] @ (target - center)
    moved = pose.copy()
    moved[:3, 3] += shift
    return moved


def _set_down(view, v, f, pose, support_z, cfg, convex):
    """The pose turned onto its stable face and standing on the support, position and yaw refitted;
    (pose, IoU) or None when the object is not near the support or standing fits worse."""
    world = se3.transform_points(pose, v)
    if not _resting(world, [], support_z, cfg.settle_m):
        return None
    standing = _standing(view, v, f, stable_down(v, pose) @ pose[:3, :3], world.mean(axis=0)[:2], support_z, convex)
    if standing[1] < iou([view], world, f, convex=convex) - 0.03:
        return None
    return standing


def _slid(view, v, f, pose, support_z, cfg, convex, free: np.ndarray):
    """For an object resting on the support (its lowest point within ``settle_m``), the pose slid
    on it, its tilt kept, as (pose, IoU); None when in the air. It takes the yaw of the free refit
    ``free`` unless a standing fit from its own yaw overlaps better by ``TURN_GAIN``, which turns
    only where that gains ``TURN_GAIN`` again: a free fit keeps an object's turn about the vertical
    well, the support its tilt and height."""
    world = se3.transform_points(pose, v)
    if not _resting(world, [], support_z, cfg.settle_m):
        return None
    at = world.mean(axis=0)[:2]
    spin = cv2.Rodrigues(np.array([0.0, 0.0, _yaw(free[:3, :3]) - _yaw(pose[:3, :3])]))[0]
    free_at = se3.transform_points(free, v).mean(axis=0)[:2]
    follows = _standing(view, v, f, spin @ pose[:3, :3], free_at, support_z, convex, steps=(0.01, 4.0), turn=False)
    moved = _standing(view, v, f, pose[:3, :3], at, support_z, convex, steps=(0.01, 4.0), turn=False)
    turned = _standing(view, v, f, pose[:3, :3], at, support_z, convex, steps=(0.01, 4.0))
    own = turned if turned[1] > moved[1] + TURN_GAIN else moved
    return own if own[1] > follows[1] + TURN_GAIN else follows


def _yaw(rot: np.ndarray) -> float:
    """The heading of a rotation's x axis (its z axis where x points up) about world +Z [rad]."""
    axis = rot[:, 0] if abs(rot[2, 0]) < 0.9 else rot[:, 2]
    return float(np.arctan2(axis[1], axis[0]))


def _standing(view, v, f, rot: np.ndarray, xy, support_z: float, convex: bool, steps=(None, 20.0), turn=True):
    """The object turned by ``rot`` standing on the support, its position (from ``xy``) and (with
    ``turn``) yaw fitted to the view (``fit_standing``, its first steps ``steps``: m, deg); (pose, IoU)."""
    turned = se3.transform_points(se3.make_pose(rot, np.zeros(3)), v)
    base = np.array([*turned[:, :2].mean(axis=0), turned[:, 2].min()])

    def shape(_size):
        return turned - base, f

    fit = fit_standing(
        shape,
        np.array([1.0]),
        [view],
        np.asarray(xy),
        support_z=support_z,
        free_size=np.array([False]),
        maxfev=120,
        convex=convex,
        step_m=steps[0],
        step_deg=steps[1],
        turn=turn,
    )
    return fit.pose(support_z) @ se3.make_pose(rot, -base), fit.iou
