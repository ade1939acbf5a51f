"""Object meshes made by other tools (TRELLIS's normalized GLB, a scan or CAD model as
GLB/OBJ/PLY/STL), shared by the object backends that use them (``imported`` with depth,
``silhouette`` without): finding the file, reading and repairing it, its up axis and its unit."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from rose_usd.case.config import ObjectSpec
from rose_usd.case.layout import Case
from rose_usd.core import se3
from rose_usd.core.color import srgb8_to_linear
from rose_usd.core.watertight import collider_problems
from rose_usd.errors import InputError, MeshError
from rose_usd.geometry.mesh import self_intersects
from rose_usd.geometry.symmetry import coloured_samples, shape_symmetries, symmetric_look, symmetry_scores
from rose_usd.geometry.texture import transfer_colors
from rose_usd.io import trellis
from rose_usd.io.meshfile import UNITS, read_mesh_file, texture_image, unless_placeholder


def find_mesh(case: Case, spec: ObjectSpec) -> Path:
    """The mesh file of object ``spec`` (:meth:`Case.mesh_file`); InputError naming where to put one."""
    path = case.mesh_file(spec)
    if path is None:
        raise InputError(
            f"no mesh of object {spec.name!r}",
            path=case.perception_dir / f"{spec.name}.glb",
            hint='put it there, set mesh = "..." in its [[objects]] entry of rose.toml, or use --backend object=fusion',
        )
    return path


@dataclass
class Surface:
    """A mesh file's textured surface as the file has it (its vertices split along UV seams):
    what an object's visual mesh shows when its file has a texture."""

    vertices: np.ndarray
    """(V, 3) in the file's frame and units (``ImportedMesh.vertices``'), or the object's [m]."""
    faces: np.ndarray
    uv: np.ndarray
    """(V, 2) texture coordinates, origin bottom-left (USD st)."""
    image: np.ndarray
    """(H, W, 3) uint8 sRGB texture."""

    def scaled(self, meters_per_unit: float) -> Surface:
        return Surface(self.vertices * meters_per_unit, self.faces, self.uv, self.image)


@dataclass
class ImportedMesh:
    vertices: np.ndarray
    """In the file's own frame and units."""
    faces: np.ndarray
    colors: np.ndarray | None
    """Linear RGB per vertex, or None."""
    normalized: bool
    """Inside TRELLIS's unit cube with its longest side 1: no metric scale at all."""
    up: np.ndarray
    """The mesh's up axis in its own frame (unit 3-vector): ``mesh_up``, else its format's convention."""
    repairs: list[str]
    up_given: bool = False
    """Whether rose.toml gave ``mesh_up``; without it every axis is tried (``up_candidates``)."""
    surface: Surface | None = None
    """The file's textured surface (``_surface``), kept only where the repairs left the shape as
    the file has it (nothing dropped or rebuilt); else None."""


MAX_TEXTURE_PX = 2048
"""A file's texture is kept at most this many pixels on its longer side."""


def _surface(mesh: trimesh.Trimesh) -> Surface | None:
    """The file's texture with its UVs (trimesh gives them origin bottom-left), None without one."""
    visual = mesh.visual
    if getattr(visual, "kind", None) != "texture" or getattr(visual, "uv", None) is None:
        return None
    image = texture_image(mesh)
    uv = np.asarray(visual.uv, float)
    if image is None or len(uv) != len(mesh.vertices) or not np.all(np.isfinite(uv)):
        return None
    rgb = np.asarray(image.convert("RGB"), np.uint8)
    if rgb.ndim != 3 or min(rgb.shape[:2]) < 2:
        return None
    if max(rgb.shape[:2]) > MAX_TEXTURE_PX:  # a scan's 5k texture: a simulator's asset needs no more
        import cv2

        f = MAX_TEXTURE_PX / max(rgb.shape[:2])
        size = (max(2, round(rgb.shape[1] * f)), max(2, round(rgb.shape[0] * f)))
        rgb = cv2.resize(rgb, size, interpolation=cv2.INTER_AREA)
    return Surface(np.asarray(mesh.vertices, float), np.asarray(mesh.faces, np.int64), uv, rgb)


def _vertex_colors(mesh: trimesh.Trimesh) -> np.ndarray | None:
    """sRGB8 per vertex: the texture at each vertex's UV, or the vertex colors; None if neither."""
    visual = mesh.visual
    try:
        if visual.kind == "texture" and getattr(visual, "uv", None) is not None:
            return unless_placeholder(np.asarray(visual.to_color().vertex_colors)[:, :3])
        if visual.kind == "vertex":
            return unless_placeholder(np.asarray(visual.vertex_colors)[:, :3])
    except Exception:  # a material trimesh cannot sample: no colors rather than no mesh  # noqa: BLE001
        return None
    return None


def read_imported(path: Path, up: str | None = None) -> ImportedMesh:
    """Read and repair one mesh file (the module's step 2). MeshError when nothing usable is left."""
    raw = read_mesh_file(path)
    colors8 = _vertex_colors(raw)
    mesh = trimesh.Trimesh(raw.vertices, raw.faces, vertex_colors=colors8, process=False)
    if not np.all(np.isfinite(mesh.vertices)):
        raise MeshError("the mesh has NaN or infinite vertices", path=path, hint="export it again")
    mesh.merge_vertices(merge_tex=True, merge_norm=True)  # UV seams split vertices: rejoin them
    mesh.update_faces(mesh.nondegenerate_faces())
    mesh.update_faces(mesh.unique_faces())
    mesh.remove_unreferenced_vertices()
    if len(mesh.faces) < 4:
        raise MeshError(
            f"the mesh has only {len(mesh.faces)} usable triangles", path=path, hint="export the object's surface"
        )
    repairs = []
    surface = _surface(raw) if colors8 is not None else None  # not a placeholder material's gray
    parts = mesh.split(only_watertight=False)
    if len(parts) > 1:
        areas = np.array([p.area for p in parts])
        keep = areas >= 0.02 * areas.sum()
        if not keep.all():
            surface = None  # the visual would keep what the collider dropped
            repairs.append(
                f"dropped {int((~keep).sum())} loose part(s) holding "
                f"{100 * areas[~keep].sum() / areas.sum():.1f} % of the surface"
            )
        if keep.sum() > 1:
            repairs.append(f"{int(keep.sum())} separate parts kept as one rigid body")
        mesh = trimesh.util.concatenate([p for p, k in zip(parts, keep) if k])
    if not mesh.is_watertight:
        _, uses = np.unique(mesh.edges_sorted, axis=0, return_counts=True)
        holes, shared = int(np.count_nonzero(uses == 1)), int(np.count_nonzero(uses > 2))
        mesh = _fill_holes(mesh)
        repairs.append(
            f"filled holes ({holes} open edges)" if holes else f"closed it ({shared} edges shared by over two faces)"
        )
    if not mesh.is_winding_consistent or mesh.volume < 0:
        trimesh.repair.fix_normals(mesh)
    problems = collider_problems(mesh.vertices, mesh.faces) or (
        ["self-intersecting"] if self_intersects(mesh.vertices, mesh.faces) else []
    )
    if problems:
        surface = None
        mesh = _remesh(mesh)
        repairs.append(f"the mesh is {', '.join(problems)}: rebuilt from its signed distance at 1/96 of its size")
    colors = None
    if colors8 is not None and mesh.visual.kind == "vertex":
        colors = srgb8_to_linear(np.asarray(mesh.visual.vertex_colors)[:, :3])
    elif colors8 is not None:  # rebuilt: carry the colors over from the file's vertices
        colors = transfer_colors(mesh.vertices, raw.vertices, srgb8_to_linear(colors8))
    extent = mesh.vertices.max(axis=0) - mesh.vertices.min(axis=0)
    normalized = bool(np.abs(raw.vertices).max() <= 0.5 + 1e-3 and extent.max() > 0.9)
    conventional = "y" if path.suffix.lower() in (".glb", ".gltf") else "z"  # glTF is Y-up by its spec
    up = (up or "auto").strip().lower()
    if up != "auto" and up.lstrip("+-") not in AXES:
        raise MeshError(
            f"mesh_up = {up!r}",
            path=path,
            hint='write mesh_up = "x", "y", "z" (or "-x", "-y", "-z", or "auto") in its [[objects]] entry',
        )
    return ImportedMesh(
        np.asarray(mesh.vertices, float),
        np.asarray(mesh.faces, np.int64),
        colors,
        normalized,
        axis_vector(conventional if up == "auto" else up),
        repairs,
        up_given=up != "auto",
        surface=surface,
    )


AXES = {"x": 0, "y": 1, "z": 2}


def axis_vector(name: str) -> np.ndarray:
    """The unit vector of an axis name: "x", "+y", "-z", ..."""
    axis = np.zeros(3)
    axis[AXES[name.lstrip("+-")]] = -1.0 if name.startswith("-") else 1.0
    return axis


def up_candidates(mesh: ImportedMesh) -> list[np.ndarray]:
    """The up axes to try: the given one, else the file format's convention first, then the other five."""
    if mesh.up_given:
        return [mesh.up]
    others = [axis_vector(s + a) for a in AXES for s in "+-"]
    return [mesh.up] + [a for a in others if not np.allclose(a, mesh.up)]


def _fill_holes(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """Each hole (a loop of edges used by one triangle) closed by a fan around its centroid,
    wound like its neighbors. Holes whose border touches itself are left to the caller's checks."""
    directed = mesh.faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    key = np.sort(directed, axis=1)
    _, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    border = directed[counts[inverse.ravel()] == 1]
    nxt = dict(zip(border[:, 0].tolist(), border[:, 1].tolist()))
    if len(nxt) != len(border):
        return mesh  # a vertex starts two border edges: not simple loops
    vertices, faces, seen = [np.asarray(mesh.vertices)], [np.asarray(mesh.faces)], set()
    count = len(mesh.vertices)
    for start in nxt:
        if start in seen:
            continue
        loop, v = [], start
        while v not in seen and v in nxt:
            seen.add(v)
            loop.append(v)
            v = nxt[v]
        if v != start or len(loop) < 3:
            return mesh
        vertices.append(mesh.vertices[loop].mean(axis=0, keepdims=True))
        a = np.array(loop)
        faces.append(np.column_stack([np.roll(a, -1), a, np.full(len(a), count)]))  # border edge reversed
        count += 1
    return trimesh.Trimesh(np.concatenate(vertices), np.concatenate(faces), process=False)


def _remesh(mesh: trimesh.Trimesh, resolution: int = 96) -> trimesh.Trimesh:
    """A closed, self-intersection-free 2-manifold of the input's solid: its signed distance on a
    grid of ``resolution`` cells along its longest side (inside by the majority of 3 ray parities,
    Open3D, so small holes and self-intersections do not leak), marched at zero."""
    import open3d as o3d
    from skimage.measure import marching_cubes

    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(
        o3d.core.Tensor(np.asarray(mesh.vertices, np.float32)), o3d.core.Tensor(np.asarray(mesh.faces, np.uint32))
    )
    step = float((mesh.bounds[1] - mesh.bounds[0]).max()) / resolution
    # off the grid by an odd fraction: flat faces exactly on grid nodes give zero distances there,
    # and marching cubes then leaves non-manifold edges
    lo = mesh.bounds[0] - (2 - 0.3819) * step
    shape = tuple(np.ceil((mesh.bounds[1] + 2 * step - lo) / step).astype(int) + 1)
    grid = np.stack(np.meshgrid(*[lo[a] + np.arange(shape[a]) * step for a in range(3)], indexing="ij"), axis=-1)
    sdf = (
        scene.compute_signed_distance(o3d.core.Tensor(grid.reshape(-1, 3).astype(np.float32)), nsamples=3)
        .numpy()
        .reshape(shape)
    )
    verts, faces, _, _ = marching_cubes(sdf, 0.0, spacing=(step,) * 3)
    out = trimesh.Trimesh(verts + lo, faces[:, ::-1], process=True)
    if out.volume < 0:
        out.invert()
    return out


def world_from_up(up: np.ndarray) -> np.ndarray:
    """The rotation (3, 3) that turns the mesh's up axis (a signed coordinate axis) into +Z (Y-up:
    -90 degrees about X); its rows are signed coordinate axes, so it is exact."""
    up = np.asarray(up, dtype=float)
    if np.allclose(up, [0, 0, 1]):
        return np.eye(3)
    if np.allclose(up, [0, 1, 0]):
        return trellis.Y_UP_FROM_Z_UP.T
    k = int(np.argmax(np.abs(up)))
    if not np.isclose(abs(up[k]), 1.0) or not np.isclose(np.abs(up).sum(), 1.0):
        raise ValueError(f"unsupported up axis {up}")
    first = np.zeros(3)
    first[(k + 1) % 3] = 1.0
    return np.stack([first, np.cross(up, first), up])


def choose_unit(rho0: float, tolerance: float = 0.25) -> tuple[float | None, str | None]:
    """For a mesh that claims to be metric: (meters per file unit, that unit's name) when rho_0
    is 1 or a known unit's within ``tolerance`` (ratio), else (None, None): the scale is unknown."""
    for name, scale in {"meters": 1.0, **UNITS}.items():
        if abs(np.log(rho0 / scale)) <= np.log(1.0 + tolerance):
            return scale, name
    return None, None


def axis_name(axis: np.ndarray) -> str:
    k = int(np.argmax(np.abs(axis)))
    return ("-" if axis[k] < 0 else "+") + "xyz"[k]


def vertex_colors(vertices_world, faces, frames, rgb_of, masks, cameras) -> np.ndarray:
    """Linear RGB per vertex: its median color over the frames where it faces the camera and
    falls inside the object's mask; vertices never seen take their nearest seen vertex's."""
    tm = trimesh.Trimesh(vertices_world, faces, process=False)
    normals = tm.vertex_normals
    samples = [[] for _ in range(len(vertices_world))]
    for t in frames:
        pose, K = cameras.world_from_cv[t], cameras.K[t]
        cam = se3.transform_points(se3.invert(pose), vertices_world)
        toward = pose[:3, 3] - vertices_world
        facing = np.einsum("ij,ij->i", normals, toward) > 0
        z = np.maximum(cam[:, 2], 1e-6)
        u = np.round(K[0, 0] * cam[:, 0] / z + K[0, 2]).astype(int)
        v = np.round(K[1, 1] * cam[:, 1] / z + K[1, 2]).astype(int)
        h, w = masks[t].shape
        ok = facing & (cam[:, 2] > 0) & (u >= 0) & (u < w) & (v >= 0) & (v < h)
        idx = np.flatnonzero(ok)
        idx = idx[masks[t][v[idx], u[idx]]]
        rgb = rgb_of(t)
        for i, c in zip(idx, rgb[v[idx], u[idx]]):
            samples[i].append(c)
    seen = np.array([len(s) > 0 for s in samples])
    colors = np.full((len(vertices_world), 3), 0.5)
    if seen.any():
        colors[seen] = srgb8_to_linear(
            np.array([np.median(np.array(s), axis=0) for s in samples if s]).astype(np.uint8)
        )
        if not seen.all():
            nearest = cKDTree(vertices_world[seen]).query(vertices_world[~seen])[1]
            colors[~seen] = colors[seen][nearest]
    return colors


def turned_by_colour(
    local: np.ndarray,
    faces: np.ndarray,
    surface: Surface | None,
    colors: np.ndarray | None,
    pose: np.ndarray,
    frames,
    rgb_of,
    masks,
    cameras,
) -> tuple[np.ndarray, dict | None]:
    """The fitted ``pose`` (world from the mesh's frame, where its vertices are ``local``, its
    textured ``surface`` too, or its linear vertex ``colors`` are per ``local`` vertex) turned by
    the shape symmetry (``geometry.symmetry``: a cube's 24 turns, a box's 4) under which the file's
    own colours (its texture, else its vertex colours) best match ``frames`` of the video inside the
    object's ``masks``: a silhouette or a depth fit cannot tell those turns apart, the print can.
    Kept only when its correlation is at least 0.3 and 0.05 above the pose as fitted. Returns the
    pose and what was measured, None for a file without colours or a shape without symmetry."""
    if surface is None and colors is None:
        return pose, None
    symmetries = shape_symmetries(local, faces)
    if len(symmetries) < 2:
        return pose, None
    if surface is not None:
        samples = coloured_samples(surface.vertices, surface.faces, uv=surface.uv, image=surface.image)
    else:
        samples = coloured_samples(local, faces, linear_colours=colors)
    look = symmetric_look(samples, symmetries)
    total, used = np.zeros(len(symmetries)), 0
    for t in frames[:6]:
        scores = symmetry_scores(look, pose, cameras.world_from_cv[t], cameras.K[t], rgb_of(t), masks[t])
        if scores is not None:
            total, used = total + scores, used + 1
    if not used:
        return pose, None
    total /= used
    best = int(np.argmax(total))
    kept = best != 0 and total[best] >= 0.3 and total[best] >= total[0] + 0.05
    fact = {
        "symmetries": len(symmetries),
        "frames": used,
        "as_fitted": round(float(total[0]), 3),
        "best": round(float(total[best]), 3),
        "turned_deg": round(float(se3.rotation_angle_deg(symmetries[best][:3, :3])), 1) if kept else 0.0,
    }
    return (pose @ symmetries[best] if kept else pose), fact
