"""The plane backend's scene (``author_plane``), which the stereo backend builds on: the support
surface and a textured backdrop, for videos without depth.

An RGB-only world knows one surface for sure: the support plane (z = 0) the objects rest on. What
lies beyond it (walls, furniture, a person) has no depth. So the scene is:

1. **Support** (visual and collider): the support plane as far as the reference camera (frame 0)
   sees it, out to ``wall_distance`` (``backdrop_reach`` times the camera's horizontal distance to
   the world origin, the object's foot, and at least ``object_reach`` times the farthest foot of
   an object masked in that frame, within 0.3-5 m, so every object stands on it): its visual mesh is textured from the
   video, and the collider is that region of the plane as a solid slab ``thickness_m`` thick (a
   prism: watertight by construction, checked as every collider is).
2. **Backdrop** (visual only, not collidable, named so): everything the camera sees beyond that
   distance or above the horizon, on a vertical cylinder of that radius around the camera's
   vertical, so floor and backdrop meet without a seam (a photo studio's cyclorama). Its depth is
   a choice, not a measurement: for a static camera, and for one that only turns, any depth
   re-renders the same picture; for a moving camera the backdrop is wrong by its parallax, which
   the gate's SSIM then shows.

Both are one grid over the reference image (``grid_px`` apart), extended to cover what the other
frames see, each vertex on the plane or the cylinder along its pixel's ray. The texture holds the
extended reference image plane: each texel is the median color of its 3D point's projections
into up to ``texture_frames`` frames spread over the video where no object's or interactor's mask
(grown by ``mask_margin_px``) covers it: the static background, objects and hands taken out,
what they always hid filled by inpainting. Lit by a unit ambient light (the video's own lighting
is in the texture).
"""

from __future__ import annotations

import tempfile
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from rose_usd.core import se3
from rose_usd.core.pinhole import project
from rose_usd.errors import MeshError
from rose_usd.geometry.frame_median import median_over_frames
from rose_usd.geometry.mesh import check_collider, self_intersects
from rose_usd.layers.masks import INTERACTOR, read_masks
from rose_usd.layers.world import read_cameras
from rose_usd.progress import progress
from rose_usd.render.lighting import Lighting
from rose_usd.scene.author import ScenePart, author_scene
from rose_usd.stage_api import StageContext
from rose_usd.usd.geom import MeshData


def backdrop_points(
    u: np.ndarray, v: np.ndarray, K: np.ndarray, world_from_cv: np.ndarray, wall_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """World points (N, 3) of pixels (u, v) of a camera on the backdrop surface: the plane z = 0
    within horizontal distance ``wall_m`` of the camera, else a vertical cylinder of that radius
    about the camera's vertical; and which of them lie on the plane."""
    rays = (
        np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], axis=-1) @ world_from_cv[:3, :3].T
    )
    c = world_from_cv[:3, 3]
    horizontal = np.maximum(np.linalg.norm(rays[:, :2], axis=1), 1e-9)
    s_wall = wall_m / horizontal
    down = rays[:, 2] < -1e-9
    s_floor = np.where(down, -c[2] / np.where(down, rays[:, 2], -1.0), np.inf)
    on_floor = down & (s_floor * horizontal <= wall_m)
    s = np.where(on_floor, s_floor, s_wall)
    return c + s[:, None] * rays, on_floor


def _extent(cameras, ref: int, wall_m: float, width: int, height: int, frames: list[int], grow: float = 0.5):
    """The reference image's region (u0, v0, u1, v1) [px] that covers what ``frames`` see of the
    backdrop, at most ``grow`` of the image beyond each side."""
    K0, pose0 = cameras.K[ref], cameras.world_from_cv[ref]
    xs, ys = (0.0, (width - 1) / 2, width - 1.0), (0.0, (height - 1) / 2, height - 1.0)
    corners = np.array([[x, y] for x in xs for y in ys if (x, y) != xs[1:2] + ys[1:2]])
    lo, hi = np.array([0.0, 0.0]), np.array([width - 1.0, height - 1.0])
    for t in frames:
        pts, _ = backdrop_points(corners[:, 0], corners[:, 1], cameras.K[t], cameras.world_from_cv[t], wall_m)
        cam = se3.transform_points(se3.invert(pose0), pts)
        front = cam[:, 2] > 1e-6
        if not front.any():
            continue
        pu, pv = project(cam[front], K0)
        lo = np.minimum(lo, [pu.min(), pv.min()])
        hi = np.maximum(hi, [pu.max(), pv.max()])
    margin = np.array([grow * width, grow * height])
    lo = np.maximum(lo, -margin)
    hi = np.minimum(hi, np.array([width - 1.0, height - 1.0]) + margin)
    return float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1])


def _grid(extent, step: float):
    u0, v0, u1, v1 = extent
    us = np.linspace(u0, u1, max(2, int(np.ceil((u1 - u0) / step)) + 1))
    vs = np.linspace(v0, v1, max(2, int(np.ceil((v1 - v0) / step)) + 1))
    uu, vv = np.meshgrid(us, vs)
    rows, cols = uu.shape
    idx = np.arange(rows * cols).reshape(rows, cols)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    faces = np.concatenate([np.column_stack([a, c, b]), np.column_stack([b, c, d])])
    return uu.ravel(), vv.ravel(), faces


def farthest_foot(layer, t: int, K: np.ndarray, world_from_cv: np.ndarray) -> float:
    """The largest horizontal distance [m] from the camera to where an object masked in frame t
    meets the plane z = 0: the median over its mask's columns of their lowest pixel cast onto it
    (the outermost columns may hold only the top of an edge leaning out; 0 when none is below the
    horizon)."""
    far = 0.0
    for name in layer.names:
        m = layer.mask(name, t)
        if m is None or not m.any():
            continue
        cols = np.flatnonzero(m.any(axis=0))
        rows = m.shape[0] - 1 - np.argmax(m[::-1, cols], axis=0)
        rays = np.column_stack([(cols - K[0, 2]) / K[0, 0], (rows - K[1, 2]) / K[1, 1], np.ones(len(cols))])
        rays = rays @ world_from_cv[:3, :3].T
        down = rays[:, 2] < -1e-9
        if down.any():
            s = -world_from_cv[2, 3] / rays[down, 2]
            far = max(far, float(np.median(s * np.linalg.norm(rays[down, :2], axis=1))))
    return far


def _moving_masks(layer, t: int, shape, kernel) -> np.ndarray:
    """Everything masked in frame t (every object and the interactor), grown by ``kernel``."""
    out = np.zeros(shape, np.uint8)
    for name in layer.names + ([INTERACTOR] if layer.has(INTERACTOR) else []):
        m = layer.mask(name, t)
        if m is not None:
            out |= m.astype(np.uint8)
    return cv2.dilate(out, kernel).astype(bool)


def bake_backdrop(ctx: StageContext, cameras, layer, ref: int, extent, size: tuple[int, int], wall_m: float, cfg):
    """The texture (H, W, 3) sRGB8 of the extended reference image plane and how many texels no
    frame saw bare (inpainted); ``layer``: the masks (objects and interactor taken out)."""
    case, n = ctx.case, ctx.time_info.n_frames
    tw, th = size
    u0, v0, u1, v1 = extent
    xs = u0 - 0.5 + (np.arange(tw) + 0.5) * (u1 - u0 + 1.0) / tw
    ys = v0 - 0.5 + (np.arange(th) + 0.5) * (v1 - v0 + 1.0) / th
    uu, vv = np.meshgrid(xs, ys)
    pts, _ = backdrop_points(uu.ravel(), vv.ravel(), cameras.K[ref], cameras.world_from_cv[ref], wall_m)
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * cfg.mask_margin_px + 1,) * 2)
    frames = sorted(set(np.linspace(0, n - 1, min(n, cfg.texture_frames)).round().astype(int).tolist()))
    samples = np.zeros((len(frames), th * tw, 3), np.uint8)
    seen = np.zeros((len(frames), th * tw), bool)
    for i, t in enumerate(progress(frames, "scene: backdrop texture", total=len(frames))):
        cam = se3.transform_points(se3.invert(cameras.world_from_cv[t]), pts)
        front = cam[:, 2] > 1e-6
        fu, fv = project(np.where(front[:, None], cam, 1.0), cameras.K[t])
        inside = front & (fu >= 0) & (fu <= case.width - 1) & (fv >= 0) & (fv <= case.height - 1)
        rgb = case.rgb(t)
        bare = ~_moving_masks(layer, t, (case.height, case.width), kernel)
        mu, mv = fu.astype(np.float32).reshape(th, tw), fv.astype(np.float32).reshape(th, tw)
        samples[i] = cv2.remap(rgb, mu, mv, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE).reshape(-1, 3)
        ok = cv2.remap(bare.astype(np.uint8), mu, mv, cv2.INTER_NEAREST, borderValue=0).reshape(-1).astype(bool)
        seen[i] = inside & ok
    median, count = median_over_frames(samples, seen)
    holes = count == 0  # texels no frame saw bare: inpainted below
    tex = median.clip(0, 255).astype(np.uint8).reshape(th, tw, 3)
    if holes.any():
        tex = cv2.inpaint(tex, holes.reshape(th, tw).astype(np.uint8), 5, cv2.INPAINT_TELEA)
    return tex, float(holes.mean()), len(frames)


def slab(polygon_xy: np.ndarray, thickness_m: float) -> tuple[np.ndarray, np.ndarray]:
    """A convex polygon (counter-clockwise, (P, 2)) on z = 0 as a prism down to -thickness: a
    closed, outward-wound mesh."""
    p = len(polygon_xy)
    top = np.column_stack([polygon_xy, np.zeros(p)])
    bottom = np.column_stack([polygon_xy, np.full(p, -thickness_m)])
    vertices = np.concatenate(
        [top, bottom, [[*polygon_xy.mean(axis=0), 0.0], [*polygon_xy.mean(axis=0), -thickness_m]]]
    )
    i = np.arange(p)
    j = (i + 1) % p
    ct, cb = 2 * p, 2 * p + 1
    faces = np.concatenate(
        [
            np.column_stack([np.full(p, ct), i, j]),  # top, counter-clockwise seen from above
            np.column_stack([np.full(p, cb), p + j, p + i]),
            np.column_stack([i, p + i, p + j]),
            np.column_stack([i, p + j, j]),
        ]
    )
    return vertices, faces


@dataclass
class PlaneScene:
    """The support plane and backdrop over the reference image: a grid of world ``points`` (V, 3)
    with ``uv`` (V, 2) into ``texture`` (sRGB8), ``faces`` (F, 3), which points lie on the support,
    and what it was made from."""

    points: np.ndarray
    faces: np.ndarray
    uv: np.ndarray
    texture: np.ndarray
    on_support: np.ndarray
    """Which points lie on the support plane (V,) bool."""
    wall_m: float
    foot_m: float
    extent: tuple[float, float, float, float]
    inpainted: float
    texture_frames: int

    @property
    def support_face(self) -> np.ndarray:
        """Faces whose three points lie on the support (F,) bool."""
        return self.on_support[self.faces].all(axis=1)

    def parts(self, tex_path: Path) -> list[ScenePart]:
        """The visual parts: "Support" (on the plane) and "Backdrop" (beyond it), textured by the
        texture written at ``tex_path``."""
        parts = []
        for name, keep in (("Support", self.support_face), ("Backdrop", ~self.support_face)):
            if not keep.any():
                continue
            used_v = np.unique(self.faces[keep])
            remap = np.full(len(self.points), -1)
            remap[used_v] = np.arange(len(used_v))
            mesh = MeshData(
                vertices=self.points[used_v], faces=remap[self.faces[keep]], uv=self.uv[used_v], texture=tex_path
            )
            parts.append(ScenePart(name, mesh))
        return parts

    def support_xy(self) -> np.ndarray:
        """The support's grid points on the plane (M, 2) [m]."""
        return self.points[self.on_support][:, :2]

    def record(self) -> dict:
        return {
            "wall_distance_m": round(self.wall_m, 4),
            "farthest_object_foot_m": round(self.foot_m, 4),
            "extent_px": [round(v, 1) for v in self.extent],
            "grid_vertices": int(len(self.points)),
            "support_triangles": int(self.support_face.sum()),
            "backdrop_triangles": int((~self.support_face).sum()),
            "texture_px": [int(self.texture.shape[1]), int(self.texture.shape[0])],
            "texture_frames": self.texture_frames,
            "texture_inpainted": round(self.inpainted, 4),
        }


def plane_scene(ctx: StageContext, cameras, layer, cfg) -> PlaneScene:
    """The support plane (z = 0) and the backdrop as the reference camera (frame 0) sees them,
    extended to what the other frames see, textured from the video (the module's text)."""
    case, n = ctx.case, ctx.time_info.n_frames
    ref = 0
    pose0 = cameras.world_from_cv[ref]
    reach = float(np.linalg.norm(pose0[:2, 3]))
    foot = farthest_foot(layer, ref, cameras.K[ref], pose0)
    wall_m = float(np.clip(max(cfg.backdrop_reach * max(reach, 0.1), cfg.object_reach * foot), 0.3, 5.0))
    sample = sorted(set(np.linspace(0, n - 1, min(n, 24)).round().astype(int).tolist()))
    extent = _extent(cameras, ref, wall_m, case.width, case.height, sample)
    uu, vv, faces = _grid(extent, cfg.grid_px)
    points, on_floor = backdrop_points(uu, vv, cameras.K[ref], pose0, wall_m)
    # the texture: the extended reference image plane, at most texture_size on its long side
    u0, v0, u1, v1 = extent
    span_u, span_v = u1 - u0 + 1.0, v1 - v0 + 1.0
    s = min(1.0, cfg.texture_size / max(span_u, span_v))
    size = (max(2, int(round(span_u * s))), max(2, int(round(span_v * s))))
    tex, holes, used = bake_backdrop(ctx, cameras, layer, ref, extent, size, wall_m, cfg)
    uv = np.column_stack([(uu - u0 + 0.5) / span_u, 1.0 - (vv - v0 + 0.5) / span_v])
    return PlaneScene(points, faces, uv, tex, on_floor, wall_m, foot, extent, holes, used)


def author_plane(ctx: StageContext) -> None:
    """Write the scene layer of the plane backend (the module's text)."""
    cfg = ctx.config.plane
    case, n = ctx.case, ctx.time_info.n_frames
    cameras = read_cameras(ctx.stage, n)
    layer = read_masks(ctx.stage, n, (case.height, case.width))
    scene = plane_scene(ctx, cameras, layer, cfg)
    # the collider: the seen support's convex hull as a slab
    floor_xy = scene.support_xy()
    if len(floor_xy) < 3:  # the view sees no support (gravity off?): a square under the world origin
        ctx.warn("the reference camera sees no support plane below its horizon: a 1 m square slab under the origin")
        floor_xy = np.array([[-0.5, -0.5], [0.5, -0.5], [0.5, 0.5], [-0.5, 0.5]])
    hull = cv2.convexHull(floor_xy.astype(np.float32)).reshape(-1, 2).astype(float)
    if np.cross(hull[1] - hull[0], hull[2] - hull[0]) < 0:
        hull = hull[::-1]
    cv, cf = slab(hull, cfg.thickness_m)
    check_collider(cv, cf, "scene collision slab")
    if self_intersects(cv, cf):
        raise MeshError("the scene slab intersects itself", hint="report this: a convex prism cannot")
    with tempfile.TemporaryDirectory() as tmp:
        tex_path = Path(tmp) / "Backdrop.png"
        cv2.imwrite(str(tex_path), cv2.cvtColor(scene.texture, cv2.COLOR_RGB2BGR))
        support = {spec.name: 0.0 for spec in case.config.objects}
        author_scene(ctx, scene.parts(tex_path), MeshData(vertices=cv, faces=cf), Lighting.unlit(), support=support)
    ctx.record(
        **scene.record(),
        collider_area_m2=round(
            float(0.5 * abs(np.cross(hull - hull.mean(0), np.roll(hull, -1, 0) - hull.mean(0)).sum())), 4
        ),
    )
