"""Where the world origin goes: the support surface under the object at frame 0.

The object is located by its prompt in rose.toml (a box or a point on some frame, back-projected
with that frame's depth); without a prompt, the point of the support plane at the center of the
first frame is used, and the layer says so.
"""

from __future__ import annotations

import numpy as np

from rose_usd.capture.gravity import Plane, ransac_plane
from rose_usd.case.config import Prompt
from rose_usd.core import se3
from rose_usd.core.pinhole import backproject


def prompt_pixel(prompt: Prompt) -> tuple[float, float]:
    if prompt.box is not None:
        x0, y0, x1, y1 = prompt.box
        return 0.5 * (x0 + x1), 0.5 * (y0 + y1)
    return prompt.point


def anchor_from_prompt(
    prompt: Prompt, depth_m: np.ndarray, K: np.ndarray, world_from_camera: np.ndarray
) -> np.ndarray | None:
    """A 3D point on the prompted object (tracking frame), or None if its depth is invalid."""
    u, v = prompt_pixel(prompt)
    h, w = depth_m.shape
    if prompt.box is not None:
        x0, y0, x1, y1 = prompt.box
        cx, cy, hw, hh = 0.5 * (x0 + x1), 0.5 * (y0 + y1), 0.25 * (x1 - x0), 0.25 * (y1 - y0)
        ys = slice(max(int(cy - hh), 0), min(int(cy + hh) + 1, h))
        xs = slice(max(int(cx - hw), 0), min(int(cx + hw) + 1, w))
    else:
        ys = slice(max(int(v) - 3, 0), min(int(v) + 4, h))
        xs = slice(max(int(u) - 3, 0), min(int(u) + 4, w))
    patch = depth_m[ys, xs]
    valid = patch[patch > 0]
    if valid.size < 3:
        return None
    z = float(np.median(valid))
    point = backproject(u, v, z, K)
    return se3.transform_points(world_from_camera, point[None])[0]


SURFACE_M = 0.01
"""A point lies on a surface within this distance of it [m]."""
STAND_M = 0.005
"""A point stands on a surface this far above it, toward the camera [m] (the segment stage's
least height of an object over its support is 4 mm)."""


class NothingStands(ValueError):
    """A prompt box shows the surface around it and nothing standing on that surface."""


def object_anchor(
    prompt: Prompt, depth_m: np.ndarray, K: np.ndarray, world_from_camera: np.ndarray, *, seed: int = 0
) -> np.ndarray | None:
    """A 3D point on the prompted object (tracking frame), or None if its depth is invalid.

    The middle of its box (``anchor_from_prompt``), unless that lies on the surface that most of
    the ring of pixels around the box lies on (one RANSAC plane): the box is wider than a small or
    thin object (a ladle lying on the table), and the object is the median of the box's points that
    stand ``STAND_M`` or more above that surface. Where fewer than 2 % of them do, ``NothingStands``
    is raised: the box holds no object the depth sees (an empty patch of table; a knife lying flat
    at 0.7 m from a RealSense). An object's top face filling its box
    lies above the ring's surface, and a point prompt is not checked."""
    anchor = anchor_from_prompt(prompt, depth_m, K, world_from_camera)
    if anchor is None or prompt.box is None:
        return anchor
    box, ring = _box_and_ring(prompt.box, depth_m.shape)
    pts = [_points(depth_m, m, K, world_from_camera) for m in (box, ring)]
    if min(len(p) for p in pts) < 50:
        return anchor
    box_pts, ring_pts = pts
    normal, offset, count = ransac_plane(ring_pts, SURFACE_M, np.random.default_rng(seed), iterations=200)
    if count < 0.5 * len(ring_pts):
        return anchor
    if normal @ world_from_camera[:3, 3] < offset:  # toward the camera
        normal, offset = -normal, -offset
    heights = box_pts @ normal - offset
    if abs(normal @ anchor - offset) >= STAND_M:
        return anchor
    standing = box_pts[heights >= STAND_M]
    if len(standing) < max(10, 0.02 * len(box_pts)):
        raise NothingStands(
            f"{np.mean(np.abs(heights) < SURFACE_M):.0%} of its depth lies within 1 cm of the surface around it,"
            f" {len(standing)} of {len(box_pts)} points stand 5 mm above it"
        )
    return np.median(standing, axis=0)


def _box_and_ring(box, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """The box's pixels, and the ring around it as wide as the box's larger side."""
    h, w = shape
    x0, y0, x1, y1 = (int(round(c)) for c in box)
    pad = max(x1 - x0, y1 - y0, 10)
    inside = np.zeros(shape, bool)
    inside[max(y0, 0) : min(y1 + 1, h), max(x0, 0) : min(x1 + 1, w)] = True
    ring = np.zeros(shape, bool)
    ring[max(y0 - pad, 0) : min(y1 + pad + 1, h), max(x0 - pad, 0) : min(x1 + pad + 1, w)] = True
    return inside, ring & ~inside


def _points(depth_m: np.ndarray, mask: np.ndarray, K: np.ndarray, world_from_camera: np.ndarray, most: int = 4000):
    """Tracking-frame points of the pixels of ``mask`` with depth, at most ``most`` (evenly strided)."""
    ys, xs = np.nonzero(mask & (depth_m > 0))
    step = max(1, len(ys) // most)
    ys, xs = ys[::step], xs[::step]
    return se3.transform_points(world_from_camera, backproject(xs, ys, depth_m[ys, xs], K))


def anchor_from_view_center(
    plane: Plane, K: np.ndarray, width: int, height: int, world_from_camera: np.ndarray
) -> np.ndarray:
    """Where the first camera's central ray meets the support plane (tracking frame)."""
    ray = world_from_camera[:3, :3] @ np.array(
        [((width - 1) / 2 - K[0, 2]) / K[0, 0], ((height - 1) / 2 - K[1, 2]) / K[1, 1], 1.0]
    )
    origin = world_from_camera[:3, 3]
    denom = plane.normal @ ray
    if abs(denom) < 1e-6:
        return plane.project(origin)
    s = (plane.offset - plane.normal @ origin) / denom
    return origin + max(s, 0.0) * ray
