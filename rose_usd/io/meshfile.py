"""Mesh files: a minimal Wavefront OBJ writer (positions, per-vertex UVs, one material), a
reader that keeps vertex order (any format, through trimesh) and a file's length unit."""

from __future__ import annotations

import os
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from rose_usd.errors import MeshError

UNITS = {"millimeters": 1e-3, "centimeters": 1e-2, "inches": 0.0254}
"""Units a metric-looking mesh may be in by mistake, and meters per unit."""
UNIT_NAMES = {"m": "meters", "cm": "centimeters", "mm": "millimeters", "in": "inches"}
"""rose.toml's ``mesh_units`` values and the units they name."""
METRIC_EXTENT_M = (0.01, 2.0)
"""The sizes [m] an object of a tabletop video may have: a file whose largest side lies in this
range read in meters is taken as metric."""


@dataclass(frozen=True)
class FileUnit:
    """The length unit of a mesh file's coordinates."""

    meters: float | None
    """Meters per file unit; None: unknown (a normalized mesh, or no plausible unit)."""
    name: str | None
    guessed: bool = False
    """Chosen from the file's size alone (not meters, not given): the caller warns."""

    def describe(self, extent: float) -> str:
        """What was assumed, for a warning: '128 units across: read as millimeters (0.128 m)'."""
        return f"{extent:.4g} units across: read as {self.name} ({extent * self.meters:.3g} m)"


def file_unit(extent: float, normalized: bool, given: str | None = None) -> FileUnit:
    """The unit of a mesh file ``extent`` (its largest side, in file units) across: rose.toml's
    ``mesh_units`` when given; meters when that makes it a tabletop object's size; else guessed:
    millimeters (3D-print and CAD files mostly are) when that does, else centimeters when that
    does; unknown for a normalized mesh or when none does."""
    if given and given != "auto":
        name = UNIT_NAMES[given]
        return FileUnit(1.0 if name == "meters" else UNITS[name], name)
    if normalized:
        return FileUnit(None, None)
    low, high = METRIC_EXTENT_M
    for name in ("meters", "millimeters", "centimeters"):
        scale = 1.0 if name == "meters" else UNITS[name]
        if low <= extent * scale <= high:
            return FileUnit(scale, name, guessed=name != "meters")
    return FileUnit(None, None)


def write_obj(
    path: str | os.PathLike,
    vertices: np.ndarray,
    faces: np.ndarray,
    *,
    uv: np.ndarray | None = None,
    color_linear: tuple[float, float, float] | None = None,
    texture_file: str | None = None,
) -> None:
    """Write an OBJ (+ MTL beside it when a color or texture is given). ``uv`` is per vertex,
    origin bottom-left (OBJ/USD convention); ``texture_file`` is relative to the OBJ's folder."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    lines = [f"# rose_usd: {len(vertices)} vertices, {len(faces)} triangles, meters"]
    has_mtl = color_linear is not None or texture_file is not None
    if has_mtl:
        lines.append(f"mtllib {path.stem}.mtl")
    lines.extend(f"v {x:.9g} {y:.9g} {z:.9g}" for x, y, z in np.asarray(vertices, dtype=float))
    if uv is not None:
        lines.extend(f"vt {u:.9g} {v:.9g}" for u, v in np.asarray(uv, dtype=float))
    if has_mtl:
        lines.append("usemtl material0")
    f1 = np.asarray(faces, dtype=np.int64) + 1
    if uv is not None:
        lines.extend(f"f {a}/{a} {b}/{b} {c}/{c}" for a, b, c in f1)
    else:
        lines.extend(f"f {a} {b} {c}" for a, b, c in f1)
    path.write_text("\n".join(lines) + "\n")
    if has_mtl:
        kd = color_linear if color_linear is not None else (1.0, 1.0, 1.0)
        mtl = ["newmtl material0", f"Kd {kd[0]:.6f} {kd[1]:.6f} {kd[2]:.6f}", "Ka 0 0 0", "Ks 0 0 0", "illum 1"]
        if texture_file is not None:
            mtl.append(f"map_Kd {texture_file}")
        path.with_suffix(".mtl").write_text("\n".join(mtl) + "\n")


def read_mesh_file(path: str | os.PathLike) -> trimesh.Trimesh:
    """Load one triangle mesh (OBJ, PLY, GLB, STL...) keeping vertex order; scenes are merged."""
    path = Path(path)
    if not path.is_file():
        raise MeshError("mesh file not found", path=path, hint="check the path")
    try:
        loaded = quiet_load(path)
    except Exception as exc:  # trimesh raises many types for unreadable files
        raise MeshError(
            f"cannot read the mesh ({type(exc).__name__}: {exc})", path=path, hint="export it again as OBJ, PLY or GLB"
        ) from None
    if isinstance(loaded, trimesh.Scene):
        loaded = loaded.to_mesh() if hasattr(loaded, "to_mesh") else loaded.dump(concatenate=True)
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        raise MeshError("the file holds no triangles", path=path, hint="export a triangle mesh")
    check_vertices(loaded, path)
    return loaded


def quiet_load(path: Path):
    """``trimesh.load`` keeping vertex order, without the NumPy warnings its OBJ reader lets through
    (an OBJ whose faces each have their own material and texture corners, as Blender exports a
    cube: "All-NaN slice encountered"), which a user would take for an error."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", category=RuntimeWarning, module=r"(trimesh|numpy)\.")
        return trimesh.load(str(path), process=False, maintain_order=True)


def check_vertices(mesh: trimesh.Trimesh, path: Path) -> None:
    """MeshError unless the vertices are finite, within 1 km, and the faces index them."""
    vertices = np.asarray(mesh.vertices, dtype=float)
    if not np.all(np.isfinite(vertices)):
        raise MeshError("the mesh has NaN or infinite vertices", path=path, hint="export it again")
    if np.abs(vertices).max() > 1e3:
        raise MeshError(
            f"the mesh reaches {np.abs(vertices).max():.3g} units from its origin", path=path, hint="export it again"
        )
    faces = np.asarray(mesh.faces)
    if faces.size and (faces.min() < 0 or faces.max() >= len(vertices)):
        raise MeshError("the mesh's faces index vertices it does not have", path=path, hint="export it again")


def texture_image(mesh: trimesh.Trimesh):
    """The base color texture (PIL image) of a mesh's material, or None: a simple material's
    image (OBJ's map_Kd) or a PBR material's baseColorTexture (glTF)."""
    material = getattr(mesh.visual, "material", None)
    image = getattr(material, "image", None)
    return image if image is not None else getattr(material, "baseColorTexture", None)


def unless_placeholder(colors8: np.ndarray) -> np.ndarray | None:
    """None when every color is trimesh's placeholder gray: the file's materials gave no color
    (visp-desk's cube.obj: six materials without Kd or texture, merged into one gray)."""
    return None if np.all(colors8 == np.asarray(trimesh.visual.DEFAULT_COLOR[:3])) else colors8


def surface_colors(mesh: trimesh.Trimesh, count: int = 20000) -> np.ndarray | None:
    """sRGB8 colors (count, 3) of points spread evenly over the mesh's surface (its texture at
    their UVs, or its vertex colors); None when the file gave it no colors."""
    visual = mesh.visual
    try:
        _, faces, bary = trimesh.sample.sample_surface(mesh, count, return_barycentric=True, seed=0)
        corners, image = mesh.faces[faces], texture_image(mesh)
        if visual.kind == "texture" and getattr(visual, "uv", None) is not None and image is not None:
            uv = np.einsum("nk,nkc->nc", bary, np.asarray(visual.uv, float)[corners])
            colors = trimesh.visual.color.uv_to_interpolated_color(uv, image)
            return np.asarray(colors)[:, :3].astype(np.uint8)
        if visual.kind == "vertex":
            per_vertex = unless_placeholder(np.asarray(visual.vertex_colors)[:, :3])
            if per_vertex is None:
                return None
            return np.einsum("nk,nkc->nc", bary, per_vertex.astype(float)[corners]).round().astype(np.uint8)
    except Exception:  # a material trimesh cannot sample: no colors rather than no mesh  # noqa: BLE001
        return None
    return None
