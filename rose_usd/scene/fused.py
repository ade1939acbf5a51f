"""Static surfaces from depth maps, made into the scene: what the depth-based scene backends
(``tsdf`` with a sensor's depth, ``stereo`` with plane-sweep stereo's) share.

``Fusion`` is the TSDF volume; the support under each resting object becomes a flat pad
(``SupportPad``, ``lay_pads``, ``flatten_pads``) and enclosed holes of the support are filled
(``fill_support_holes``); ``wrap_collider`` wraps the fused surface into a checked, watertight
slab collider; ``textured_parts`` textures it from the frames (``FrameColors``)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial import cKDTree

from rose_usd.core.color import srgb8_to_linear
from rose_usd.core.watertight import collider_problems
from rose_usd.errors import InputError, MeshError
from rose_usd.geometry.background import StaticBackground
from rose_usd.geometry.frame_median import FrameMedian, FrameStack
from rose_usd.geometry.mesh import faces_facing, self_intersects, submesh
from rose_usd.geometry.texture import bake_texture, transfer_colors
from rose_usd.geometry.wrap import alpha_wrap
from rose_usd.io.images import read_mask
from rose_usd.layers.masks import INTERACTOR, read_masks
from rose_usd.layers.world import read_cameras
from rose_usd.progress import progress
from rose_usd.scene.author import ScenePart
from rose_usd.stage_api import StageContext
from rose_usd.usd.geom import MeshData


def _mask_files(ctx: StageContext, n: int) -> list[list[Path]]:
    """Per frame, the mask files of every object and the interactor (from the masks layer)."""
    masks = read_masks(ctx.stage, n)
    tracks = sorted(masks.names + ([INTERACTOR] if masks.has(INTERACTOR) else []))
    if not tracks:
        raise InputError(
            "no masks to exclude moving parts", path=ctx.stage.GetRootLayer().identifier, hint="run the segment stage"
        )
    return [[f for f in (masks.file(name, t) for name in tracks) if f is not None] for t in range(n)]


def _read_frame_masks(files: list[Path], case) -> list[tuple[Path, np.ndarray]]:
    """One frame's masks (objects and interactor), each checked to be the frames' size."""
    out = []
    for f in files:
        m = read_mask(f)
        if m.shape != (case.height, case.width):
            raise InputError(
                f"mask is {m.shape[1]}x{m.shape[0]}, frames are {case.width}x{case.height}",
                path=f,
                hint="re-run the segment stage",
            )
        out.append((f, m))
    return out


def _moving(frame_masks: list, shape: tuple[int, int]) -> np.ndarray:
    """The union of one frame's masks (uint8 0/1, ``shape``)."""
    moving = np.zeros(shape, np.uint8)
    for _, m in frame_masks:
        moving |= m.astype(np.uint8)
    return moving


def _static_pixels(
    t: int, depth: np.ndarray, frame_masks: list, background: StaticBackground, kernel: np.ndarray
) -> np.ndarray:
    """The static pixels of frame t: with depth, under no mask grown by ``kernel``, and not in
    front of the static world (what the scene is fused and textured from)."""
    moving = _moving(frame_masks, depth.shape)
    fg, _ = background.foreground(t, depth)
    return ~(cv2.dilate(moving, kernel).astype(bool) | fg) & (depth > 0)


class Fusion:
    """A TSDF volume (Open3D's tensor voxel-block grid on the CPU; its legacy ScalableTSDFVolume
    returns no points on CPU in Open3D 0.20) of metric depth frames with colors.

    The grid's blocks are allocated by several threads, so the surface it extracts comes out in
    a different order from run to run (the same points, colors and normals). It is sorted by
    position here, so that nothing downstream (the wrap, the colors' nearest neighbors, the
    texture) can depend on thread timing."""

    def __init__(self, voxel_m: float, depth_max_m: float):
        import open3d as o3d
        import open3d.core as o3c

        self._o3d, self._o3c = o3d, o3c
        self.depth_max_m = depth_max_m
        self.grid = o3d.t.geometry.VoxelBlockGrid(
            attr_names=("tsdf", "weight", "color"),
            attr_dtypes=(o3c.float32, o3c.float32, o3c.float32),
            attr_channels=((1), (1), (3)),
            voxel_size=voxel_m,
            block_resolution=16,
            # Open3D's hash map grows (rehashes) when more blocks are needed, with the same
            # voxels: 50 000 blocks were preallocated before, 4 GB of memory (80 kB a block)
            block_count=4_000,
            device=o3c.Device("CPU:0"),
        )
        self.frames = 0

    def add(self, depth_m: np.ndarray, rgb8: np.ndarray, K: np.ndarray, world_from_cv: np.ndarray) -> bool:
        """Integrate one frame (depth 0 = skip the pixel); False when it has no usable depth."""
        o3d, o3c = self._o3d, self._o3c
        depth = np.where(depth_m <= self.depth_max_m, depth_m, 0.0)
        if not np.any(depth > 0):
            return False
        intr = o3c.Tensor(np.asarray(K, dtype=np.float64))
        extr = o3c.Tensor(np.linalg.inv(world_from_cv))
        depth_img = o3d.t.geometry.Image(o3c.Tensor(np.ascontiguousarray(depth, dtype=np.float32)))
        color_img = o3d.t.geometry.Image(o3c.Tensor(np.ascontiguousarray(rgb8, dtype=np.float32) / 255.0))
        blocks = self.grid.compute_unique_block_coordinates(depth_img, intr, extr, 1.0, self.depth_max_m)
        self.grid.integrate(blocks, depth_img, color_img, intr, intr, extr, 1.0, self.depth_max_m)
        self.frames += 1
        return True

    def points(self) -> tuple[np.ndarray, np.ndarray]:
        """The fused surface as points (V, 3) and colors in [0, 1] (V, 3)."""
        points, colors, _ = self.oriented_points()
        return points, colors

    def oriented_points(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The fused surface as points (V, 3), colors in [0, 1] (V, 3) and unit normals (V, 3)
        pointing out of the material (the TSDF's gradient: toward the cameras that saw it)."""
        if not self.frames:
            return np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3))
        cloud = self.grid.extract_point_cloud()
        points = cloud.point.positions.numpy().astype(float)
        order = np.lexsort(points.T[::-1])  # see the class text: the same frames, the same order
        normals = cloud.point.normals.numpy().astype(float)[order]
        normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
        return points[order], cloud.point.colors.numpy().astype(float)[order], normals

    def mesh(self) -> tuple[np.ndarray, np.ndarray]:
        """The fused surface as a triangle mesh (marching cubes): vertices (V, 3), faces (F, 3),
        in an order set by the geometry alone (vertices sorted, then faces)."""
        mesh = self.grid.extract_triangle_mesh()
        vertices = mesh.vertex.positions.numpy().astype(float)
        order = np.lexsort(vertices.T[::-1])
        rank = np.empty_like(order)
        rank[order] = np.arange(len(order))
        faces = rank[mesh.triangle.indices.numpy().astype(np.int64)]
        faces = faces[np.lexsort(faces.T[::-1])]
        return vertices[order], faces


class FrameColors:
    """Texel colors from the video itself: each texel is projected into ``frames`` and takes the
    median of its linear colors (bilinear) over the frames that see it: ``depth_of`` there within
    ``tol_m`` (+ 2 % of the depth) of the texel, the surface facing the camera (cos >
    ``min_cos``), and the pixel static (no object or interactor mask within ``margin_px``, and,
    with ``background``, not nearer than the static world). The median leaves out what passed
    through (a hand, its shadow). The TSDF's colors are averages over its voxels (``voxel_m``,
    8 mm); the frames hold the texture's own detail (a tablecloth's weave). The projection and
    median run in one Warp kernel (``geometry.frame_median``)."""

    def __init__(
        self,
        ctx: StageContext,
        depth_of,
        frames: list[int],
        *,
        margin_px: int,
        background: StaticBackground | None = None,
        tol_m: float = 0.01,
        min_cos: float = 0.15,
    ):
        case, n = ctx.case, ctx.time_info.n_frames
        cameras = read_cameras(ctx.stage, n)
        masks = _mask_files(ctx, n)
        kernel = np.ones((2 * margin_px + 1, 2 * margin_px + 1), np.uint8)
        depth = np.zeros((len(frames), case.height, case.width), np.float32)
        static = np.zeros((len(frames), case.height, case.width), bool)
        rgb = np.zeros((len(frames), case.height, case.width, 3), np.float32)
        for k, t in enumerate(progress(frames, "scene texture: frames", total=len(frames))):
            depth[k] = depth_of(t)
            frame_masks = _read_frame_masks(masks[t], case)
            if background is not None:
                static[k] = _static_pixels(t, depth[k], frame_masks, background, kernel)
            else:
                static[k] = ~cv2.dilate(_moving(frame_masks, depth[k].shape), kernel).astype(bool) & (depth[k] > 0)
            rgb[k] = srgb8_to_linear(case.rgb(t))
        stack = FrameStack(cameras.world_from_cv[frames], cameras.K[frames], depth, static, rgb)
        self.frames = frames
        self.median = FrameMedian(stack, tol_m=tol_m, rel_tol=0.02, min_cos=min_cos, min_z=0.05)

    def __call__(self, xyz: np.ndarray, normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.median(xyz, normals)


def fill_support_holes(
    points: np.ndarray, *, cell_m: float = 0.01, max_area_m2: float = 0.25, flat_m: float = 0.01
) -> np.ndarray:
    """Points that close the holes of the support surface: what an object that never moved hid
    (the table under it) is never fused, and a wrap spans only gaps narrower than its alpha.

    The points are binned on a horizontal grid; a hole is a connected group of empty cells that
    points surround on every side (enclosed), at most ``max_area_m2``, whose surrounding cells'
    lowest points are flat (their spread within ``flat_m``): it is filled at their median height.
    Returns the new points (N, 3), possibly none."""
    from scipy import ndimage

    lo = points[:, :2].min(axis=0)
    cells = np.floor((points[:, :2] - lo) / cell_m).astype(int)
    shape = tuple(cells.max(axis=0) + 1)
    low = np.full(shape, np.inf)
    np.minimum.at(low, (cells[:, 0], cells[:, 1]), points[:, 2])
    seen = np.isfinite(low)
    holes, count = ndimage.label(ndimage.binary_fill_holes(seen) & ~seen)
    new = []
    for k in range(1, count + 1):
        hole = holes == k
        if hole.sum() * cell_m**2 > max_area_m2:
            continue
        ring = ndimage.binary_dilation(hole, iterations=2) & seen
        z = low[ring]
        if len(z) < 4 or np.percentile(z, 90) - np.percentile(z, 10) > flat_m:
            continue
        ij = np.argwhere(ndimage.binary_dilation(hole, iterations=1))  # overlap the rim a little
        sub = np.linspace(0.25, 0.75, 2)
        offsets = np.array([(a, b) for a in sub for b in sub])
        xy = (ij[:, None, :] + offsets[None, :, :]).reshape(-1, 2) * cell_m + lo
        new.append(np.column_stack([xy, np.full(len(xy), float(np.median(z)))]))
    return np.concatenate(new) if new else np.zeros((0, 3))


@dataclass(frozen=True)
class SupportPad:
    """A flat patch of the support under a resting object: the grid points ``xy`` (N, 2) of its
    footprint, grown by a margin, at ``height_m``."""

    name: str
    height_m: float
    xy: np.ndarray
    cell_m: float
    """The grid's spacing [m]."""

    @property
    def area_m2(self) -> float:
        return len(self.xy) * self.cell_m**2

    @property
    def over_m(self) -> float:
        """A point lies over the footprint when its nearest grid point is within this horizontally
        (a cell's half diagonal is 0.71 of it)."""
        return 0.75 * self.cell_m


def _footprint(xy: np.ndarray, margin_m: float, cell_m: float) -> np.ndarray:
    """Grid points (spacing ``cell_m``) within ``margin_m`` of the convex hull of ``xy``."""
    grow = int(np.ceil(margin_m / cell_m))
    lo = xy.min(axis=0) - (grow + 1) * cell_m
    size = np.ceil((xy.max(axis=0) - lo) / cell_m).astype(int) + grow + 2
    grid = np.zeros((size[1], size[0]), np.uint8)
    hull = cv2.convexHull(np.round((xy - lo) / cell_m).astype(np.int32))
    cv2.fillConvexPoly(grid, hull, 1)
    if grow:
        grid = cv2.dilate(grid, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * grow + 1, 2 * grow + 1)))
    rows, cols = np.nonzero(grid)
    return np.column_stack([cols, rows]) * cell_m + lo


def lay_pads(
    points: np.ndarray, colors: np.ndarray, normals: np.ndarray, pads: list[SupportPad], *, band_m: float = 0.03
):
    """The fused surface with each pad laid in: fused points over a pad's footprint within
    ``band_m`` of its height replaced by its grid points (normals up, colors of their 3 nearest
    remaining fused points). Returns points, colors, normals and the number of points replaced."""
    replaced, new = 0, []
    for pad in pads:
        near = cKDTree(pad.xy).query(points[:, :2], distance_upper_bound=pad.over_m)[0] < np.inf
        drop = near & (np.abs(points[:, 2] - pad.height_m) < band_m)
        replaced += int(drop.sum())
        points, colors, normals = points[~drop], colors[~drop], normals[~drop]
        new.append(np.column_stack([pad.xy, np.full(len(pad.xy), pad.height_m)]))
    if new:
        added = np.concatenate(new)
        colors = np.concatenate([colors, transfer_colors(added, points, colors)])
        points = np.concatenate([points, added])
        normals = np.concatenate([normals, np.tile([0.0, 0.0, 1.0], (len(added), 1))])
    return points, colors, normals, replaced


def flatten_pads(
    vertices: np.ndarray,
    faces: np.ndarray,
    pads: list[SupportPad],
    *,
    band_m: float,
    over_band_m: float,
    up_deg: float = 20.0,
    over_up_deg: float = 45.0,
) -> tuple[np.ndarray, int]:
    """The wrapped collider with its top flat at each pad's height over the pad's footprint.

    The wrap of a flat pad is flat only to its vertices' scatter about its offset surface: it
    leaves sub-millimeter relief there (triangles tilted by up to about a degree), on which a
    resting object rocks in Newton. Every triangle over the footprint must be flat, and the wrap's
    triangles are alpha-sized (3-6 cm), so a triangle over the footprint can have its vertices
    outside it: the vertices set at the pad's height are those within one edge length of the
    footprint (the longest among the flat triangles that reach takes in, grown until that stops
    growing), within ``band_m`` of the pad's height (the pad height is the surface's around the
    object) and facing within ``up_deg`` of up. Over the footprint itself nothing but the pad is
    wrapped (``lay_pads`` replaced the fused surface there), so a vertex there is the pad's when within
    ``over_band_m`` (less than the slab's thickness, so never its underside) and ``over_up_deg``:
    one left out would tilt a triangle under the object. Vertices move only vertically, on a slab
    ``thickness_m`` thick: the caller still checks validity. Returns the vertices and how many
    moved."""
    import trimesh

    if not pads:
        return vertices, 0
    tm = trimesh.Trimesh(vertices, faces, process=False)
    up = tm.vertex_normals[:, 2] > np.cos(np.radians(up_deg))
    edge = np.linalg.norm(vertices[faces] - vertices[np.roll(faces, 1, axis=1)], axis=2).max(axis=1)
    out = vertices.copy()
    moved = 0
    for pad in pads:
        dz = np.abs(out[:, 2] - pad.height_m)
        near_height = dz <= band_m
        near = cKDTree(pad.xy).query(out[:, :2])[0]  # horizontal distance to the footprint (within half a cell)
        flat_faces = (tm.face_normals[:, 2] > np.cos(np.radians(up_deg))) & near_height[faces].all(axis=1)
        # a triangle over the footprint has its vertices within its longest edge of it: grow the
        # reach by the longest edge among the triangles it takes in, until that stops growing
        reach = pad.over_m
        for _ in range(8):
            taken = flat_faces & (near[faces] <= reach).any(axis=1)
            grown = pad.over_m + (float(edge[taken].max()) if taken.any() else 0.0)
            if grown <= reach:
                break
            reach = grown
        over = (near <= pad.over_m) & (dz <= over_band_m) & (tm.vertex_normals[:, 2] > np.cos(np.radians(over_up_deg)))
        snap = ((near <= reach) & near_height & up) | over
        moved += int(np.count_nonzero(out[snap, 2] != pad.height_m))
        out[snap, 2] = pad.height_m
    return out, moved


def wrap_collider(points: np.ndarray, normals: np.ndarray, pads: list[SupportPad], cfg):
    """The collider: the fused surface moved ``offset_m`` into the material, solidified, alpha
    wrapped (coarser until under ``max_triangles``), its top set flat over each pad, checked
    watertight, 2-manifold and free of self-intersections. Returns (vertices, faces, the first
    wrap's triangle count, the alpha used, vertices flattened onto pads)."""
    # the wrap lies offset_m outside what it wraps: it wraps the surface moved offset_m into the
    # material, so that its outside lands on the fused surface (a resting object is not lifted)
    inset = points - cfg.offset_m * normals
    # solidify: a copy of the surface thickness_m lower makes supports (table tops, floors) solid
    # slabs instead of a thin shell that a resting object could be pushed through
    slab = np.concatenate([inset, inset - np.array([0.0, 0.0, cfg.thickness_m])])
    alpha = cfg.alpha_m
    vertices, faces = alpha_wrap(slab, alpha, cfg.offset_m)
    first_triangles = len(faces)
    while len(faces) > cfg.max_triangles and alpha < 0.5:
        # coarser wrap rather than decimation: the wrap's guarantees (no self-intersection) hold
        alpha *= 1.5
        vertices, faces = alpha_wrap(slab, alpha, cfg.offset_m)
    vertices, flattened = flatten_pads(
        vertices, faces, pads, band_m=2 * cfg.offset_m, over_band_m=0.5 * cfg.thickness_m
    )
    problems = collider_problems(vertices, faces)
    if problems:
        raise MeshError(f"the wrapped scene mesh is {', '.join(problems)}", hint="try a larger scene.tsdf.alpha_m")
    if self_intersects(vertices, faces):
        raise MeshError(
            "the wrapped scene mesh intersects itself",
            hint="try a larger scene.tsdf.alpha_m or scene.tsdf.max_triangles",
        )
    return vertices, faces, first_triangles, alpha, flattened


def collider_record(pads: list[SupportPad], no_pad: dict, padded: int, wrapped: tuple) -> dict:
    """What the scene layer records of its collider: the pads (``no_pad``: the objects that got
    none, and why), the fused points they replaced (``lay_pads``) and the wrap (``wrapped``,
    ``wrap_collider``'s result), which passed its checks."""
    _, faces, first_triangles, alpha, flattened = wrapped
    pad_facts = {p.name: {"height_m": round(p.height_m, 4), "area_cm2": round(1e4 * p.area_m2, 1)} for p in pads}
    return {
        "support_pads": pad_facts,
        "no_support_pad": no_pad,
        "pad_replaced_points": padded,
        "pad_flattened_vertices": flattened,
        "wrap_triangles": first_triangles,
        "alpha_m": round(alpha, 4),
        "triangles": int(len(faces)),
        "watertight": True,
        "self_intersections": False,
    }


def textured_parts(
    ctx: StageContext, vertices, faces, points, colors, frame_colors, cfg, folder: Path, name: str = "Reconstruction"
) -> tuple[list[ScenePart], dict]:
    """A mesh (vertices, faces) as visual parts: the triangles that face one of the video's
    cameras textured (``name``; texels from ``frame_colors``, or the 3-NN colors of the fused
    ``points``; the texture written into ``folder``), the others ("Unseen") colored per vertex.
    Returns the parts and what the layer's record says of the texture."""
    # only the triangles that face one of the video's cameras take texels: the slab's underside
    # and the wrap's far sides (about a third of its area) are never seen, and textured with the
    # rest they would take texture from the seen surface and make the packing vary between runs
    facing = faces_facing(vertices, faces, read_cameras(ctx.stage, ctx.time_info.n_frames).world_from_cv[:, :3, 3])
    seen_v, seen_f = submesh(vertices, faces, facing)
    tv, tf, uv, tcols, tex = bake_texture(seen_v, seen_f, points, colors, cfg.texture_size, frame_colors)
    tex_path = Path(folder) / f"{name}.png"
    cv2.imwrite(str(tex_path), cv2.cvtColor(tex, cv2.COLOR_RGB2BGR))
    parts = [ScenePart(name, MeshData(vertices=tv, faces=tf, vertex_colors=tcols, uv=uv, texture=tex_path))]
    if not facing.all():  # what no camera faces: colored per vertex (3-NN), in its own part
        unseen_v, unseen_f = submesh(vertices, faces, ~facing)
        unseen = MeshData(vertices=unseen_v, faces=unseen_f, vertex_colors=transfer_colors(unseen_v, points, colors))
        parts.append(ScenePart("Unseen", unseen))
    record = {
        "texture_px": cfg.texture_size,
        "textured_triangles": int(facing.sum()),
        "texture_frames": len(frame_colors.frames) if frame_colors else 0,
    }
    return parts, record
