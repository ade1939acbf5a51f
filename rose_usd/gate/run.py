"""The quality gate: re-render every frame of the composed stage with Mitsuba from the stage's own
cameras and compare it with the input video by SSIM (the paper's Eq. 4); load the stage in Newton
and check that objects at rest stay at rest; check that every collider is a closed 2-manifold."""

from __future__ import annotations

import json

import cv2
import numpy as np
from pxr import Usd, UsdGeom, UsdPhysics

from rose_usd.core.watertight import collider_problems
from rose_usd.gate.report import write_report
from rose_usd.gate.ssim import masked_ssim
from rose_usd.io.images import read_mask, write_rgb
from rose_usd.progress import progress, say
from rose_usd.stage_api import StageContext
from rose_usd.usd import paths, schema
from rose_usd.usd.camera import read_camera
from rose_usd.usd.geom import read_mesh


def _interactor_mask(stage: Usd.Stage, t: int, dilate_px: int) -> np.ndarray | None:
    prim = stage.GetPrimAtPath(paths.INTERACTOR_MASK)
    if not prim:
        return None
    asset = prim.GetAttribute("rose:masks:file").Get(Usd.TimeCode(t))
    if asset is None or not asset.resolvedPath:
        return None
    mask = read_mask(asset.resolvedPath)
    if dilate_px > 0:
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * dilate_px + 1, 2 * dilate_px + 1))
        mask = cv2.dilate(mask.astype(np.uint8), kernel) > 0
    return mask


def _objects(stage: Usd.Stage) -> dict[str, str]:
    objects = stage.GetPrimAtPath(paths.OBJECTS)
    if not objects:
        return {}
    return {
        child.GetName(): str(child.GetPath())
        for child in objects.GetChildren()
        if child.HasAPI(UsdPhysics.RigidBodyAPI)
    }


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


def run(ctx: StageContext) -> None:
    cfg = ctx.config
    stage = ctx.stage
    case = ctx.case
    n = ctx.time_info.n_frames
    from rose_usd.render.from_usd import StageRenderer

    camera = read_camera(stage, paths.CAMERA, n)
    if (camera.width, camera.height) != (case.width, case.height):
        say(f"gate: the stage's camera is {camera.width}x{camera.height}, the video {case.width}x{case.height}")
    renderer = StageRenderer(stage)
    frames = list(range(0, n, max(1, cfg.frame_stride)))
    report_dir = ctx.side_dir("report")
    ssim = np.full(n, np.nan)
    keep = {}
    sample_frames = set(np.linspace(0, len(frames) - 1, 4).round().astype(int).tolist())
    for i, t in enumerate(progress(frames, "gate render", total=len(frames))):
        renderer.pose_at(t)
        rendered = renderer.scene.render_srgb8(
            camera.world_from_cv[t], camera.K[t], case.width, case.height, spp=cfg.spp, seed=t
        )
        original = case.rgb(t)
        exclude = _interactor_mask(stage, t, cfg.interactor_dilate_px) if cfg.exclude_interactor else None
        ssim[t], ssim_map = masked_ssim(original, rendered, exclude)
        if cfg.save_frames:
            write_rgb(report_dir / "frames" / f"{t:06d}.png", rendered)
        if i in sample_frames:
            keep[t] = (original, rendered, ssim_map, exclude)
    worst = int(np.nanargmin(ssim))
    if worst not in keep:
        renderer.pose_at(worst)
        rendered = renderer.scene.render_srgb8(
            camera.world_from_cv[worst], camera.K[worst], case.width, case.height, spp=cfg.spp, seed=worst
        )
        exclude = _interactor_mask(stage, worst, cfg.interactor_dilate_px) if cfg.exclude_interactor else None
        keep[worst] = (case.rgb(worst), rendered, masked_ssim(case.rgb(worst), rendered, exclude)[1], exclude)
    ssim_mean = float(np.nanmean(ssim))

    rest = []
    objects = _objects(stage)
    if cfg.physics and objects:
        from rose_usd.sim.rest import simulate_rest

        rest = simulate_rest(
            stage, objects, duration_s=cfg.physics_duration_s, dt_s=cfg.physics_dt_s, iterations=cfg.physics_iterations
        )
    physics_ok = all(r.max_displacement_m < cfg.physics_threshold_m for r in rest)
    geometry_problems = _geometry_check(stage)

    # ---------------------------------------------------------------- author
    gate = UsdGeom.Scope.Define(stage, paths.GATE).GetPrim()
    gate.ApplyAPI(schema.GATE_API)
    ssim_attr = gate.GetAttribute("rose:gate:ssim")
    for t in frames:
        ssim_attr.Set(float(ssim[t]), Usd.TimeCode(t))
    passed_ssim = ssim_mean >= cfg.ssim_threshold
    gate.GetAttribute("rose:gate:ssimMean").Set(ssim_mean)
    gate.GetAttribute("rose:gate:ssimThreshold").Set(float(cfg.ssim_threshold))
    gate.GetAttribute("rose:gate:ssimPassed").Set(bool(passed_ssim))
    gate.GetAttribute("rose:gate:renderVariant").Set(renderer.scene.variant)
    gate.GetAttribute("rose:gate:samplesPerPixel").Set(int(cfg.spp))
    gate.GetAttribute("rose:gate:physics:objects").Set([r.name for r in rest])
    gate.GetAttribute("rose:gate:physics:displacement").Set([float(r.max_displacement_m) for r in rest])
    gate.GetAttribute("rose:gate:physics:rotation").Set([float(r.max_rotation_deg) for r in rest])
    gate.GetAttribute("rose:gate:physics:threshold").Set(float(cfg.physics_threshold_m))
    gate.GetAttribute("rose:gate:physics:duration").Set(float(cfg.physics_duration_s if cfg.physics else 0.0))
    gate.GetAttribute("rose:gate:physics:passed").Set(bool(physics_ok and cfg.physics))
    gate.GetAttribute("rose:gate:geometry:passed").Set(not geometry_problems)
    gate.GetAttribute("rose:gate:geometry:report").Set("\n".join(geometry_problems))
    passed = passed_ssim and (physics_ok or not cfg.physics) and not geometry_problems
    gate.GetAttribute("rose:gate:passed").Set(bool(passed))

    summary = {
        "passed": passed,
        "ssim_mean": ssim_mean,
        "ssim_min": float(np.nanmin(ssim)),
        "ssim_min_frame": worst,
        "ssim_threshold": cfg.ssim_threshold,
        "render_variant": renderer.scene.variant,
        "frames_rendered": len(frames),
        "physics": [r.__dict__ for r in rest],
        "physics_passed": physics_ok if cfg.physics else None,
        "geometry_problems": geometry_problems,
    }
    (report_dir / "gate.json").write_text(json.dumps(summary, indent=2) + "\n")
    write_report(report_dir, ssim, cfg.ssim_threshold, keep)
    ctx.record(
        ssim_mean=round(ssim_mean, 5), passed=passed, physics={r.name: round(r.max_displacement_m, 6) for r in rest}
    )
