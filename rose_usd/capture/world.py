"""Authoring layers/world.usda: the world prim, physics scene and the camera track.
Every capture backend ends here, so all of them write the same layer."""

from __future__ import annotations

import numpy as np
from pxr import UsdGeom

from rose_usd.stage_api import StageContext
from rose_usd.usd import paths, schema
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
) -> None:
    """Write the world layer.

    Args:
        world_from_camera: OpenCV camera poses in the gravity-aligned metric world, (N, 4, 4) [m].
        K: (3, 3) or (N, 3, 3) intrinsics [px].
        world_from_input: transform from the input frame to the world (4, 4).
    """
    n = ctx.time_info.n_frames
    if len(world_from_camera) != n:
        raise ValueError(f"author_world: {len(world_from_camera)} camera poses for {n} frames")
    Ks = np.asarray(K, dtype=float)
    for k in Ks.reshape(-1, 3, 3):
        check_K(k, ctx.case.width, ctx.case.height)
    stage = ctx.stage
    world = UsdGeom.Xform.Define(stage, paths.WORLD)
    prim = world.GetPrim()
    prim.ApplyAPI(schema.WORLD_API)
    prim.GetAttribute("rose:world:gravitySource").Set(gravity_source)
    prim.GetAttribute("rose:world:gravityUncertaintyDeg").Set(float(gravity_uncertainty_deg))
    prim.GetAttribute("rose:world:worldFromInput").Set(gf_matrix(world_from_input))
    prim.GetAttribute("rose:world:scaleSource").Set(scale_source)
    prim.GetAttribute("rose:world:scaleAlpha").Set(float(scale_alpha))
    prim.GetAttribute("rose:world:scaleBeta").Set(float(scale_beta))
    prim.GetAttribute("rose:world:scaleResidual").Set(float(scale_residual))
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
