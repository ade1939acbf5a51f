"""The sfm capture backend: cameras, gravity and a metric scale from RGB frames alone.

No depth, no imported tool: what a casual monocular video gives.

1. **Intrinsics**: cam_K.txt; else a field-of-view guess (``capture.fov_guess_deg``, with a
   warning), which structure from motion refines when the camera moves (``self-calibrated``).
2. **Cameras**, by how much the camera moves:
   - *static* (at least ``sfm.static_fraction`` of the first frame's corners stay within 0.5 px,
     ``capture.static``): every frame keeps the reference camera's pose;
   - *near-static* (the reference frame's corners move by less than ``sfm.near_static_motion`` of
     the image width over the whole video: a camera held still by hand): PnP against the corners
     of the reference frame that lie on the support plane (``capture.planar``);
   - *moving*: COLMAP structure from motion over at most ``sfm.keyframes`` keyframes
     (``capture.colmap``); the frames between keyframes are interpolated on SE(3).
3. **Gravity**: imu/gravity.txt, else perception/geocalib.json, else (moving camera) the support
   plane of the map's points under the prompted object (``capture.gravity``), else the vertical
   vanishing point of the reference frame's lines (``geometry.vanishing``), else a level camera
   pitched 30 deg down (``upright-prior``, a warning). Gravity from one image is then refined by
   the prompted object standing on the support (``sfm.level_by_object``, ``scale.level_by_object``).
4. **Scale** (``capture.scale``): the prompted object's silhouette in its prompt frame fitted by its
   mesh or its category's primitive standing on the support plane; the scale from ``mesh``,
   ``size-prior`` (``size_m``, else a metric mesh's largest side), ``category-prior`` or
   ``camera-height``, the most certain; all of them and their agreement recorded. The world layer
   says there is no metric depth (``rose:world:metricDepth``).

The world frame is the contract's: +Z up, the origin on the support plane under the prompted
object, +X the first camera's image-right made horizontal.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from rose_usd.capture.colmap import run_sfm
from rose_usd.capture.gravity import (
    GravityEstimate,
    Plane,
    gravity_from_geocalib,
    gravity_from_imu,
    gravity_from_planes,
    world_from_tracking,
)
from rose_usd.capture.intrinsics import resolve_K
from rose_usd.capture.planar import image_motion, track_planar
from rose_usd.capture.scale import (
    CAMERA_HEIGHT_M,
    ScaleCue,
    choose,
    fit_mesh,
    fit_primitive,
    level_by_object,
    prompt_silhouette,
)
from rose_usd.capture.static import still_fraction
from rose_usd.capture.world import author_world, prompted_objects, prompts_source
from rose_usd.case.config import Prompt
from rose_usd.core import se3
from rose_usd.core.grabcut import SEEDS, split_shared
from rose_usd.core.pinhole import resized_K
from rose_usd.errors import InputError
from rose_usd.geometry.silhouette import crop_view
from rose_usd.geometry.vanishing import up_from_lines, upright_prior
from rose_usd.progress import say
from rose_usd.stage_api import StageContext

PLAUSIBLE_HEIGHT_M = (0.05, 3.0)
"""The reference camera's height over the support a tabletop video can have [m]; outside, a warning."""

UNCERTAIN_GRAVITY_DEG = 10.0
"""Gravity measured less surely than this gets a warning (a guessed upright has its own)."""

_IMAGE_GRAVITY = ("vanishing-points", "upright-prior")
"""Gravity sources of a single image (not a map's plane, not a sensor): the object may refine them."""


def _prompted(ctx: StageContext):
    """The first object with a prompt (``capture.prompts`` over rose.toml's), or None."""
    return next(iter(prompted_objects(ctx)), None)


def _box(prompt: Prompt, width: int, height: int) -> tuple[float, float, float, float]:
    if prompt.box is not None:
        return prompt.box
    x, y = prompt.point
    r = 0.08 * max(width, height)
    return (max(0.0, x - r), max(0.0, y - r), min(width, x + r), min(height, y + r))


def _interpolate(poses: dict[int, np.ndarray], n: int) -> np.ndarray:
    """Poses of every frame from those of some: SE(3) interpolation between neighbours, held at the ends."""
    have = np.array(sorted(poses))
    out = np.zeros((n, 4, 4))
    for t in range(n):
        if t in poses:
            out[t] = poses[t]
            continue
        after, before = have[have > t], have[have < t]
        if len(before) and len(after):
            a, b = int(before[-1]), int(after[0])
            out[t] = se3.slerp_poses(poses[a], poses[b], (t - a) / (b - a))
        else:
            out[t] = poses[int(before[-1] if len(before) else after[0])]
    return out


def _up_from_image(ctx: StageContext, K: np.ndarray, ref: int) -> tuple[np.ndarray, float, str, dict]:
    """Up in the reference camera's axes from its lines, else the upright prior: (up, sigma deg, source, record)."""
    import cv2

    gray = cv2.cvtColor(ctx.case.rgb(ref), cv2.COLOR_RGB2GRAY)
    s = min(1.0, 640 / max(gray.shape))  # LSD's segments (and their length threshold) at a 640 px image
    small = cv2.resize(gray, None, fx=s, fy=s, interpolation=cv2.INTER_AREA) if s < 1 else gray
    est = up_from_lines(small, resized_K(K, s))
    if est is not None:
        return (
            est.up_cam,
            est.uncertainty_deg,
            "vanishing-points",
            {
                "vanishing": est.how,
                "vertical_segments": est.vertical_segments,
                "horizontal_segments": est.horizontal_segments,
            },
        )
    ctx.warn("no vanishing point in the reference frame's lines: gravity assumed level, pitched 30 deg down (a guess)")
    return upright_prior(30.0), 20.0, "upright-prior", {}


def _file_gravity(ctx: StageContext, poses: np.ndarray) -> GravityEstimate | None:
    folder = ctx.case.folder
    method = ctx.config.gravity.value
    imu, geocalib = folder / "imu" / "gravity.txt", folder / "perception" / "geocalib.json"
    if method in ("auto", "imu") and imu.is_file():
        return gravity_from_imu(imu, poses)
    if method in ("auto", "geocalib") and geocalib.is_file():
        return gravity_from_geocalib(geocalib, poses)
    if method in ("imu", "geocalib"):
        raise InputError(
            f"gravity = {method} but its file is missing", path=folder, hint="add it or choose gravity = auto"
        )
    return None


def run(ctx: StageContext) -> None:
    case, cfg = ctx.case, ctx.config
    K, k_source, warning = resolve_K(case, fov_guess_deg=cfg.fov_guess_deg)
    spec = _prompted(ctx)
    ref = spec.prompt.frame if spec is not None else 0
    record: dict = {}
    mask, hidden = _prompt_mask(ctx, spec)  # before the cameras: a box holding nothing stops here

    # ---------------------------------------------------------------- cameras (reference frame = tracking frame)
    motion, poses, points, K, k_source = _cameras(ctx, K, k_source, ref, record)
    if warning and k_source == "fov-guess":
        ctx.warn(warning)
    record["camera_motion"] = motion

    # ---------------------------------------------------------------- gravity and the support plane
    gravity, support, poses = _gravity_and_support(ctx, motion, poses, points, K, spec, ref, record)
    if motion == "moving" and float(support.normal @ poses[ref][:3, 3]) <= support.offset:
        # a map whose support plane is not under its camera is wrong, and so is its self-calibration
        ctx.warn(
            "structure from motion put the support plane above the camera: the camera is tracked against"
            " its support plane instead, with the intrinsics it had before"
        )
        record["sfm_rejected"] = "support plane above the camera"
        motion, points = "near-static", None
        K, k_source, _ = resolve_K(case, fov_guess_deg=cfg.fov_guess_deg)
        record["camera_motion"] = motion
        gravity, support, poses = _gravity_and_support(ctx, motion, None, None, K, spec, ref, record)
    up = gravity.up / np.linalg.norm(gravity.up)

    # ---------------------------------------------------------------- world frame (units) and scale
    anchor_pt = _anchor_on_plane(ctx, mask, poses[ref], K, support)
    world_from_track = world_from_tracking(up, support, anchor_pt, poses[0])
    world_units = np.einsum("ij,njk->nik", world_from_track, poses)
    if cfg.sfm.level_by_object and mask is not None and gravity.source in _IMAGE_GRAVITY:
        world_from_track, world_units, gravity = _level(
            spec, mask, K, gravity, world_from_track, world_units, poses, ref, record
        )
        if motion == "near-static" and not np.allclose(gravity.up, up):
            # the camera was tracked against the support as the one image put it: track it again
            # against the levelled support (tracking frame = the reference camera, 1 unit above
            # it), unless that keeps far fewer of the plane's corners
            again: dict = {}
            levelled = _track_near_static(ctx, K, spec, ref, gravity.up, again)
            first = {k: v for k, v in record.items() if k.startswith("planar_")}
            record["planar_tracked_levelled"] = again["planar_inliers_median"] >= 0.5 * first["planar_inliers_median"]
            if record["planar_tracked_levelled"]:
                record.update(again, planar_first=first)
                up, poses = gravity.up, levelled
                support = Plane(up, -1.0, 0, 0.0)
                anchor_pt = _anchor_on_plane(ctx, mask, poses[ref], K, support)
                world_from_track = world_from_tracking(up, support, anchor_pt, poses[0])
                world_units = np.einsum("ij,njk->nik", world_from_track, poses)
            else:
                record["planar_levelled_rejected"] = again
    cues, chosen, agreement = _scale(ctx, spec, mask, K, world_units[ref], record, hidden)
    world_from_camera = _author(ctx, world_units, world_from_track, K, k_source, gravity, chosen, cues)
    height = float(world_from_camera[ref, 2, 3])
    _summarize(ctx, motion, gravity, chosen, height)
    ctx.record(
        **record,
        gravity=gravity.source,
        gravity_uncertainty_deg=round(float(gravity.uncertainty_deg), 3),
        scale_source=chosen.name,
        meters_per_unit=chosen.meters_per_unit,
        scale_uncertainty=chosen.sigma,
        scale_cues={c.name: {"meters_per_unit": c.meters_per_unit, "sigma": c.sigma, **c.detail} for c in cues},
        scale_agreement=agreement,
        camera_height_m=round(height, 4),
        origin="prompt" if spec is not None else "view-center",
        metric_depth=False,
    )


def _summarize(ctx: StageContext, motion: str, gravity, chosen: ScaleCue, height: float) -> None:
    """The capture's one line (motion, gravity, scale and its source, camera height), and a warning
    when the camera's height above the support is not a tabletop video's."""
    if not PLAUSIBLE_HEIGHT_M[0] <= height <= PLAUSIBLE_HEIGHT_M[1]:
        ctx.warn(
            f"the camera comes out {height:.3g} m above the support, not a tabletop video's"
            f" {PLAUSIBLE_HEIGHT_M[0]}-{PLAUSIBLE_HEIGHT_M[1]} m: the gravity, the intrinsics or the scale is"
            " likely wrong (give cam_K.txt, size_m)"
        )
    if gravity.uncertainty_deg > UNCERTAIN_GRAVITY_DEG and gravity.source != "upright-prior":
        ctx.warn(
            f"gravity from {gravity.source} is uncertain (+-{gravity.uncertainty_deg:.0f} deg): the support may"
            " be tilted, and objects set down on it float or sink; give imu/gravity.txt, or film more of the"
            " table and the room's straight edges"
        )
    scale_from = chosen.name + (f" {chosen.detail['file']}" if "file" in chosen.detail else "")
    say(
        f"capture: {motion} camera, gravity from {gravity.source} (+-{gravity.uncertainty_deg:.1f} deg), "
        f"scale from {scale_from} (+-{100 * chosen.sigma:.0f} %): camera {height:.3f} m above the support"
    )


def _cameras(ctx: StageContext, K: np.ndarray, k_source: str, ref: int, record: dict):
    """How the camera moves and its poses (n, 4, 4; None when near-static, tracked with gravity),
    with the map's points (P, 3) when moving (else None), and K (3, 3) [px] and its source:
    (motion, poses, points, K, k_source)."""
    case, cfg = ctx.case, ctx.config
    n = case.n_frames
    still = still_fraction(case.rgb, n)
    record["still_corners"] = round(still, 3)
    poses = points = None
    if still >= cfg.sfm.static_fraction:
        motion, poses = "static", np.repeat(np.eye(4)[None], n, axis=0)
    else:
        moved = image_motion(case.rgb, n, ref)
        record["image_motion"] = round(moved, 4)
        motion = "near-static" if moved < cfg.sfm.near_static_motion else "moving"
    if motion == "moving":
        poses, points, K, k_source, sfm_record = _structure_from_motion(ctx, K, k_source, ref)
        record.update(sfm_record)
        if poses is None:
            ctx.warn("structure from motion made no model: the camera is tracked against its support plane instead")
            motion = "near-static"
    return motion, poses, points, K, k_source


def _gravity_and_support(ctx: StageContext, motion: str, poses, points, K: np.ndarray, spec, ref: int, record: dict):
    """Gravity, the support plane (in the tracking frame) and the poses (n, 4, 4; a near-static
    camera's tracked against that plane): (gravity, support, poses)."""
    n = ctx.case.n_frames
    gravity = _file_gravity(ctx, np.repeat(np.eye(4)[None], n, axis=0) if motion != "moving" else poses)
    if motion == "moving":
        gravity, support = _map_gravity(ctx, gravity, poses, points, K, spec, ref, record)
        return gravity, support, poses
    if gravity is None:
        up_cam, sigma, source, more = _up_from_image(ctx, K, ref)
        record.update(more)
        gravity = GravityEstimate(up_cam, source, None, [], sigma)
    # the reference camera 1 unit above the plane: the scale step sets the unit
    support = Plane(gravity.up, -1.0, 0, 0.0)
    if motion == "near-static":
        poses = _track_near_static(ctx, K, spec, ref, gravity.up, record)
    return gravity, support, poses


def _track_near_static(ctx: StageContext, K: np.ndarray, spec, ref: int, up_cam: np.ndarray, record: dict):
    """A near-static camera's poses (n, 4, 4) tracked against the support plane, the prompted
    object's box left out."""
    case = ctx.case
    exclude = None
    if spec is not None:
        exclude = np.zeros((case.height, case.width), bool)
        x0, y0, x1, y1 = (int(v) for v in _box(spec.prompt, case.width, case.height))
        exclude[y0:y1, x0:x1] = True
    poses, planar = track_planar(case.rgb, case.n_frames, ref, K, up_cam, exclude=exclude)
    record.update(planar)
    return poses


def _level(spec, mask, K, gravity, world_from_track, world_units, poses, ref: int, record: dict):
    """Gravity from one image's lines (or a guess) refined by the prompted object standing on the
    support: the tilt that lets its primitive fit its silhouette best. (world_from_track (4, 4),
    world_units (n, 4, 4), gravity), unchanged when there is no tilt."""
    tilt, record["level_by_object"] = level_by_object(spec, mask, K, world_units[ref], gravity.uncertainty_deg)
    if not np.allclose(tilt, np.eye(4)):
        world_from_track = tilt @ world_from_track
        world_units = np.einsum("ij,njk->nik", world_from_track, poses)
        # the refined up keeps its source and its sigma: a primitive's fit to one silhouette can
        # sit sharply in a wrong minimum (a can's, 38 deg off), so it narrows nothing
        gravity = GravityEstimate(world_from_track[2, :3], gravity.source, None, [], gravity.uncertainty_deg)
    return world_from_track, world_units, gravity


def _scale(ctx: StageContext, spec, mask, K: np.ndarray, world_from_cv_units: np.ndarray, record: dict, hidden=None):
    """The scale cues, the most certain of them and their agreement: (cues, chosen, agreement);
    a warning when the chosen one is a prior."""
    cues, fit_record = _scale_cues(ctx, spec, mask, K, world_from_cv_units, hidden)
    record["scale_fit"] = fit_record
    chosen, agreement = choose(cues)
    if chosen.name == "camera-height":
        ctx.warn(
            "no object's size could be used (a size_m, a metric mesh standing in its prompt frame's silhouette,"
            " a prompted object of a known category): the metric scale assumes the camera is 0.5 m above the"
            " support (+-50 %)"
        )
    elif chosen.name == "category-prior":
        ctx.warn(
            f"metric scale from the typical size of a {spec.category!r} (+-{100 * chosen.sigma:.0f} %):"
            " give size_m in rose.toml for a better one"
        )
    return cues, chosen, agreement


def _author(ctx: StageContext, world_units, world_from_track, K, k_source: str, gravity, chosen, cues) -> np.ndarray:
    """The world layer, the cameras scaled to meters by the chosen cue; world_from_camera (n, 4, 4) [m]."""
    scale = chosen.meters_per_unit
    world_from_camera = world_units.copy()
    world_from_camera[:, :3, 3] *= scale
    world_from_input = se3.make_pose(world_from_track[:3, :3], world_from_track[:3, 3] * scale)
    author_world(
        ctx,
        world_from_camera=world_from_camera,
        K=K,
        world_from_input=world_from_input,
        gravity_source=gravity.source,
        gravity_uncertainty_deg=gravity.uncertainty_deg,
        scale_source=chosen.name,
        scale_alpha=scale,
        intrinsics_source=k_source,
        metric_depth=False,
        scale_uncertainty=chosen.sigma,
        scale_cues=[(c.name, c.meters_per_unit, c.sigma) for c in cues],
    )
    return world_from_camera


# ---------------------------------------------------------------------------- moving camera


def _structure_from_motion(ctx: StageContext, K: np.ndarray, k_source: str, ref: int):
    """(poses of every frame in the map, map points, K, its source, record); poses None on failure."""
    case, cfg = ctx.case, ctx.config.sfm
    n = case.n_frames
    step = max(1, int(np.ceil(n / cfg.keyframes)))
    keys = sorted(set(range(0, n, step)) | {n - 1, ref})
    say(f"capture: structure from motion over {len(keys)} keyframes (COLMAP)")
    frames = [case.rgb(t) for t in keys]
    result = run_sfm(frames, K, fix_K=k_source == "file", max_side=cfg.max_side)
    record = {"keyframes": len(keys)}
    guessed = False  # the map made with the field-of-view guess held fixed
    if k_source != "file" and result is not None:
        result, guessed = _checked_focal(ctx, result, frames, K, record)
    if result is None or ref not in {keys[i] for i in result.poses}:
        record["sfm"] = "failed" if result is None else "reference frame not registered"
        return None, None, K, k_source, record
    poses = {keys[i]: p for i, p in result.poses.items()}
    record.update(
        sfm_registered=len(poses),
        sfm_models=result.models,
        sfm_points=int(len(result.points)),
        sfm_reprojection_px=round(result.reprojection_px, 3),
        sfm_seconds=round(result.wall_s, 1),
    )
    if k_source != "file" and not guessed:
        record["sfm_focal_px"] = round(float(result.K[0, 0]), 2)
        record["sfm_k1"] = round(result.distortion, 5)
        K, k_source = result.K, "self-calibrated"
    if len(poses) < len(keys):
        ctx.warn(f"structure from motion registered {len(poses)} of {len(keys)} keyframes; the others are interpolated")
    all_poses = _interpolate(poses, n)
    # normalize the map: the reference camera at the origin, its points about 1 unit away
    ref_inv = se3.invert(all_poses[ref])
    all_poses = np.einsum("ij,njk->nik", ref_inv, all_poses)
    points = se3.transform_points(ref_inv, result.points)
    unit = float(np.median(np.linalg.norm(points, axis=1))) or 1.0
    all_poses[:, :3, 3] /= unit
    return all_poses, points / unit, K, k_source, record


FOCAL_CHECK = 0.2
"""A self-calibrated focal length this far (relative) from the field-of-view guess is checked
(``_checked_focal``)."""
FOCAL_GAIN = 0.9
"""...and kept only where its map reprojects at most this share of the error of a map made with
the guess held fixed."""


def _checked_focal(ctx: StageContext, result, frames, K: np.ndarray, record: dict):
    """The map, and whether it holds the guess ``K`` fixed: a self-calibrated focal length far from the guess
    (``FOCAL_CHECK``) is kept only where it explains the keyframes clearly better than the guess
    (``FOCAL_GAIN``), registering as many; else the map made with the guess held fixed. A small
    baseline leaves the focal length free: the realistic suite's unstack-can-s300 (rgb)
    self-calibrated 244 px against a true 413 (the guess 416), and its world came out 17.6 deg
    and 152 % off."""
    f, guess = float(result.K[0, 0]), float(K[0, 0])
    if abs(f / guess - 1) <= FOCAL_CHECK:
        return result, False
    say(f"capture: the self-calibrated focal length {f:.0f} px is {f / guess - 1:+.0%} off the guess: checking it")
    fixed = run_sfm(frames, K, fix_K=True, max_side=ctx.config.sfm.max_side)
    record["sfm_focal_check"] = {
        "self_calibrated_px": round(f, 2),
        "reprojection_px": round(result.reprojection_px, 3),
        "guess_reprojection_px": None if fixed is None else round(fixed.reprojection_px, 3),
        "guess_registered": 0 if fixed is None else len(fixed.poses),
    }
    if (
        fixed is None
        or len(fixed.poses) < len(result.poses)
        or result.reprojection_px <= FOCAL_GAIN * fixed.reprojection_px
    ):
        return result, False
    ctx.warn(
        f"structure from motion's self-calibrated focal length ({f:.0f} px) is {f / guess - 1:+.0%} off the guess"
        f" ({guess:.0f} px) and its map reprojects no better than one with the guess held ({result.reprojection_px:.2f}"
        f" vs {fixed.reprojection_px:.2f} px): the camera moves too little to measure it, the guess is kept"
    )
    return fixed, True


MAP_PLANE_BAND = 0.02
"""Plane inliers lie this near the plane, in map units (the reference camera's points are about 1
unit away): COLMAP's points from a hand-held video scatter by about 1 % of their distance."""
MAP_PATCH_STEP = 0.05
"""A plane is its largest patch of inliers joined in steps of this many map units
(``fit_planes``'s ``connected_m``). On 7-Scenes' kitchen (200 frames, sensor K) the gravity error
in the first camera's frame: 9.6 deg without patches (band 0.01), 3.0 deg with them (band 0.02; with
0.015 or 0.025, 7.6 and 4.8 deg: the map's planes are that noisy, and the uncertainty recorded
is their scatter, ``disagreement_deg``)."""


def _map_gravity(ctx: StageContext, gravity, poses, points, K: np.ndarray, spec, ref: int, record: dict):
    """A moving camera's gravity (the file's, else the map's support plane under the prompted object,
    else the reference frame's lines) and the support plane among the map's points: (gravity, support)."""
    ref_pose = poses[ref]
    anchor = _map_anchor(points, ref_pose, K, spec, ctx.case.width, ctx.case.height)
    support = None
    if gravity is None:
        try:
            est = gravity_from_planes(
                points,
                poses,
                anchor=anchor,
                min_points=max(30, len(points) // 50),
                distance_m=MAP_PLANE_BAND,
                connected_m=MAP_PATCH_STEP,
            )
            gravity, support = est, est.support
        except InputError as exc:
            record["plane_gravity"] = exc.message
    if gravity is None:
        up_cam, sigma, source, more = _up_from_image(ctx, K, ref)
        record.update(more)
        gravity = GravityEstimate(ref_pose[:3, :3] @ up_cam, source, None, [], sigma)
    if support is None:
        support = _plane_along(gravity.up, points, anchor)
    return gravity, support


def _map_anchor(points, ref_pose, K, spec, width, height) -> np.ndarray | None:
    """A point of the map on the prompted object (the median depth of the points inside its box), or None."""
    if spec is None or points is None:
        return None
    x0, y0, x1, y1 = _box(spec.prompt, width, height)
    cam = se3.transform_points(se3.invert(ref_pose), points)
    front = cam[:, 2] > 1e-6
    u = K[0, 0] * cam[front, 0] / cam[front, 2] + K[0, 2]
    v = K[1, 1] * cam[front, 1] / cam[front, 2] + K[1, 2]
    cx, cy, hw, hh = 0.5 * (x0 + x1), 0.5 * (y0 + y1), 0.25 * (x1 - x0), 0.25 * (y1 - y0)
    inside = (np.abs(u - cx) < hw) & (np.abs(v - cy) < hh)
    if inside.sum() < 3:
        return None
    z = float(np.median(cam[front][inside, 2]))
    ray = np.array([(cx - K[0, 2]) / K[0, 0], (cy - K[1, 2]) / K[1, 1], 1.0])
    return se3.transform_points(ref_pose, (z * ray)[None])[0]


def _plane_along(up: np.ndarray, points: np.ndarray, anchor: np.ndarray | None) -> Plane:
    """The support plane with normal ``up`` among the map's points: the densest height band just
    under the anchor (or overall), its median height."""
    h = points @ up
    if anchor is not None:
        below = h[(h < anchor @ up - 0.005) & (h > anchor @ up - 0.35)]
        h = below if len(below) >= 20 else h
    hist, edges = np.histogram(h, bins=60)
    k = int(np.argmax(hist))
    band = h[(h >= edges[k] - 0.01) & (h <= edges[k + 1] + 0.01)]
    return Plane(up, float(np.median(band)), int(len(band)), 0.0)


# ---------------------------------------------------------------------------- origin and scale


MIN_PROMPT_PX = 30
"""A prompted object's GrabCut silhouette holds at least this many pixels, else the capture stops
with one line (a box on bare table: nothing in it to set the world's origin and scale by)."""


def _prompt_mask(ctx: StageContext, spec) -> tuple[np.ndarray | None, np.ndarray | None]:
    """The prompted object's silhouette in its prompt frame (GrabCut in the box, less what the
    other objects prompted on that frame take: ``core.grabcut.split_shared``), None without a
    prompt; and those other objects' pixels (None without any), where they may hide it. Raises
    ``InputError`` when the silhouette has under ``MIN_PROMPT_PX`` pixels."""
    if spec is None:
        return None, None
    case = ctx.case
    rgb = case.rgb(spec.prompt.frame)
    masks, boxes = {}, {}
    for other in [s for s in prompted_objects(ctx) if s.prompt.frame == spec.prompt.frame]:
        seeds = SEEDS if other.prompt.box is not None else 1  # a point's box says nothing of the extent
        masks[other.name] = prompt_silhouette(rgb, _box(other.prompt, case.width, case.height), seeds=seeds)
        boxes[other.name] = other.prompt.box
    split = split_shared(masks, boxes)
    mask = split.pop(spec.name)
    if mask.sum() < MIN_PROMPT_PX:
        raise InputError(
            f"GrabCut found {int(mask.sum())} px of {spec.name!r} inside its prompt on frame {spec.prompt.frame}:"
            " nothing to measure it by",
            path=prompts_source(ctx),
            hint="draw the box tightly around the object on a frame where it is visible",
        )
    hidden = np.any(list(split.values()), axis=0) if split else None
    return mask, hidden


def _anchor_on_plane(ctx: StageContext, mask, ref_pose: np.ndarray, K: np.ndarray, support: Plane) -> np.ndarray:
    """The origin: where the prompted object's silhouette's foot (``mask``) meets the support plane
    (or the first view's center without one), in the tracking frame."""
    case = ctx.case
    if mask is not None:
        ys, xs = np.nonzero(mask)
        u, v = float(np.median(xs)), float(np.percentile(ys, 98))
    else:
        u, v = (case.width - 1) / 2.0, (case.height - 1) / 2.0
        ctx.warn("no usable object prompt: the world origin is where the first view's center meets the support plane")
    ray = ref_pose[:3, :3] @ np.array([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], 1.0])
    origin = ref_pose[:3, 3]
    denom = support.normal @ ray
    if denom >= -1e-6:  # at or above the horizon: straight below the camera
        return support.project(origin)
    s = (support.offset - support.normal @ origin) / denom
    return origin + s * ray


def _scale_cues(ctx: StageContext, spec, mask, K: np.ndarray, world_from_cv_units: np.ndarray, hidden=None):
    """Every scale cue that can be measured, and what the fits found; ``hidden``: the pixels of the
    other prompted objects, which may hide this one (the fits neither reward nor punish there)."""
    height_units = float(world_from_cv_units[2, 3])
    cues = [ScaleCue("camera-height", CAMERA_HEIGHT_M[0] / max(height_units, 1e-9), CAMERA_HEIGHT_M[1])]
    record: dict = {"camera_height_units": round(height_units, 5)}
    if spec is None or mask is None or mask.sum() < 30:
        return cues, record
    view = crop_view(mask, hidden, K, world_from_cv_units, max_side=320)
    path = ctx.case.mesh_file(spec)
    mesh = _metric_mesh(path, spec) if path is not None else None
    # the object's size: size_m, else a metric mesh's largest side (the same measurement)
    size = {"size_m": float(spec.overrides["size_m"])} if "size_m" in spec.overrides else None
    if size is None and mesh is not None:
        size = {"size_m": round(float(np.ptp(mesh[0], axis=0).max()), 5), "from": "mesh"}
    prim = fit_primitive(spec, view, mask, K, world_from_cv_units)
    if prim is not None:
        record["primitive"] = {
            "kind": prim["kind"],
            "dims_units": [round(float(d), 5) for d in prim["dims"]],
            "iou": round(prim["iou"], 4),
        }
        fit_sigma = 0.05 + max(0.0, 0.9 - prim["iou"])  # a poor fit widens the measurement's error
        if size is not None:
            cues.append(
                ScaleCue(
                    "size-prior", size["size_m"] / prim["size_units"], fit_sigma, {**size, "iou": round(prim["iou"], 4)}
                )
            )
        cues.append(
            ScaleCue(
                "category-prior",
                prim["typical_size_m"] / prim["size_units"],
                float(np.hypot(prim["typical_sigma"], fit_sigma)),
                {"category": spec.category, "typical_size_m": prim["typical_size_m"], "source": prim["typical_source"]},
            )
        )
    if mesh is not None:
        fit = fit_mesh(*mesh, view, mask, K, world_from_cv_units)
        if fit is not None:
            record["mesh"] = {"rho_units_per_m": round(fit["rho"], 5), "iou": round(fit["iou"], 4)}
            if fit["iou"] >= 0.75:
                where = str(path.relative_to(ctx.case.folder)) if path.is_relative_to(ctx.case.folder) else str(path)
                cues.append(
                    ScaleCue(
                        "mesh",
                        1.0 / fit["rho"],
                        0.03 + max(0.0, 0.92 - fit["iou"]),
                        {"iou": round(fit["iou"], 4), "file": where},
                    )
                )
            else:
                ctx.warn(
                    f"the mesh of object {spec.name!r} stands poorly in its prompt frame's silhouette"
                    f" (IoU {fit['iou']:.2f}):"
                    " not used for the scale (held in the air?)"
                )
    return cues, record


def _metric_mesh(path: Path, spec):
    """The object's mesh file ``path`` (vertices in meters, up-aligned by mesh_up or its format's
    convention, faces) when its unit is known (``io.meshfile.file_unit``: not TRELLIS's unit
    cube), decimated for silhouettes; else None."""
    import trimesh

    from rose_usd.geometry.mesh import decimate
    from rose_usd.io.meshfile import file_unit, read_mesh_file

    raw = read_mesh_file(path)
    v = np.asarray(raw.vertices, float)
    extent = float(np.max(v.max(axis=0) - v.min(axis=0)))
    unit = file_unit(extent, bool(np.abs(v).max() <= 0.5 + 1e-3 and extent > 0.9), spec.overrides.get("mesh_units"))
    if unit.meters is None:
        return None
    v = v * unit.meters
    up = str(spec.overrides.get("mesh_up", "auto")).lower()
    if up == "auto":
        up = "y" if path.suffix.lower() in (".glb", ".gltf") else "z"
    axis = "xyz".index(up.lstrip("+-"))
    sign = -1.0 if up.startswith("-") else 1.0
    order = [(axis + 1) % 3, (axis + 2) % 3, axis]
    rot = np.zeros((3, 3))
    for row, col in enumerate(order):
        rot[row, col] = 1.0
    rot[2] *= sign
    if np.linalg.det(rot) < 0:
        rot[0] *= -1
    mesh = trimesh.Trimesh(v @ rot.T, raw.faces, process=False)
    if len(mesh.faces) > 1500:
        mesh = decimate(mesh, 1500, check=False)
    return np.asarray(mesh.vertices, float), np.asarray(mesh.faces, np.int64)
