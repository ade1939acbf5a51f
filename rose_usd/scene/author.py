"""Authoring layers/scene.usda: visual parts with looks, one static collider, and lights.
Every scene backend ends here, so all of them write the same layer."""

from __future__ import annotations

import shutil
from dataclasses import dataclass

import numpy as np
from pxr import Gf, UsdGeom, UsdLux, Vt

from rose_usd.geometry.mesh import check_collider
from rose_usd.render.lighting import Lighting
from rose_usd.stage_api import StageContext
from rose_usd.usd import paths, schema, tokens
from rose_usd.usd.geom import (
    MeshData,
    author_mesh,
    author_preview_material,
    bind_material,
    relative_asset,
)
from rose_usd.usd.physics import Approximation, make_collider


@dataclass(frozen=True)
class ScenePart:
    name: str
    mesh: MeshData
    """In world coordinates."""


def author_scene(
    ctx: StageContext,
    parts: list[ScenePart],
    collision: MeshData,
    lighting: Lighting,
    support: dict[str, float] | None = None,
) -> None:
    """Write the scene layer.

    Args:
        parts: visual meshes (world coordinates), each with its own look.
        collision: one watertight 2-manifold static collider in world coordinates.
        lighting: the lights to render the scene with (Lighting.unlit() for baked colors).
        support: object name -> the height [m] of the flat pad laid in the collider under it
            (``RoseSupportAPI``); None when the backend lays no pads.
    """
    check_collider(collision.vertices, collision.faces, "scene collision mesh")
    stage = ctx.stage
    UsdGeom.Xform.Define(stage, paths.SCENE)
    UsdGeom.Xform.Define(stage, paths.SCENE_VISUAL)
    UsdGeom.Scope.Define(stage, paths.SCENE_LOOKS)
    textures = {}
    for part in parts:
        mesh = part.mesh
        usd_mesh = author_mesh(stage, paths.scene_part(part.name), mesh)
        look_path = paths.SCENE_LOOKS.AppendChild(part.name)
        if mesh.texture is not None and mesh.uv is not None:
            if mesh.texture not in textures:
                dst = ctx.side_dir("textures") / f"{part.name}{mesh.texture.suffix}"
                shutil.copyfile(mesh.texture, dst)
                textures[mesh.texture] = ctx.out_dir / "textures" / dst.name
            material = author_preview_material(
                stage, look_path, texture_asset=relative_asset(textures[mesh.texture], ctx.layer_dir)
            )
        else:
            material = author_preview_material(
                stage, look_path, color=mesh.color, use_vertex_color=mesh.vertex_colors is not None
            )
        bind_material(usd_mesh.GetPrim(), material)
    collider = author_mesh(stage, paths.SCENE_COLLISION, collision, purpose=UsdGeom.Tokens.guide)
    make_collider(collider.GetPrim(), Approximation.NONE)
    if support is not None:
        prim = collider.GetPrim()
        prim.ApplyAPI(schema.SUPPORT_API)
        prim.GetAttribute(tokens.SUPPORT_OBJECTS).Set(Vt.TokenArray(list(support)))
        prim.GetAttribute(tokens.SUPPORT_HEIGHTS).Set(Vt.DoubleArray([float(h) for h in support.values()]))
    _author_lights(stage, lighting)


def _author_lights(stage, lighting: Lighting) -> None:
    """Lights as UsdLux: a DomeLight for the ambient term and a point-like SphereLight per point
    light; rose's renderer reads intensity * color as linear radiant intensity (README)."""
    UsdGeom.Scope.Define(stage, paths.SCENE_LIGHTS)
    dome = UsdLux.DomeLight.Define(stage, paths.SCENE_LIGHTS.AppendChild("Ambient"))
    amb = np.asarray(lighting.ambient, dtype=float)
    dome.CreateIntensityAttr(float(amb.max()) if amb.max() > 0 else 0.0)
    dome.CreateColorAttr(Gf.Vec3f(*(amb / amb.max() if amb.max() > 0 else amb).tolist()))
    for i, light in enumerate(lighting.points):
        sphere = UsdLux.SphereLight.Define(stage, paths.SCENE_LIGHTS.AppendChild(f"Point{i}"))
        sphere.CreateTreatAsPointAttr(True)
        sphere.CreateRadiusAttr(0.0)
        intensity = np.asarray(light.intensity, dtype=float)
        peak = float(intensity.max())
        sphere.CreateIntensityAttr(peak)
        sphere.CreateColorAttr(Gf.Vec3f(*(intensity / peak).tolist()))
        sphere.AddTranslateOp(UsdGeom.XformOp.PrecisionDouble).Set(Gf.Vec3d(*light.position_m))
