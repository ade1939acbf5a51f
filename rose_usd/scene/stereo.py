"""The stereo scene backend: the plane backend's scene, with what a moving camera's parallax
measures added (RGB only, no depth).

1. **References**: up to ``keyframes`` reference frames spread over the video, each with up to
   ``sources`` source frames, the nearest in time on either side whose camera stands at least
   ``min_baseline`` (then twice that) of the reference camera's distance to the world origin
   away, and turned less than ``max_turn_deg`` from it; a reference with fewer than two is
   dropped. With fewer than two references left (a static or near-static camera has no
   parallax), the scene is the plane backend's.
2. **Depth** of each reference by plane-sweep stereo at ``max_side_px`` (``geometry.stereo``: ZNCC
   over the sources, planes between ``near`` and ``far`` times the camera's distance to the world
   origin), every object's and the interactor's masks (grown by ``scene.tsdf.mask_margin_px``)
   left out in the reference and its sources; kept where a neighbouring reference agrees within
   ``agree_rel`` (``geometry.stereo.consistent``).
3. **The support**: the plane backend's (z = 0, its convex hull) in ``support_cell_m`` cells,
   less where the references see past the plane (``through_rel``) more often than on it: a
   table ends where the floor below it is seen (``SupportGrid``).
4. **What stands on it**: the depths fused in a TSDF (``scene.tsdf.voxel_m``); the points over
   the support's cells that rise above the support as stereo sees it (``geometry.support``) by
   more than ``support_band_m`` and ``standing_rel`` of their distance to the nearest reference,
   in clusters of ``min_standing_points`` that rise ``min_rise_m`` more, not over an object's pad.
5. **Collider and looks**: the support's cells at z = 0, a flat pad at z = 0 under each object
   (``object_pads``) and what stands, alpha wrapped and checked as the tsdf backend's (its
   settings); the visual parts are the plane scene's ``Support`` and ``Backdrop`` and the
   wrap's standing triangles, ``Standing``, textured from ``scene.tsdf.texture_frames`` frames
   whose visibility comes from the wrap itself (ray cast, Open3D). Objects stand at z = 0.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial import cKDTree

from rose_usd.core.color import srgb8_to_linear
from rose_usd.core.pinhole import backproject, resized_K, view_counts
from rose_usd.core.runs import spread_frames
from rose_usd.geometry.mesh import submesh
from rose_usd.geometry.stereo import SweepParams, View, consistent, sweep
from rose_usd.geometry.support import SupportSurface
from rose_usd.geometry.texture import transfer_colors
from rose_usd.layers.masks import read_masks
from rose_usd.layers.world import read_cameras
from rose_usd.progress import progress
from rose_usd.render.lighting import Lighting
from rose_usd.scene.author import author_scene
from rose_usd.scene.backdrop import author_plane, plane_scene
from rose_usd.scene.fused import (
    FrameColors,
    Fusion,
    SupportPad,
    _footprint,
    _mask_files,
    _moving,
    _read_frame_masks,
    collider_record,
    lay_pads,
    textured_parts,
    wrap_collider,
)
from rose_usd.stage_api import StageContext
from rose_usd.usd.geom import MeshData

PAD_CELL_M = 0.004
"""Grid spacing of a pad's footprint [m] (as the tsdf backend's pads)."""
CLOSE_CELLS = 5
"""Carved parts of the support narrower than about this many cells are closed again."""


def choose_sources(
    world_from_cv: np.ndarray, ref: int, *, count: int, min_baseline: float, max_turn_deg: float
) -> list[int]:
    """Source frames of reference frame ``ref``: on each side in time, the nearest frames whose
    cameras stand at least ``min_baseline`` (then 2x, 3x ...) times the reference camera's distance
    to the world origin from it and turned less than ``max_turn_deg``, ``count`` in all (half a
    side where both have them)."""
    n = len(world_from_cv)
    c = world_from_cv[ref, :3, 3]
    reach = max(float(np.linalg.norm(c)), 1e-6)
    axis = world_from_cv[ref, :3, 2]
    cos_max = np.cos(np.radians(max_turn_deg))
    sides = []
    for step in (-1, 1):
        got, t = [], ref
        while 0 <= t + step < n and len(got) < count:
            t += step
            if float(world_from_cv[t, :3, 2] @ axis) < cos_max:
                break
            if np.linalg.norm(world_from_cv[t, :3, 3] - c) >= min_baseline * reach * (len(got) + 1):
                got.append(t)
        sides.append(got)
    before, after = sides
    half = count // 2
    take_b = min(len(before), max(half, count - len(after)))
    take_a = min(len(after), count - take_b)
    return sorted(before[:take_b] + after[:take_a])


def support_hits(u, v, K: np.ndarray, world_from_cv: np.ndarray):
    """Where the rays of pixels (u, v) meet the plane z = 0: their depth there (the distance along
    the optical axis; inf for a ray that goes up), the points' xy (..., 2) and which rays go down."""
    rays = backproject(u, v, 1.0, K) @ world_from_cv[:3, :3].T
    down = rays[..., 2] < -1e-6
    depth = np.where(down, -world_from_cv[2, 3] / np.where(down, rays[..., 2], -1.0), np.inf)
    xy = world_from_cv[:2, 3] + np.where(down, depth, 0.0)[..., None] * rays[..., :2]
    return depth, xy, down


def object_pads(ctx: StageContext, cameras, layer, margin_m: float) -> tuple[list[SupportPad], dict[str, str]]:
    """A flat pad at z = 0 under each object: where its first clear mask's pixels meet the support
    plane (those within 1.5 times the median distance from the camera, so a ray that grazes the
    plane does not stretch it), grown by ``margin_m``. Returns the pads and, per object without
    one, why."""
    pads, skipped = [], {}
    for spec in ctx.case.config.objects:
        if not layer.has(spec.name):
            skipped[spec.name] = "no masks"
            continue
        area = layer.visible_pixels(spec.name)
        clear = np.flatnonzero(area >= max(50, 0.5 * area.max()))
        if not len(clear):
            skipped[spec.name] = "never visible"
            continue
        t = int(clear[0])
        v, u = np.nonzero(layer.mask(spec.name, t))
        _, xy, down = support_hits(u, v, cameras.K[t], cameras.world_from_cv[t])
        xy = xy[down]
        if len(xy) < 10:
            skipped[spec.name] = f"its mask at frame {t} lies above the horizon"
            continue
        dist = np.linalg.norm(xy - cameras.world_from_cv[t, :2, 3], axis=1)
        xy = xy[dist <= 1.5 * np.median(dist)]
        pads.append(SupportPad(spec.name, 0.0, _footprint(xy, margin_m, PAD_CELL_M), PAD_CELL_M))
    return pads, skipped


def _view(ctx: StageContext, cameras, t: int, files: list, s: float, kernel) -> View:
    case = ctx.case
    gray = cv2.cvtColor(case.rgb(t), cv2.COLOR_RGB2GRAY).astype(np.float32)
    moving = cv2.dilate(_moving(_read_frame_masks(files, case), gray.shape), kernel)
    size = (max(2, round(case.width * s)), max(2, round(case.height * s)))
    if s < 1:
        gray = cv2.resize(gray, size, interpolation=cv2.INTER_AREA)
        moving = cv2.resize(moving, size, interpolation=cv2.INTER_NEAREST)
    return View(gray, resized_K(cameras.K[t], s), cameras.world_from_cv[t], moving.astype(bool))


def stereo_depths(ctx: StageContext, cameras, refs: dict[int, list[int]], cfg, margin_px: int):
    """Each reference's depth (at ``max_side_px``) kept where a neighbouring reference agrees:
    {t: (depth (h, w) [m], View)}, and per reference the fraction of its pixels with a depth
    before and after the agreement check."""
    case, n = ctx.case, ctx.time_info.n_frames
    s = min(1.0, cfg.max_side_px / max(case.width, case.height))
    kernel = np.ones((2 * margin_px + 1, 2 * margin_px + 1), np.uint8)
    masks = _mask_files(ctx, n)
    params = SweepParams(planes=cfg.planes, window_px=cfg.window_px, min_zncc=cfg.min_zncc)
    views: dict[int, View] = {}

    def view(t: int) -> View:
        if t not in views:
            views[t] = _view(ctx, cameras, t, masks[t], s, kernel)
        return views[t]

    raw = {}
    for r in progress(sorted(refs), "scene stereo: depth", total=len(refs)):
        reach = float(np.linalg.norm(cameras.world_from_cv[r, :3, 3]))
        raw[r], _ = sweep(view(r), [view(t) for t in refs[r]], cfg.near * reach, cfg.far * reach, params)
        for t in [t for t in views if t not in refs and t < min(refs[r])]:
            del views[t]  # a frame behind this reference's sources is seldom asked for again
    keys = sorted(raw)
    out, kept = {}, {}
    for i, r in enumerate(keys):
        near = keys[max(0, i - 2) : i] + keys[i + 1 : i + 3]
        ok = consistent(raw[r], view(r), [(raw[o], view(o)) for o in near], rel_tol=cfg.agree_rel)
        out[r] = (np.where(ok, raw[r], 0.0).astype(np.float32), view(r))
        kept[r] = (round(float((raw[r] > 0).mean()), 3), round(float(ok.mean()), 3))
    return out, kept


def _raycast_depth(vertices: np.ndarray, faces: np.ndarray, cameras, width: int, height: int):
    """A function t -> the mesh's depth seen from frame t (H, W) float32 [m], 0 where no hit."""
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(
        o3d.core.Tensor(np.ascontiguousarray(vertices, np.float32)),
        o3d.core.Tensor(np.ascontiguousarray(faces, np.uint32)),
    )
    v, u = np.indices((height, width), dtype=np.float64)

    def depth_of(t: int) -> np.ndarray:
        pose = cameras.world_from_cv[t]
        dirs = backproject(u, v, 1.0, cameras.K[t]) @ pose[:3, :3].T
        rays = np.concatenate([np.broadcast_to(pose[:3, 3], dirs.shape), dirs], axis=-1).astype(np.float32)
        hit = scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()  # along a ray of unit depth: the depth
        return np.where(np.isfinite(hit), hit, 0.0).astype(np.float32)

    return depth_of


def plane_depth(view: View, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Per pixel of a view (``shape``), the depth at which its ray meets the plane z = 0 (inf where
    it goes up) and that point's xy: ((H, W), (H, W, 2))."""
    v, u = np.indices(shape, dtype=float)
    depth, xy, _ = support_hits(u, v, view.K, view.world_from_cv)
    return depth, xy


class SupportGrid:
    """The support plane as cells of ``cell_m`` over the convex hull of ``xy`` (the plane
    backend's support), with stereo's evidence per cell: how many reference pixels saw the plane
    there (``on``) and how many saw through it (``through``: a depth beyond the plane, the floor
    past a table's edge)."""

    def __init__(self, xy: np.ndarray, cell_m: float):
        self.cell = cell_m
        self.lo = xy.min(axis=0) - cell_m
        size = np.ceil((xy.max(axis=0) - self.lo) / cell_m).astype(int) + 2
        self.inside = np.zeros((size[1], size[0]), np.uint8)
        hull = cv2.convexHull(np.round((xy - self.lo) / cell_m).astype(np.int32))
        cv2.fillConvexPoly(self.inside, hull, 1)
        self.on = np.zeros(self.inside.shape, np.int32)
        self.through = np.zeros(self.inside.shape, np.int32)

    def cells(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(row, col, on the grid) of points (N, 2)."""
        ij = np.floor((xy - self.lo) / self.cell).astype(np.int64)
        ok = (ij[:, 0] >= 0) & (ij[:, 1] >= 0) & (ij[:, 0] < self.inside.shape[1]) & (ij[:, 1] < self.inside.shape[0])
        return np.where(ok, ij[:, 1], 0), np.where(ok, ij[:, 0], 0), ok

    def add(self, depth: np.ndarray, view: View, tol: float) -> None:
        """A reference's evidence: its pixels with a depth within ``tol`` of the plane's see it,
        those beyond it by more see through it."""
        plane, xy = plane_depth(view, depth.shape)
        has = (depth > 0) & np.isfinite(plane)
        for counts, sel in (
            (self.on, has & (np.abs(depth - plane) <= tol * plane)),
            (self.through, has & (depth > (1 + tol) * plane)),
        ):
            r, c, ok = self.cells(xy[sel])
            np.add.at(counts, (r[ok], c[ok]), 1)

    def seen_through(self) -> np.ndarray:
        """The hull's cells (bool) seen through more often than seen, and at least twice."""
        return (self.inside > 0) & (self.through >= 2) & (self.through > self.on)

    def kept(self, anchors_xy: np.ndarray) -> np.ndarray:
        """The cells (bool) of the support: inside the hull, not seen through more often than seen
        (and at least twice) unless closed in by the support (``CLOSE_CELLS``), in the connected
        parts that hold an anchor (the world origin, the objects' pads), or all when none does."""
        keep = (self.inside > 0) & ~self.seen_through()
        # a support has no holes a hand wide: stray far matches carve none
        disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (CLOSE_CELLS, CLOSE_CELLS))
        keep = (cv2.morphologyEx(keep.astype(np.uint8), cv2.MORPH_CLOSE, disc) > 0) & (self.inside > 0)
        _, labels = cv2.connectedComponents(keep.astype(np.uint8), connectivity=4)
        r, c, ok = self.cells(anchors_xy)
        wanted = {int(x) for x in labels[r[ok], c[ok]] if x > 0}
        return np.isin(labels, sorted(wanted)) if wanted else keep

    def centers(self, cells: np.ndarray) -> np.ndarray:
        rows, cols = np.nonzero(cells)
        return self.lo + (np.column_stack([cols, rows]) + 0.5) * self.cell


def standing_clusters(points: np.ndarray, rise: np.ndarray, eps_m: float, min_points: int, min_rise_m: float):
    """Which points (bool) lie in a cluster (points within ``eps_m`` of one another, DBSCAN) of at
    least ``min_points`` whose highest point rises at least ``min_rise_m`` over the band above the
    support (``rise``, per point [m]): things on a table are such clusters; stereo's stray
    matches stand as specks, and its noise over a plain stretch of table as low sheets."""
    if len(points) < min_points:
        return np.zeros(len(points), bool)
    import open3d as o3d

    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.ascontiguousarray(points, np.float64)))
    labels = np.asarray(cloud.cluster_dbscan(eps=eps_m, min_points=3))
    if not (labels >= 0).any():
        return np.zeros(len(points), bool)
    sizes = np.bincount(labels[labels >= 0])
    tops = np.full(len(sizes), -np.inf)
    np.maximum.at(tops, labels[labels >= 0], rise[labels >= 0])
    good = (sizes >= min_points) & (tops >= min_rise_m)
    return (labels >= 0) & good[np.maximum(labels, 0)]


def _standing_faces(vertices: np.ndarray, faces: np.ndarray, band_m: float) -> np.ndarray:
    """Triangles (bool) that stand above the support: a vertex higher than ``band_m``."""
    return (vertices[faces][:, :, 2] > band_m).any(axis=1)


def references(cameras, cfg) -> dict[int, list[int]]:
    """Reference frames spread over the video, each with its source frames (at least two)."""
    refs = {}
    for r in spread_frames(len(cameras.world_from_cv), cfg.keyframes):
        src = choose_sources(
            cameras.world_from_cv, r, count=cfg.sources, min_baseline=cfg.min_baseline, max_turn_deg=cfg.max_turn_deg
        )
        if len(src) >= 2:
            refs[r] = src
    return refs


def standing_points(ctx: StageContext, depths: dict, grid: SupportGrid, support: np.ndarray, pads, cfg, tcfg):
    """What stands on the support (the module's step 4): fused points (N, 3), their linear colors
    and normals, and the support's height field as stereo sees it."""
    volume = Fusion(tcfg.voxel_m, tcfg.depth_max_m)
    for r, (depth, view) in depths.items():
        rgb = cv2.resize(ctx.case.rgb(r), (depth.shape[1], depth.shape[0]), interpolation=cv2.INTER_AREA)
        volume.add(depth, rgb, view.K, view.world_from_cv)
    points, colors01, normals = volume.oriented_points()
    views = [(d, v.K, v.world_from_cv) for d, v in depths.values()]
    through, near, _ = view_counts(points, views, tol_m=0.02, rel=0.03)
    r, c, ok = grid.cells(points[:, :2])
    over = cv2.dilate(support.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    # heights over the support as stereo sees it: the capture's plane can be a degree or two off
    # the table, a centimetre at 40 cm
    keys = sorted(depths)
    poses = np.stack([depths[k][1].world_from_cv for k in keys])
    Ks = np.stack([depths[k][1].K for k in keys])
    surface = SupportSurface(lambda i: depths[keys[i]][0], poses, Ks, list(range(len(keys))), stride=2)
    above = surface.height_above(points)
    # stereo's error grows with distance: a point stands when it rises above the support by more
    # than the band and than standing_rel of its distance to the nearest reference camera
    band = np.maximum(cfg.support_band_m, cfg.standing_rel * cKDTree(poses[:, :3, 3]).query(points)[0])
    standing = ok & over[r, c] & (above > band) & (through <= near)
    for pad in pads:  # over an object's pad stands the object (what its masks missed of it)
        standing &= cKDTree(pad.xy).query(points[:, :2], distance_upper_bound=pad.over_m)[0] == np.inf
    standing[standing] = standing_clusters(
        points[standing], above[standing] - band[standing], 2.5 * tcfg.voxel_m, cfg.min_standing_points, cfg.min_rise_m
    )
    colors = srgb8_to_linear(np.clip(colors01[standing] * 255.0 + 0.5, 0, 255).astype(np.uint8))
    return points[standing], colors, normals[standing], surface


def run(ctx: StageContext) -> None:
    cfg, tcfg = ctx.config.stereo, ctx.config.tsdf
    case, n = ctx.case, ctx.time_info.n_frames
    cameras = read_cameras(ctx.stage, n)
    refs = references(cameras, cfg)
    if len(refs) < 2:
        author_plane(ctx)
        ctx.built_as("plane")
        ctx.warn(
            f"the camera moves too little for stereo ({len(refs)} reference frames with parallax): the scene is"
            " the plane backend's (the support as a slab, the rest a backdrop)"
        )
        ctx.record(stereo=f"{len(refs)} reference frames with parallax: the plane backend's scene")
        return
    layer = read_masks(ctx.stage, n, (case.height, case.width))
    base = plane_scene(ctx, cameras, layer, ctx.config.plane)
    depths, kept = stereo_depths(ctx, cameras, refs, cfg, tcfg.mask_margin_px)
    # the support: the plane backend's, less where stereo sees through it
    grid = SupportGrid(base.support_xy(), cfg.support_cell_m)
    for depth, view in depths.values():
        grid.add(depth, view, cfg.through_rel)
    pads, no_pad = object_pads(ctx, cameras, layer, tcfg.pad_margin_m)
    support = grid.kept(np.concatenate([np.zeros((1, 2))] + [p.xy for p in pads]))
    standing, colors, normals, surface = standing_points(ctx, depths, grid, support, pads, cfg, tcfg)
    # the collider: the support's cells at z = 0 and what stands on them, wrapped
    floor = np.column_stack([grid.centers(support), np.zeros(int(support.sum()))])
    floor_colors = transfer_colors(floor, standing, colors) if len(standing) else np.full((len(floor), 3), 0.5)
    points, colors = np.concatenate([floor, standing]), np.concatenate([floor_colors, colors])
    normals = np.concatenate([np.tile([0.0, 0.0, 1.0], (len(floor), 1)), normals])
    points, colors, normals, padded = lay_pads(points, colors, normals, pads)
    wrapped = wrap_collider(points, normals, pads, tcfg)
    vertices, faces = wrapped[:2]
    up, textured = _author(ctx, cameras, base, vertices, faces, points, colors, cfg, tcfg)
    ctx.record(
        reference_frames={str(r): {"sources": refs[r], "depth": kept[r][0], "agreed": kept[r][1]} for r in depths},
        working_px=list(next(iter(depths.values()))[0].shape[::-1]),
        support_area_m2=round(float(support.sum()) * cfg.support_cell_m**2, 3),
        support_hull_area_m2=round(float(grid.inside.sum()) * cfg.support_cell_m**2, 3),
        support_cells_seen_through=int(grid.seen_through().sum()),
        standing_points=int(len(standing)),
        support_relief_mm=surface.relief_mm(),
        **collider_record(pads, no_pad, padded, wrapped),
        standing_triangles=int(up.sum()),
        **base.record(),
        standing_texture=textured,
    )


def _author(ctx: StageContext, cameras, base, vertices, faces, points, colors, cfg, tcfg):
    """Write the scene layer: the plane scene's visual parts, the wrap's standing triangles as
    ``Standing`` (textured from the frames, their visibility from the wrap), the wrap as the
    collider. Returns which triangles stand and the texture's record."""
    case, n = ctx.case, ctx.time_info.n_frames
    up = _standing_faces(vertices, faces, cfg.support_band_m)
    frame_colors = None
    if tcfg.texture_frames > 0 and up.any():
        depth_of = _raycast_depth(vertices, faces, cameras, case.width, case.height)
        frame_colors = FrameColors(ctx, depth_of, spread_frames(n, tcfg.texture_frames), margin_px=tcfg.mask_margin_px)
    with tempfile.TemporaryDirectory() as tmp:
        tex_path = Path(tmp) / "Support.png"
        cv2.imwrite(str(tex_path), cv2.cvtColor(base.texture, cv2.COLOR_RGB2BGR))
        parts, textured = base.parts(tex_path), {}
        if up.any():
            sv, sf = submesh(vertices, faces, up)
            more, textured = textured_parts(ctx, sv, sf, points, colors, frame_colors, tcfg, Path(tmp), "Standing")
            parts += more
        collision = MeshData(vertices=vertices, faces=faces)
        author_scene(ctx, parts, collision, Lighting.unlit(), support={spec.name: 0.0 for spec in case.config.objects})
    return up, textured
