"""The tsdf scene backend: fuse the static pixels, wrap them into a valid collider, color it.

1. **Fuse** every ``frame_stride``-th frame's metric depth into a TSDF volume (Open3D, CPU),
   keeping only static pixels: not an object or the interactor (their masks dilated by
   ``mask_margin_px``) and not nearer than the static world (geometry.background), so neither the
   object's resting place nor the hand leaves a ghost.
2. **Wrap** the fused surface with CGAL's 3D alpha wrapping (``alpha_m``, ``offset_m``): a
   closed, 2-manifold, consistently oriented, self-intersection-free shell around it and around
   a copy of it ``thickness_m`` lower (against gravity), so an open table top becomes a solid
   slab that a resting object cannot be pushed through. The wrap lies ``offset_m`` outside what
   it wraps, so it wraps the surface moved ``offset_m`` into the material (along the TSDF's
   normals): the table's collider top is the fused table, and a resting object is not lifted.
   Validity is then checked, never assumed: trimesh must find it watertight and consistently
   wound with positive volume, and CGAL must find no self-intersection.
3. **Budget**: while the wrap has more than ``max_triangles`` triangles, wrap again with a 1.5x
   larger alpha (coarser, and still valid: decimating the wrap with manifold3d can create
   self-intersections), re-checked.
   Under each object resting on the support before it is touched, the fused surface is replaced
   by a flat pad before the wrap (``support_pads``), and the wrap's top is set exactly at the
   pad's height after it (``flatten_pads``).
4. **Color**: each vertex gets the distance-weighted mean color of its 3 nearest fused points
   (the paper's rule). Each texel of a texture baked over xatlas UVs takes the median color of
   its projections into ``texture_frames`` frames that see it (static pixels, depth agreeing,
   facing the camera; ``FrameColors``), or the 3-NN rule where no frame sees it: the TSDF's
   colors are 8 mm voxel averages, the frames keep the surface's own detail. The colors hold the
   video's lighting, so the scene is lit by a unit ambient light.
"""

from __future__ import annotations

import functools
import tempfile
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial import cKDTree

from rose_usd.core import se3
from rose_usd.core.color import srgb8_to_linear
from rose_usd.core.pinhole import backproject, masked_world_points, view_counts
from rose_usd.core.watertight import collider_problems
from rose_usd.errors import InputError, MeshError
from rose_usd.geometry.background import StaticBackground
from rose_usd.geometry.contact import first_contact, ring_height
from rose_usd.geometry.frame_median import FrameMedian, FrameStack
from rose_usd.geometry.mesh import faces_facing, self_intersects, submesh
from rose_usd.geometry.texture import bake_texture, transfer_colors
from rose_usd.geometry.wrap import alpha_wrap
from rose_usd.io.images import read_mask
from rose_usd.layers.masks import INTERACTOR, read_masks
from rose_usd.layers.world import metric_depth_reader, read_cameras
from rose_usd.progress import progress
from rose_usd.render.lighting import Lighting
from rose_usd.scene.author import ScenePart, author_scene
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


def _static_pixels(
    t: int, depth: np.ndarray, frame_masks: list, background: StaticBackground, kernel: np.ndarray
) -> np.ndarray:
    """The static pixels of frame t: with depth, under no mask grown by ``kernel``, and not in
    front of the static world (what the scene is fused and textured from)."""
    moving = np.zeros(depth.shape, np.uint8)
    for _, m in frame_masks:
        moving |= m.astype(np.uint8)
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


def seen_through(
    points: np.ndarray, depth_of, cameras, frames, *, tol_m: float = 0.02, rel: float = 0.03
) -> np.ndarray:
    """Points (N, 3) that more of ``frames`` see through (the depth at their pixel lies beyond
    them by more than ``tol_m`` + ``rel`` x depth) than see (depth within that of them)."""
    through, near, _ = view_counts(
        points, ((depth_of(t), cameras.K[t], cameras.world_from_cv[t]) for t in frames), tol_m=tol_m, rel=rel
    )
    return through > near


CARVE_ABOVE_M = 0.015
"""Carving never touches the support: only fused points this high above it [m]."""


def fuse_static(
    ctx: StageContext, *, voxel_m: float, frame_stride: int, margin_px: int, depth_max_m: float, carve_m: float
):
    """TSDF-fuse the static pixels. Returns the fused surface's points (V, 3), their linear colors
    (V, 3), their outward normals (V, 3), the number of frames fused and the number of points
    carved away."""
    case = ctx.case
    n = ctx.time_info.n_frames
    cameras = read_cameras(ctx.stage, n)
    depth_of = metric_depth_reader(ctx.stage, case, cache=24)
    background = StaticBackground(depth_of, cameras.world_from_cv, cameras.K, case.width, case.height)
    masks = _mask_files(ctx, n)
    volume = Fusion(voxel_m, depth_max_m)
    kernel = np.ones((2 * margin_px + 1, 2 * margin_px + 1), np.uint8)
    used = 0
    frames = range(0, n, frame_stride)
    object_points = []
    for t in progress(frames, "scene fuse", total=len(frames)):
        depth = depth_of(t).copy()
        frame_masks = _read_frame_masks(masks[t], case)
        for f, m in frame_masks:
            if f.parent.name != INTERACTOR:
                v, u = np.nonzero(m[::4, ::4] & (depth[::4, ::4] > 0))
                cam = backproject(4 * u, 4 * v, depth[4 * v, 4 * u], cameras.K[t])
                object_points.append(se3.transform_points(cameras.world_from_cv[t], cam))
        depth[~_static_pixels(t, depth, frame_masks, background, kernel)] = 0.0
        used += volume.add(depth, case.rgb(t), cameras.K[t], cameras.world_from_cv[t])
    points, colors01, normals = volume.oriented_points()
    # carve: fused surface above the support and within carve_m of where an object was seen is
    # a piece of an object its masks missed (the top of a can that never moves), not scene
    carved = 0
    objs = np.concatenate(object_points) if object_points else np.zeros((0, 3))
    objs = objs[objs[:, 2] > CARVE_ABOVE_M]
    if len(objs) and len(points):
        near = cKDTree(objs).query(points, distance_upper_bound=carve_m)[0] < carve_m
        near &= points[:, 2] > CARVE_ABOVE_M
        carved = int(near.sum())
        points, colors01, normals = points[~near], colors01[~near], normals[~near]
    # free space: a fused point that more frames see through (their depth lies well behind it)
    # than see it was there only for a while (a moving part its masks missed in a few frames)
    transient = seen_through(points, depth_of, cameras, range(0, n, max(1, n // 60)))
    carved += int(transient.sum())
    points, colors01, normals = points[~transient], colors01[~transient], normals[~transient]
    if len(points) < 100:
        raise InputError(
            f"the fused static volume is empty ({len(points)} points from {used} frames)",
            path=case.folder,
            hint="check the depth and the masks: every pixel may have been masked as moving",
        )
    colors = srgb8_to_linear(np.clip(colors01 * 255.0 + 0.5, 0, 255).astype(np.uint8))
    return points, colors, normals, used, carved


class FrameColors:
    """Texel colors from the video itself: each texel is projected into ``count`` frames spread
    over the video and takes the median of its linear colors (bilinear) over the frames that see
    it: the frame's depth there within ``tol_m`` (+ 2 % of the depth) of the texel, the surface
    facing the camera (cos > ``min_cos``), and the pixel static (no object or interactor mask
    within ``margin_px``, not nearer than the static world). The median leaves out what passed
    through (a hand, its shadow). The TSDF's colors are averages over its voxels (``voxel_m``, 8 mm);
    the frames hold the texture's own detail (a tablecloth's weave). The projection and median
    run in one Warp kernel (``geometry.frame_median``)."""

    def __init__(self, ctx: StageContext, *, count: int, margin_px: int, tol_m: float = 0.01, min_cos: float = 0.15):
        case, n = ctx.case, ctx.time_info.n_frames
        cameras = read_cameras(ctx.stage, n)
        depth_of = metric_depth_reader(ctx.stage, case, cache=4)
        frames = np.unique(np.linspace(0, n - 1, min(count, n)).round().astype(int)).tolist()
        background = StaticBackground(depth_of, cameras.world_from_cv, cameras.K, case.width, case.height)
        masks = _mask_files(ctx, n)
        kernel = np.ones((2 * margin_px + 1, 2 * margin_px + 1), np.uint8)
        depth = np.zeros((len(frames), case.height, case.width), np.float32)
        static = np.zeros((len(frames), case.height, case.width), bool)
        rgb = np.zeros((len(frames), case.height, case.width, 3), np.float32)
        for k, t in enumerate(progress(frames, "scene texture: frames", total=len(frames))):
            depth[k] = depth_of(t)
            static[k] = _static_pixels(t, depth_of(t), _read_frame_masks(masks[t], case), background, kernel)
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


def support_pads(
    ctx: StageContext, *, margin_m: float, cell_m: float = 0.004, max_gap_m: float = 0.025, count: int = 8
) -> tuple[list[SupportPad], dict[str, str]]:
    """Where each object rests before the interactor first touches it, the support under it as a
    flat pad at the height the object stage stands it on (``geometry.contact.ring_height``).

    The table under a resting object is never seen while it rests, and what is fused there from
    other frames is what the depth makes of it: with MegaSaM's, bumps and slopes of several
    millimeters, on which Newton's object rocks or slides. The footprint is the convex hull of the
    object's seen points (its top seen from above covers it), grown by ``margin_m``. An object
    whose lowest seen points lie more than ``max_gap_m`` above the surface around it does not
    stand on it (held, or on another object) and gets no pad. (A real sensor's masks leave out
    an object's lowest centimetre: the segmenter takes only what stands above the support's depth
    noise, 11 mm on cups-rgbd, whose ball's lowest masked points are 16 mm above the ring.)
    Returns the pads and, per object without one, why."""
    case, n = ctx.case, ctx.time_info.n_frames
    cameras = read_cameras(ctx.stage, n)
    depth_of = metric_depth_reader(ctx.stage, case, cache=8)
    layer = read_masks(ctx.stage, n)
    hand_of = functools.partial(layer.mask, INTERACTOR) if layer.has(INTERACTOR) else (lambda t: None)
    pads, skipped = [], {}
    for spec in case.config.objects:
        masks = layer.track(spec.name)
        area = np.array([0 if m is None else int(m.sum()) for m in masks])
        masks = [m if a >= 50 else None for m, a in zip(masks, area, strict=True)]
        if not np.any(area >= 50):
            skipped[spec.name] = "never visible"
            continue
        touched = first_contact(masks, hand_of, depth_of, n)
        clear = np.flatnonzero(area >= max(50, 0.5 * np.percentile(area[area >= 50], 90)))
        frames = [int(t) for t in clear if t < touched]
        if not frames:
            skipped[spec.name] = "touched before it is clearly seen"
            continue
        occluders = functools.partial(layer.occluders, spec.name, grow_px=3)
        height = ring_height(occluders, [(t, 1.0) for t in frames], masks, depth_of, cameras, count=count)
        seen = []
        for t in [frames[i] for i in np.unique(np.linspace(0, len(frames) - 1, min(count, len(frames))).astype(int))]:
            seen.append(
                masked_world_points(depth_of(t), masks[t], cameras.K[t], cameras.world_from_cv[t], erode_px=2)[0]
            )
        pts = np.concatenate(seen)
        pts = pts[pts[:, 2] > height + 0.005]
        if len(pts) < 50:
            skipped[spec.name] = "too few points above the surface around it"
            continue
        gap = float(np.percentile(pts[:, 2], 2)) - height
        if gap > max_gap_m:
            skipped[spec.name] = (
                f"its lowest points are {1000 * gap:.0f} mm above the surface around it (held, or on another object)"
            )
            continue
        pads.append(SupportPad(spec.name, height, _footprint(pts[:, :2], margin_m, cell_m), cell_m))
    return pads, skipped


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


def run(ctx: StageContext) -> None:
    cfg = ctx.config.tsdf
    points, colors, normals, used, carved = fuse_static(
        ctx,
        voxel_m=cfg.voxel_m,
        frame_stride=cfg.frame_stride,
        margin_px=cfg.mask_margin_px,
        depth_max_m=cfg.depth_max_m,
        carve_m=cfg.carve_m,
    )
    pads, no_pad = support_pads(ctx, margin_m=cfg.pad_margin_m) if cfg.pad_margin_m > 0 else ([], {})
    points, colors, normals, padded = lay_pads(points, colors, normals, pads)
    filled = fill_support_holes(points)
    if len(filled):  # colored by their nearest fused neighbors, like any other point
        colors = np.concatenate([colors, transfer_colors(filled, points, colors)])
        points = np.concatenate([points, filled])
        normals = np.concatenate([normals, np.tile([0.0, 0.0, 1.0], (len(filled), 1))])
    vertices, faces, first_triangles, alpha, flattened = wrap_collider(points, normals, pads, cfg)
    frame_colors = (
        FrameColors(ctx, count=cfg.texture_frames, margin_px=cfg.mask_margin_px) if cfg.texture_frames > 0 else None
    )
    # only the triangles that face one of the video's cameras take texels: the slab's underside
    # and the wrap's far sides (about a third of its area) are never seen, and textured with the
    # rest they would take texture from the seen surface and make the packing vary between runs
    facing = faces_facing(vertices, faces, read_cameras(ctx.stage, ctx.time_info.n_frames).world_from_cv[:, :3, 3])
    seen_v, seen_f = submesh(vertices, faces, facing)
    tv, tf, uv, tcols, tex = bake_texture(seen_v, seen_f, points, colors, cfg.texture_size, frame_colors)
    with tempfile.TemporaryDirectory() as tmp:
        tex_path = Path(tmp) / "Reconstruction.png"
        cv2.imwrite(str(tex_path), cv2.cvtColor(tex, cv2.COLOR_RGB2BGR))
        parts = [
            ScenePart("Reconstruction", MeshData(vertices=tv, faces=tf, vertex_colors=tcols, uv=uv, texture=tex_path))
        ]
        if not facing.all():  # what no camera faces: colored per vertex (3-NN), in its own part
            unseen_v, unseen_f = submesh(vertices, faces, ~facing)
            parts.append(
                ScenePart(
                    "Unseen",
                    MeshData(
                        vertices=unseen_v, faces=unseen_f, vertex_colors=transfer_colors(unseen_v, points, colors)
                    ),
                )
            )
        collision = MeshData(vertices=vertices, faces=faces)
        author_scene(ctx, parts, collision, Lighting.unlit(), support={p.name: p.height_m for p in pads})
    ctx.record(
        fused_frames=used,
        fused_points=int(len(points)),
        support_hole_points=int(len(filled)),
        support_pads={p.name: {"height_m": round(p.height_m, 4), "area_cm2": round(1e4 * p.area_m2, 1)} for p in pads},
        no_support_pad=no_pad,
        pad_replaced_points=padded,
        pad_flattened_vertices=flattened,
        carved_points=carved,
        wrap_triangles=first_triangles,
        alpha_m=round(alpha, 4),
        triangles=int(len(faces)),
        watertight=True,
        self_intersections=False,
        texture_px=cfg.texture_size,
        textured_triangles=int(facing.sum()),
        texture_frames=len(frame_colors.frames) if frame_colors else 0,
    )
