"""The OpenCV pinhole camera in one place: back-projection (pixel (u, v) at depth z -> camera
point) and projection (camera or world point -> pixel)."""

from __future__ import annotations

import cv2
import numpy as np

from rose_usd.core import se3
from rose_usd.core.raster import fill_mesh


def backproject(u, v, z, K: np.ndarray) -> np.ndarray:
    """Camera points (..., 3) in OpenCV axes of pixels ``u``, ``v`` (pixel centers at integers)
    with depth ``z`` [m] along the optical axis; u, v and z broadcast together."""
    x = (u - K[0, 2]) / K[0, 0] * z
    y = (v - K[1, 2]) / K[1, 1] * z
    return np.stack(np.broadcast_arrays(x, y, z), axis=-1)


def masked_world_points(
    depth: np.ndarray, mask: np.ndarray, K: np.ndarray, world_from_cv: np.ndarray, *, erode_px: int = 0
) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray]]:
    """World points (N, 3) of the pixels of ``mask`` (eroded by ``erode_px``) with depth, and
    those pixels' (rows, columns)."""
    if erode_px:
        mask = cv2.erode(mask.astype(np.uint8), np.ones((2 * erode_px + 1, 2 * erode_px + 1), np.uint8)).astype(bool)
    v, u = np.nonzero(mask & (depth > 0))
    return se3.transform_points(world_from_cv, backproject(u, v, depth[v, u], K)), (v, u)


def resized_K(K: np.ndarray, s: float, origin: tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
    """Intrinsics (3, 3) of the image cut at pixel ``origin`` (x0, y0) and resized by ``s``, pixel
    centers kept (a pixel's center u maps to (u - x0 + 0.5) s - 0.5)."""
    k = np.asarray(K, dtype=float)
    x0, y0 = origin
    return np.array(
        [
            [k[0, 0] * s, 0.0, (k[0, 2] - x0 + 0.5) * s - 0.5],
            [0.0, k[1, 1] * s, (k[1, 2] - y0 + 0.5) * s - 0.5],
            [0.0, 0.0, 1.0],
        ]
    )


def project(points_cam: np.ndarray, K: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixel coordinates (u, v), as floats with pixel centers at integers, of camera points
    (..., 3) in OpenCV axes in front of the camera: the inverse of ``backproject``."""
    z = points_cam[..., 2]
    return K[0, 0] * points_cam[..., 0] / z + K[0, 2], K[1, 1] * points_cam[..., 1] / z + K[1, 2]


def pixels_of(
    points_world: np.ndarray, world_from_cv: np.ndarray, K: np.ndarray, width: int, height: int, *, min_z: float = 0.0
):
    """Where world points (N, 3) fall in a camera: (u, v, z), the nearest pixel (integers) and the
    depth along the optical axis; u = v = -1 for points not farther than ``min_z`` or outside the
    ``width`` x ``height`` image."""
    cam = se3.transform_points(se3.invert(world_from_cv), points_world)
    z = cam[:, 2]
    ok = z > min_z
    u = np.full(len(z), -1)
    v = np.full(len(z), -1)
    fu, fv = project(cam[ok], K)
    u[ok], v[ok] = np.round(fu).astype(int), np.round(fv).astype(int)
    outside = (u < 0) | (u >= width) | (v < 0) | (v >= height)
    u[outside], v[outside] = -1, -1
    return u, v, z


def nearest_depth(
    points_world: np.ndarray, world_from_cv: np.ndarray, K: np.ndarray, width: int, height: int, *, window_px: int
) -> np.ndarray:
    """The depth (H, W) of the nearest of ``points_world`` that falls within a ``window_px``-wide
    square around each pixel (a point cloud's visible surface, its gaps closed); inf where none."""
    u, v, z = pixels_of(points_world, world_from_cv, K, width, height, min_z=0.05)
    near = np.full((height, width), np.inf, np.float32)
    seen = u >= 0
    np.minimum.at(near, (v[seen], u[seen]), z[seen].astype(np.float32))
    return cv2.erode(near, np.ones((window_px, window_px), np.uint8), borderType=cv2.BORDER_REPLICATE)


def sample_at(image: np.ndarray, u: np.ndarray, v: np.ndarray, fill=0):
    """``image`` at the pixels (u, v) from ``pixels_of``, ``fill`` where u = -1."""
    inside = u >= 0
    out = np.full(len(u), fill, dtype=image.dtype)
    out[inside] = image[v[inside], u[inside]]
    return out


def view_counts(
    points_world: np.ndarray, views, *, tol_m: float, rel: float = 0.0, window: int = 1
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Free-space evidence for world points (N, 3) from ``views``, an iterable of (depth, K,
    world_from_cv). Returns per point how many views (through, near, observed): observed, the views
    whose depth at its pixel is valid; through, those whose depth lies beyond it by more than
    ``tol_m`` + ``rel`` x its depth (the view saw past it); near, those within that of it. With
    ``window`` > 1 a view's depth at a pixel is the nearest valid one of the ``window`` x ``window``
    pixels around it, so that a point at a silhouette counts as seen through only when all its
    neighbours are beyond it."""
    through = np.zeros(len(points_world), np.int32)
    near = np.zeros(len(points_world), np.int32)
    observed = np.zeros(len(points_world), np.int32)
    for depth, K, world_from_cv in views:
        d_img = np.where(depth > 0, depth, np.inf).astype(np.float32)
        if window > 1:
            d_img = cv2.erode(d_img, np.ones((window, window), np.uint8))
        u, v, z = pixels_of(points_world, world_from_cv, K, depth.shape[1], depth.shape[0], min_z=0.05)
        d = sample_at(d_img, u, v, fill=np.inf).astype(float)
        ok = np.isfinite(d)
        tol = tol_m + rel * z
        observed += ok
        through += ok & (d > z + tol)
        near += ok & (np.abs(d - z) <= tol)
    return through, near, observed


def projected_box(
    vertices_world: np.ndarray,
    world_from_cv: np.ndarray,
    K: np.ndarray,
    width: int,
    height: int,
    *,
    min_z: float = 1e-3,
) -> tuple[float, float, float, float] | None:
    """The bounding box (x0, y0, x1, y1) [px, pixel centers at integers] of the vertices in front
    of ``min_z`` as a camera sees them, clipped to the ``width`` x ``height`` image; None when no
    vertex is in front or the box misses the image."""
    cam = se3.transform_points(se3.invert(world_from_cv), vertices_world)
    cam = cam[cam[:, 2] > min_z]
    if not len(cam):
        return None
    u, v = project(cam, K)
    box = (
        max(0.0, float(u.min())),
        max(0.0, float(v.min())),
        min(float(width), float(u.max())),
        min(float(height), float(v.max())),
    )
    return box if box[2] > box[0] and box[3] > box[1] else None


def silhouette(
    vertices_world: np.ndarray,
    faces: np.ndarray,
    world_from_cv: np.ndarray,
    K: np.ndarray,
    width: int,
    height: int,
    *,
    min_z: float = 1e-3,
    closed: bool = False,
    window: tuple[int, int, int, int] | None = None,
) -> np.ndarray:
    """The mesh's silhouette in a camera: a (height, width) bool image of the pixels whose
    centers some triangle covers. Triangles with a vertex not in front of ``min_z`` are left out
    (an object is never that close to the camera). A ``closed`` mesh (watertight, faces wound
    outward) is drawn by its camera-facing triangles only: the first surface a pixel's ray meets
    faces the camera, so the silhouette is the same at half the triangles. With ``window`` (x0,
    y0, x1, y1), only those pixels of it: a (y1 - y0, x1 - x0) image, the same pixels as the
    whole image's there."""
    cam = se3.transform_points(se3.invert(world_from_cv), vertices_world)
    x0, y0, x1, y1 = window if window is not None else (0, 0, width, height)
    return fill_mesh(cam, faces, K, x1 - x0, y1 - y0, min_z=min_z, closed=closed, origin=(x0, y0))


def world_points(depth: np.ndarray, K: np.ndarray, world_from_cv: np.ndarray) -> np.ndarray:
    """World point of every pixel (H, W, 3); NaN where depth is 0."""
    h, w = depth.shape
    u = np.arange(w, dtype=np.float32)[None, :]
    v = np.arange(h, dtype=np.float32)[:, None]
    z = np.where(depth > 0, depth, np.nan).astype(np.float32)
    cam = backproject(u, v, z, K)
    return cam @ world_from_cv[:3, :3].T.astype(np.float32) + world_from_cv[:3, 3].astype(np.float32)
