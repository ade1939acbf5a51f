"""Meshes and their looks: authoring triangle meshes with colors, UVs and preview materials,
and reading them back as numpy arrays.

Colors in USD are linear RGB (``displayColor``, ``diffuseColor``); textures are sRGB PNGs.
UVs are USD ``st``: origin at the image's bottom-left corner.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from pxr import Gf, Sdf, Usd, UsdGeom, UsdShade, Vt


@dataclass
class MeshData:
    """A triangle mesh with its appearance, as read from or written to a stage."""

    vertices: np.ndarray
    """Vertex positions [m], shape (V, 3)."""
    faces: np.ndarray
    """Triangle vertex indices, shape (F, 3), counter-clockwise seen from outside."""
    vertex_colors: np.ndarray | None = None
    """Linear RGB per vertex in [0, 1], shape (V, 3), or None."""
    color: tuple[float, float, float] | None = None
    """One linear RGB color for the whole mesh, or None."""
    uv: np.ndarray | None = None
    """USD st texture coordinates per vertex, shape (V, 2), or None."""
    texture: Path | None = None
    """sRGB PNG holding the base color, used with ``uv``."""
    extras: dict = field(default_factory=dict)

    @property
    def mean_color(self) -> tuple[float, float, float]:
        """A representative linear color (for displayColor, which Newton reads as one value)."""
        if self.vertex_colors is not None and len(self.vertex_colors):
            return tuple(float(c) for c in np.mean(self.vertex_colors, axis=0))
        if self.color is not None:
            return tuple(float(c) for c in self.color)
        return (0.5, 0.5, 0.5)


def author_mesh(stage: Usd.Stage, path: Sdf.Path, mesh: MeshData, *, purpose: str | None = None) -> UsdGeom.Mesh:
    """Define a polygonal (not subdivided) triangle mesh with its colors and UVs."""
    vertices = np.ascontiguousarray(mesh.vertices, dtype=np.float32)
    faces = np.ascontiguousarray(mesh.faces, dtype=np.int32)
    if vertices.ndim != 2 or vertices.shape[1] != 3 or faces.ndim != 2 or faces.shape[1] != 3:
        raise ValueError(f"author_mesh {path}: expected (V,3) vertices and (F,3) faces")
    usd_mesh = UsdGeom.Mesh.Define(stage, path)
    usd_mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(vertices))
    usd_mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(faces), 3, dtype=np.int32)))
    usd_mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(faces.reshape(-1)))
    usd_mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    usd_mesh.CreateOrientationAttr(UsdGeom.Tokens.rightHanded)
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    usd_mesh.CreateExtentAttr(Vt.Vec3fArray([Gf.Vec3f(*lo.tolist()), Gf.Vec3f(*hi.tolist())]))
    if purpose is not None:
        usd_mesh.CreatePurposeAttr(purpose)
    if mesh.vertex_colors is not None:
        colors = np.ascontiguousarray(np.clip(mesh.vertex_colors, 0.0, 1.0), dtype=np.float32)
        primvar = usd_mesh.CreateDisplayColorPrimvar(UsdGeom.Tokens.vertex)
        primvar.Set(Vt.Vec3fArray.FromNumpy(colors))
    else:
        primvar = usd_mesh.CreateDisplayColorPrimvar(UsdGeom.Tokens.constant)
        primvar.Set(Vt.Vec3fArray([Gf.Vec3f(*mesh.mean_color)]))
    if mesh.uv is not None:
        st = UsdGeom.PrimvarsAPI(usd_mesh).CreatePrimvar(
            "st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.vertex
        )
        st.Set(Vt.Vec2fArray.FromNumpy(np.ascontiguousarray(mesh.uv, dtype=np.float32)))
    return usd_mesh


def author_preview_material(
    stage: Usd.Stage,
    path: Sdf.Path,
    *,
    color: tuple[float, float, float] | None = None,
    texture_asset: str | None = None,
    use_vertex_color: bool = False,
) -> UsdShade.Material:
    """A UsdPreviewSurface material: diffuse from a texture (``st`` UVs), a constant color, or the
    mesh's ``displayColor`` primvar; rough and non-metallic (our renderer is Lambertian)."""
    material = UsdShade.Material.Define(stage, path)
    shader = UsdShade.Shader.Define(stage, path.AppendChild("Surface"))
    shader.CreateIdAttr("UsdPreviewSurface")
    shader.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(1.0)
    shader.CreateInput("metallic", Sdf.ValueTypeNames.Float).Set(0.0)
    diffuse = shader.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f)
    if texture_asset is not None:
        reader = UsdShade.Shader.Define(stage, path.AppendChild("StReader"))
        reader.CreateIdAttr("UsdPrimvarReader_float2")
        reader.CreateInput("varname", Sdf.ValueTypeNames.String).Set("st")
        tex = UsdShade.Shader.Define(stage, path.AppendChild("BaseColorTexture"))
        tex.CreateIdAttr("UsdUVTexture")
        tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(Sdf.AssetPath(texture_asset))
        tex.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set("sRGB")
        tex.CreateInput("wrapS", Sdf.ValueTypeNames.Token).Set("repeat")
        tex.CreateInput("wrapT", Sdf.ValueTypeNames.Token).Set("repeat")
        tex.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(reader.ConnectableAPI(), "result")
        diffuse.ConnectToSource(tex.ConnectableAPI(), "rgb", UsdShade.AttributeType.Output, Sdf.ValueTypeNames.Float3)
    elif use_vertex_color:
        reader = UsdShade.Shader.Define(stage, path.AppendChild("ColorReader"))
        reader.CreateIdAttr("UsdPrimvarReader_float3")
        reader.CreateInput("varname", Sdf.ValueTypeNames.String).Set("displayColor")
        diffuse.ConnectToSource(
            reader.ConnectableAPI(), "result", UsdShade.AttributeType.Output, Sdf.ValueTypeNames.Float3
        )
    else:
        diffuse.Set(Gf.Vec3f(*(color if color is not None else (0.5, 0.5, 0.5))))
    material.CreateSurfaceOutput().ConnectToSource(shader.ConnectableAPI(), "surface")
    return material


def bind_material(prim: Usd.Prim, material: UsdShade.Material, purpose: str = UsdShade.Tokens.allPurpose) -> None:
    api = UsdShade.MaterialBindingAPI.Apply(prim)
    api.Bind(material, UsdShade.Tokens.weakerThanDescendants, purpose)


def read_mesh(prim: Usd.Prim, time: Usd.TimeCode = Usd.TimeCode.Default(), *, world: bool = True) -> MeshData:
    """Read a mesh (triangulating polygons by fans) with its colors, UVs and texture.

    Args:
        world: return vertices in world coordinates at ``time`` (else in the prim's local frame).
    """
    usd_mesh = UsdGeom.Mesh(prim)
    points = np.asarray(usd_mesh.GetPointsAttr().Get(time), dtype=float)
    counts = np.asarray(usd_mesh.GetFaceVertexCountsAttr().Get(time), dtype=np.int64)
    indices = np.asarray(usd_mesh.GetFaceVertexIndicesAttr().Get(time), dtype=np.int64)
    faces = triangulate(counts, indices)
    if usd_mesh.GetOrientationAttr().Get() == UsdGeom.Tokens.leftHanded:
        faces = faces[:, ::-1]
    if world:
        xf = np.array(UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(time), dtype=float).T
        points = points @ xf[:3, :3].T + xf[:3, 3]
    data = MeshData(vertices=points, faces=faces)
    primvars = UsdGeom.PrimvarsAPI(prim)
    display = primvars.GetPrimvar("displayColor")
    if display and display.HasValue():
        values = np.asarray(display.ComputeFlattened(time), dtype=float)
        interp = display.GetInterpolation()
        if interp == UsdGeom.Tokens.vertex and len(values) == len(points):
            data.vertex_colors = values
        elif len(values):
            data.color = tuple(float(v) for v in values[0])
    st = primvars.GetPrimvar("st")
    if st and st.HasValue() and st.GetInterpolation() == UsdGeom.Tokens.vertex:
        data.uv = np.asarray(st.ComputeFlattened(time), dtype=float)
    material, _ = UsdShade.MaterialBindingAPI(prim).ComputeBoundMaterial()
    if material:
        data.texture, base_color = _material_base(material)
        if base_color is not None and data.vertex_colors is None:
            data.color = base_color
    return data


def triangulate(counts: np.ndarray, indices: np.ndarray) -> np.ndarray:
    """Fan-triangulate polygons given by face vertex counts and indices; (F, 3) int."""
    if len(counts) and np.all(counts == 3):
        return indices.reshape(-1, 3)
    tris = []
    start = 0
    for c in counts:
        poly = indices[start : start + c]
        for k in range(1, c - 1):
            tris.append((poly[0], poly[k], poly[k + 1]))
        start += c
    return np.asarray(tris, dtype=np.int64).reshape(-1, 3)


def _material_base(material: UsdShade.Material) -> tuple[Path | None, tuple[float, float, float] | None]:
    """(texture file, constant diffuse color) of a UsdPreviewSurface material."""
    surface = material.ComputeSurfaceSource()[0]
    if not surface:
        return None, None
    diffuse = surface.GetInput("diffuseColor")
    if not diffuse:
        return None, None
    if diffuse.HasConnectedSource():
        source = diffuse.GetConnectedSources()[0][0].source
        shader = UsdShade.Shader(source.GetPrim())
        if shader.GetIdAttr().Get() == "UsdUVTexture":
            asset = shader.GetInput("file").Get()
            resolved = asset.resolvedPath if asset is not None else ""
            return (Path(resolved) if resolved else None), None
        return None, None
    value = diffuse.Get()
    return None, (tuple(float(v) for v in value) if value is not None else None)


def relative_asset(target: Path, layer_dir: Path) -> str:
    """Asset path of ``target`` relative to the folder of the layer that authors it."""
    rel = os.path.relpath(target, layer_dir).replace(os.sep, "/")
    return rel if rel.startswith("../") else "./" + rel
