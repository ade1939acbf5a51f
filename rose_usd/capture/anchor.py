"""Where the world origin goes: the support surface under the object at frame 0.

The object is located by its prompt in rose.toml (a box or a point on some frame, back-projected
with that frame's depth); without a prompt, the point of the support plane at the center of the
first frame is used, and the layer says so.
"""

from __future__ import annotations

import numpy as np

from rose_usd.capture.gravity import Plane
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
