"""The quality gate: re-render every frame of the composed stage with Mitsuba from the stage's own
cameras and compare it with the input video by SSIM (the paper's Eq. 4); load the stage in Newton
and check that objects at rest stay at rest; check that every collider is a closed 2-manifold."""

from __future__ import annotations

import json
from concurrent.futures import ThreadPoolExecutor

import cv2
import numpy as np
from pxr import Usd, UsdGeom, UsdPhysics

from rose_usd.core import se3
from rose_usd.core.watertight import collider_problems
from rose_usd.gate.report import write_report
from rose_usd.gate.ssim import masked_ssim
from rose_usd.io.images import write_rgb
from rose_usd.layers.gate import read_gate
from rose_usd.layers.masks import INTERACTOR, Masks, read_masks
from rose_usd.layers.objects import object_paths
from rose_usd.layers.trajectory import object_poses
from rose_usd.layers.world import read_cameras
from rose_usd.progress import progress, say
from rose_usd.sim.resting import rest_checks, resting_frames
from rose_usd.stage_api import StageContext
from rose_usd.usd import paths, schema, tokens
from rose_usd.usd.geom import read_mesh


def _interactor_mask(masks: Masks | None, t: int, dilate_px: int) -> np.ndarray | None:
    """The interactor's mask at frame t grown by ``dilate_px``, None where there is none."""
    mask = masks.mask(INTERACTOR, t) if masks is not None and masks.has(INTERACTOR) else None
    if mask is None:
        return None
    if dilate_px > 0:
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * dilate_px + 1, 2 * dilate_px + 1))
        mask = cv2.dilate(mask.astype(np.uint8), kernel) > 0
    return mask


def _geometry_check(stage: Usd.Stage) -> list[str]:
    """One line per collider mesh that is not a closed, consistently wound, positive-volume mesh."""
    problems = []
    for prim in stage.Traverse():
        if not (prim.IsA(UsdGeom.Mesh) and prim.HasAPI(UsdPhysics.CollisionAPI)):
            continue
        mesh = read_mesh(prim, world=False)
        issues = collider_problems(mesh.vertices, mesh.faces)
        if issues:
            problems.append(f"{prim.GetPath()}: {', '.join(issues)}")
    return problems


def _contact_sheets(ctx: StageContext, report_dir) -> None:
    """``report/masks.jpg`` (each object's mask and the interactor's over the video) and
    ``report/object.jpg`` (each object's mesh at its trajectory pose, its mask's outline red)."""
    from rose_usd.render.sheets import mask_sheet, object_sheet, sheet_every

    every = sheet_every(ctx.time_info.n_frames)
    mask_sheet(ctx.case, ctx.stage, report_dir / "masks.jpg", every=every)
    object_sheet(ctx.case, ctx.stage, report_dir / "object.jpg", every=every)


def run(ctx: StageContext) -> None:
    cfg, stage, n = ctx.config, ctx.stage, ctx.time_info.n_frames
    from rose_usd.render.from_usd import StageRenderer

    objects = object_paths(stage)
    renderer = StageRenderer(stage, labels={path: k + 1 for k, path in enumerate(objects.values())})
    frames = list(range(0, n, max(1, cfg.frame_stride)))
    report_dir = ctx.side_dir("report")
    # the rest check (Newton on Warp: one core, mostly Python between kernel launches) runs beside
    # the renders (Mitsuba's own threads); both only read the stage, and neither's result depends
    # on the other's timing
    with ThreadPoolExecutor(max_workers=1) as pool:
        resting = pool.submit(_rest, stage, objects, cfg, n, ctx.time_info.fps) if cfg.physics and objects else None
        ssim, keep, track_iou, rendered_share = _render_and_compare(ctx, renderer, frames, report_dir, list(objects))
        rest, not_resting = resting.result() if resting else ([], [])
    worst = int(np.nanargmin(ssim))
    ssim_mean = float(np.nanmean(ssim))
    track = _track_summary(track_iou, cfg, ctx.time_info.fps)
    physics_ok = all(r.max_displacement_m < cfg.physics_threshold_m for _, r in rest)
    geometry_problems = _geometry_check(stage)
    passed = _author_gate(
        ctx, frames, ssim, renderer.scene.variant, rest, physics_ok, track, geometry_problems, not_resting=not_resting
    )
    if not_resting:
        ctx.warn(
            f"rest check: {', '.join(repr(n) for n in not_resting)} rest(s) in no frame of the video (moved or"
            " touched in every one): not checked"
        )
    _rest_warnings(ctx, rest, cfg.physics_threshold_m, n)

    summary = {
        "passed": passed,
        "ssim_mean": ssim_mean,
        "ssim_min": float(np.nanmin(ssim)),
        "ssim_min_frame": worst,
        "ssim_threshold": cfg.ssim_threshold,
        "render_variant": renderer.scene.variant,
        "frames_rendered": len(frames),
        "rendered_share": round(rendered_share, 4),
        "physics": [{"frame": t, **r.__dict__} for t, r in rest],
        "physics_not_resting": not_resting,
        "physics_passed": physics_ok if cfg.physics else None,
        "track": track,
        "geometry_problems": geometry_problems,
    }
    (report_dir / "gate.json").write_text(json.dumps(summary, indent=2) + "\n")
    result = read_gate(ctx.stage)
    verdict = "gate PASS" if passed else "gate FAIL: " + "; ".join(result.failures() if result else [])
    write_report(report_dir, ssim, cfg.ssim_threshold, keep, verdict)
    _contact_sheets(ctx, report_dir)
    for name, iou in track["iou"].items():
        if iou is not None and iou < cfg.track_iou_threshold:
            ctx.warn(
                f"object {name!r}: its re-render overlaps its masks by IoU {iou:.2f} on average"
                f" (threshold {cfg.track_iou_threshold}): its shape or trajectory does not follow the video"
            )
        window = track["worst_window"][name]
        if window is not None and window["iou"] < cfg.track_window_iou:
            ctx.warn(
                f"object {name!r}: its re-render overlaps its masks by IoU {window['iou']:.2f} over frames"
                f" {window['frames'][0]}-{window['frames'][1]} (threshold {cfg.track_window_iou} over"
                f" {cfg.track_window_s:g} s): its trajectory has left the object there"
            )
    ctx.record(
        ssim_mean=round(ssim_mean, 5),
        passed=passed,
        physics={f"{r.name}@{t}": round(r.max_displacement_m, 6) for t, r in rest},
        track_iou={k: None if v is None else round(v, 4) for k, v in track["iou"].items()},
    )


def _rest_warnings(ctx: StageContext, rest: list, threshold_m: float, n: int) -> None:
    """A warning per rest check an object failed: how far it moved from which frame, and how its
    pose there stands: how tall (against its first checked rest: a tilt shows), its lowest point
    over (or into) the support plane z = 0. The summary's "rest Marker 39.35 mm (frames 0, 153)" told a new user
    neither which frame failed nor why (a pen fitted 15 deg off level, one end 4.7 cm up)."""
    first = {}
    for t, r in rest:
        first.setdefault(r.name, t)
    for t, r in rest:
        if r.max_displacement_m < threshold_m:
            continue
        poses = object_poses(ctx.stage, r.name, n)
        mesh = read_mesh(ctx.stage.GetPrimAtPath(paths.object_collision(r.name)), world=False)
        z_t, z_0 = (se3.transform_points(poses[k], mesh.vertices)[:, 2] for k in (t, first[r.name]))
        low = float(z_t.min())
        tall = (1e3 * float(np.ptp(z_t)), 1e3 * float(np.ptp(z_0)))
        where = f", {tall[0]:.0f} mm tall there, {tall[1]:.0f} mm at its rest at frame {first[r.name]}"
        where = where if t != first[r.name] else ""
        ctx.warn(
            f"rest check: {r.name!r} moved {1e3 * r.max_displacement_m:.0f} mm (turned {r.max_rotation_deg:.0f}"
            f" deg) in {r.simulated_s:.2f} s from its pose at frame {t}{where}, its lowest point"
            f" {1e3 * abs(low):.1f} mm {'over' if low >= 0 else 'into'} the support (z = 0): that pose does not"
            " rest (report/object.jpg shows it over the video)"
        )


def _rest(stage, objects: dict[str, str], cfg, n: int, fps: float) -> tuple[list, list[str]]:
    """The rest check from each object's first and last resting frame (``sim.resting``; the
    frames it is still from the first count as resting, touched or not): a list of (frame,
    ``RestResult``), and the objects resting in no frame."""
    from rose_usd.sim.rest import simulate_rest

    poses = {name: object_poses(stage, name, n) for name in objects}
    checks = rest_checks(resting_frames(stage, objects, n), fps)
    out = []
    for check in checks:
        results = simulate_rest(
            stage,
            {name: objects[name] for name in check.resting},
            duration_s=cfg.physics_duration_s,
            dt_s=cfg.physics_dt_s,
            iterations=cfg.physics_iterations,
            poses={name: poses[name][check.frame] for name in check.resting},
            aside={name: path for name, path in objects.items() if name not in check.resting},
        )
        out += [(check.frame, r) for r in results if r.name in check.names]
    return out, [name for name in objects if not any(name in c.names for c in checks)]


def _render_and_compare(
    ctx: StageContext, renderer, frames: list[int], report_dir, names: list[str]
) -> tuple[np.ndarray, dict, dict, float]:
    """SSIM per frame of the re-render against the video (NaN where not rendered); the pictures
    of four frames spread over the video and of the worst: t -> (original, rendered, SSIM map,
    excluded pixels); per object (``names``, render labels 1, 2, ... in that order) the IoU
    per rendered frame of its visible re-rendered pixels with its mask (``_track_iou``); and the
    mean share of the image rendered a frame (a fixed camera's frames re-render only the window
    its objects are in: ``render.fixed_view``)."""
    cfg, stage, case, n = ctx.config, ctx.stage, ctx.case, ctx.time_info.n_frames
    camera = read_cameras(stage, n)
    if (camera.width, camera.height) != (case.width, case.height):
        say(f"gate: the stage's camera is {camera.width}x{camera.height}, the video {case.width}x{case.height}")

    masks = read_masks(stage, n) if stage.GetPrimAtPath(paths.MASKS) else None
    track = {name: np.full(n, np.nan) for name in names} if cfg.track and masks is not None else {}

    from rose_usd.render.fixed_view import FixedView, fixed_view_applies

    fixed, shares = None, []
    if fixed_view_applies(renderer.scene, camera.world_from_cv[frames], camera.K[frames]):
        fixed = FixedView(
            renderer.scene,
            camera.world_from_cv[frames[0]],
            camera.K[frames[0]],
            case.width,
            case.height,
            spp=cfg.spp,
            moving=renderer.animated,
        )

    def render(t: int) -> tuple[np.ndarray, np.ndarray | None]:
        """The re-render at frame t and, for the track check, its labels from the same samples."""
        renderer.pose_at(t)
        if fixed is not None:
            rgb, labels = fixed.render_srgb8_and_labels(seed=t)
            shares.append(fixed.window_share())
            return rgb, labels if track else None
        args = (camera.world_from_cv[t], camera.K[t], case.width, case.height)
        if track:
            return renderer.scene.render_srgb8_and_labels(*args, spp=cfg.spp, seed=t)
        return renderer.scene.render_srgb8(*args, spp=cfg.spp, seed=t), None

    def exclude(t: int) -> np.ndarray | None:
        return _interactor_mask(masks, t, cfg.interactor_dilate_px) if cfg.exclude_interactor else None

    ssim = np.full(n, np.nan)
    keep = {}
    sample_frames = set(np.linspace(0, len(frames) - 1, 4).round().astype(int).tolist())
    for i, t in enumerate(progress(frames, "gate render", total=len(frames))):
        (rendered, labels), original, left_out = render(t), case.rgb(t), exclude(t)
        ssim[t], ssim_map = masked_ssim(original, rendered, left_out)
        if track:
            for k, name in enumerate(names):
                track[name][t] = _track_iou(masks, name, t, labels == k + 1, left_out, cfg.track_min_pixels)
        if cfg.save_frames:
            write_rgb(report_dir / "frames" / f"{t:06d}.png", rendered)
        if i in sample_frames:
            keep[t] = (original, rendered, ssim_map, left_out)
    worst = int(np.nanargmin(ssim))
    if worst not in keep:
        rendered, left_out = render(worst)[0], exclude(worst)
        keep[worst] = (case.rgb(worst), rendered, masked_ssim(case.rgb(worst), rendered, left_out)[1], left_out)
    return ssim, keep, track, float(np.mean(shares[: len(frames)])) if shares else 1.0


def _track_iou(masks: Masks, name: str, t: int, seen: np.ndarray, left_out, min_pixels: int) -> float:
    """IoU of an object's visible re-rendered pixels ``seen`` with its mask at frame t, the
    interactor's (``left_out``) not counted; NaN where the mask has fewer than ``min_pixels``."""
    mask = masks.mask(name, t) if masks.has(name) else None
    if mask is None:
        return float("nan")
    if left_out is not None:
        mask, seen = mask & ~left_out, seen & ~left_out
    if np.count_nonzero(mask) < min_pixels:
        return float("nan")
    return float(np.count_nonzero(mask & seen) / np.count_nonzero(mask | seen))


def _track_summary(track: dict[str, np.ndarray], cfg, fps: float) -> dict:
    """Per object its mean IoU (None without masked frames), frame count and worst window (the
    lowest mean over ``cfg.track_window_s``, frames [first, last], None where no window holds 3
    rendered frames); passed when every object with masked frames reaches
    ``cfg.track_iou_threshold`` on average and ``cfg.track_window_iou`` in every window."""
    iou = {name: (float(np.nanmean(v)) if np.isfinite(v).any() else None) for name, v in track.items()}
    frames = {name: int(np.isfinite(v).sum()) for name, v in track.items()}
    width = max(1, int(round(cfg.track_window_s * fps)))
    worst = {name: _worst_window(v, width) for name, v in track.items()}
    passed = all(v is None or v >= cfg.track_iou_threshold for v in iou.values()) and all(
        w is None or w["iou"] >= cfg.track_window_iou for w in worst.values()
    )
    return {
        "iou": iou,
        "frames": frames,
        "threshold": cfg.track_iou_threshold,
        "worst_window": worst,
        "window_threshold": cfg.track_window_iou,
        "passed": passed,
    }


def _worst_window(v: np.ndarray, width: int) -> dict | None:
    """The lowest mean of ``v``'s finite values over ``width`` consecutive frames that hold 3 or
    more of them, with its first and last frame; None where no window does."""
    finite = np.isfinite(v)
    sums = np.concatenate([[0.0], np.cumsum(np.where(finite, v, 0.0))])
    counts = np.concatenate([[0], np.cumsum(finite)])
    starts = np.flatnonzero(finite)
    ends = np.minimum(starts + width, len(v))
    n = counts[ends] - counts[starts]
    if not np.any(n >= 3):
        return None
    means = np.where(n >= 3, (sums[ends] - sums[starts]) / np.maximum(n, 1), np.inf)
    k = int(np.argmin(means))
    last = starts[k] + int(np.flatnonzero(finite[starts[k] : ends[k]])[-1])
    return {"iou": float(means[k]), "frames": [int(starts[k]), int(last)]}


def _author_gate(
    ctx: StageContext,
    frames,
    ssim,
    variant: str,
    rest,
    physics_ok: bool,
    track: dict,
    geometry_problems,
    *,
    not_resting: list[str],
) -> bool:
    """Write /World/Gate (RoseGateAPI); returns whether the gate passed. ``rest``: the rest
    checks, [(frame, ``RestResult``)]; ``not_resting``: the objects resting in no frame."""
    cfg = ctx.config
    gate = UsdGeom.Scope.Define(ctx.stage, paths.GATE).GetPrim()
    gate.ApplyAPI(schema.GATE_API)
    ssim_attr = gate.GetAttribute(tokens.GATE_SSIM)
    for t in frames:
        ssim_attr.Set(float(ssim[t]), Usd.TimeCode(t))
    ssim_mean = float(np.nanmean(ssim))
    passed_ssim = ssim_mean >= cfg.ssim_threshold
    gate.GetAttribute(tokens.GATE_SSIM_MEAN).Set(ssim_mean)
    gate.GetAttribute(tokens.GATE_SSIM_THRESHOLD).Set(float(cfg.ssim_threshold))
    gate.GetAttribute(tokens.GATE_SSIM_PASSED).Set(bool(passed_ssim))
    gate.GetAttribute(tokens.GATE_RENDER_VARIANT).Set(variant)
    gate.GetAttribute(tokens.GATE_SAMPLES_PER_PIXEL).Set(int(cfg.spp))
    gate.GetAttribute(tokens.GATE_PHYSICS_OBJECTS).Set([r.name for _, r in rest])
    gate.GetAttribute(tokens.GATE_PHYSICS_FRAMES).Set([int(t) for t, _ in rest])
    gate.GetAttribute(tokens.GATE_PHYSICS_DISPLACEMENT).Set([float(r.max_displacement_m) for _, r in rest])
    gate.GetAttribute(tokens.GATE_PHYSICS_ROTATION).Set([float(r.max_rotation_deg) for _, r in rest])
    gate.GetAttribute(tokens.GATE_PHYSICS_NOT_RESTING).Set(list(not_resting))
    gate.GetAttribute(tokens.GATE_PHYSICS_THRESHOLD).Set(float(cfg.physics_threshold_m))
    gate.GetAttribute(tokens.GATE_PHYSICS_DURATION).Set(float(cfg.physics_duration_s if cfg.physics else 0.0))
    gate.GetAttribute(tokens.GATE_PHYSICS_PASSED).Set(bool(physics_ok and cfg.physics))
    names = list(track["iou"])
    gate.GetAttribute(tokens.GATE_TRACK_OBJECTS).Set(names)
    gate.GetAttribute(tokens.GATE_TRACK_IOU).Set(
        [float("nan") if track["iou"][k] is None else track["iou"][k] for k in names]
    )
    gate.GetAttribute(tokens.GATE_TRACK_FRAMES).Set([track["frames"][k] for k in names])
    gate.GetAttribute(tokens.GATE_TRACK_THRESHOLD).Set(float(track["threshold"]))
    worst = [track["worst_window"][k] for k in names]
    gate.GetAttribute(tokens.GATE_TRACK_WINDOW_IOU).Set([float("nan") if w is None else w["iou"] for w in worst])
    gate.GetAttribute(tokens.GATE_TRACK_WINDOW_THRESHOLD).Set(float(track["window_threshold"]))
    gate.GetAttribute(tokens.GATE_TRACK_PASSED).Set(bool(track["passed"]))
    gate.GetAttribute(tokens.GATE_GEOMETRY_PASSED).Set(not geometry_problems)
    gate.GetAttribute(tokens.GATE_GEOMETRY_REPORT).Set("\n".join(geometry_problems))
    passed = passed_ssim and (physics_ok or not cfg.physics) and track["passed"] and not geometry_problems
    gate.GetAttribute(tokens.GATE_PASSED).Set(bool(passed))
    return bool(passed)
