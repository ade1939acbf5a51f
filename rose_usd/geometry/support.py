"""The support surface as the video sees it: its height over the world's z = 0 plane, per place.

The capture stage's z = 0 is one plane fitted to the whole scene. A real table is not one plane
to a depth sensor: a notebook or a cloth lies on it, and seen at a grazing angle its depth bends
by millimetres to centimetres from near to far (on a hand-held RealSense clip the fitted plane
was 5 deg off the desk right around one object, and the desk there read -15 to +9 mm). Whether a
pixel "stands on the support" is decided against the surface under it, not against z = 0.

The surface is a height field over world (x, y) in square cells: in each cell, a low percentile
of the heights of up-facing points (normal within ``max_tilt_deg`` of +Z) that lie within
``band_m`` of z = 0, over reference frames spread through the video. An object that rests in a
cell for part of the video is seen past in the others, and the low percentile takes the
surface under it. Cells never seen (under an object that never moves, outside the views) take
the value of the seen cells around them. A median filter over ``smooth_cells`` cells removes
what is left of small things lying flat on the support (it keeps a cloth or a notebook).
"""

from __future__ import annotations

from collections.abc import Callable

import cv2
import numpy as np

from rose_usd.core import se3
from rose_usd.core.pinhole import backproject


class SupportSurface:
    def __init__(
        self,
        depth_of: Callable[[int], np.ndarray],
        world_from_cv: np.ndarray,
        K: np.ndarray,
        frames: list[int],
        *,
        cell_m: float = 0.02,
        band_m: float = 0.03,
        max_tilt_deg: float = 25.0,
        percentile: float = 25.0,
        min_points: int = 4,
        smooth_cells: int = 5,
        stride: int = 4,
        depth_max_m: float = 3.0,
    ):
        self.cell_m = cell_m
        K = np.asarray(K, dtype=float).reshape(-1, 3, 3)
        points = []
        for t in frames:
            points.append(
                _up_facing(
                    depth_of(t), K[t] if len(K) > 1 else K[0], world_from_cv[t], stride, max_tilt_deg, depth_max_m
                )
            )
        pts = np.concatenate(points) if points else np.zeros((0, 3))
        pts = pts[np.abs(pts[:, 2]) < band_m]
        self.seen_points = len(pts)
        if len(pts) < 50:
            self.origin = np.zeros(2)
            self.grid = np.zeros((1, 1), np.float32)
            self.seen = np.zeros((1, 1), bool)
            return
        lo = np.floor(pts[:, :2].min(axis=0) / cell_m) * cell_m - 2 * cell_m
        hi = pts[:, :2].max(axis=0) + 2 * cell_m
        shape = tuple(int(v) for v in np.ceil((hi - lo) / cell_m)[::-1])  # (rows = y, cols = x)
        ij = np.floor((pts[:, :2] - lo) / cell_m).astype(np.int64)
        cell = ij[:, 1] * shape[1] + ij[:, 0]
        order = np.lexsort((pts[:, 2], cell))
        cell, z = cell[order], pts[order, 2]
        starts = np.flatnonzero(np.r_[True, cell[1:] != cell[:-1]])
        counts = np.diff(np.r_[starts, len(cell)])
        keep = counts >= min_points
        pick = starts + np.floor(percentile / 100.0 * (counts - 1)).astype(np.int64)
        grid = np.full(shape[0] * shape[1], np.nan, np.float32)
        grid[cell[starts[keep]]] = z[pick[keep]]
        grid = grid.reshape(shape)
        self.seen = np.isfinite(grid)
        self.grid = _smooth(_fill(grid), smooth_cells)
        self.origin = lo

    def relief_mm(self) -> list[float]:
        """The seen cells' heights over z = 0: 5th, 50th and 95th percentiles [mm]."""
        if not self.seen.any():
            return [0.0, 0.0, 0.0]
        return [round(float(v) * 1000, 1) for v in np.percentile(self.grid[self.seen], [5, 50, 95])]

    def height_of(self, points: np.ndarray) -> np.ndarray:
        """The support's height [m] under world points (..., 3), bilinear between cell centres;
        outside the grid, the nearest cell's."""
        p = np.asarray(points)
        rows, cols = self.grid.shape
        # x and y each on their own (no (..., 2) temporaries); cells by flat index into the grid
        x = np.clip((np.nan_to_num(p[..., 0]) - self.origin[0]) / self.cell_m - 0.5, 0, cols - 1)
        y = np.clip((np.nan_to_num(p[..., 1]) - self.origin[1]) / self.cell_m - 0.5, 0, rows - 1)
        x0 = np.minimum(np.floor(x).astype(np.int64), max(cols - 2, 0))
        y0 = np.minimum(np.floor(y).astype(np.int64), max(rows - 2, 0))
        dx, dy = (x0 + 1 < cols).astype(np.int64), (y0 + 1 < rows).astype(np.int64) * cols
        fx, fy = (x - x0).astype(np.float32), (y - y0).astype(np.float32)
        g, at = self.grid.ravel(), y0 * cols + x0
        top = g.take(at) * (1 - fx) + g.take(at + dx) * fx
        at += dy
        bottom = g.take(at) * (1 - fx) + g.take(at + dx) * fx
        return top * (1 - fy) + bottom * fy

    def height_above(self, points: np.ndarray) -> np.ndarray:
        """Height [m] of world points (..., 3) over the support under them (NaN stays NaN)."""
        p = np.asarray(points)
        return p[..., 2] - self.height_of(p)


def _up_facing(
    depth: np.ndarray, K: np.ndarray, world_from_cv: np.ndarray, stride: int, max_tilt_deg: float, depth_max_m: float
) -> np.ndarray:
    """World points of ``depth`` (every ``stride``-th pixel) whose surface normal, from the
    neighbouring samples, is within ``max_tilt_deg`` of +Z."""
    d = depth[::stride, ::stride].astype(np.float64)
    h, w = d.shape
    v, u = np.mgrid[0:h, 0:w]
    valid = (d > 0) & (d < depth_max_m)
    cam = backproject(u * stride, v * stride, np.where(valid, d, np.nan), K)
    world = se3.transform_points(world_from_cv, cam.reshape(-1, 3)).reshape(h, w, 3)
    du = world[1:-1, 2:] - world[1:-1, :-2]
    dv = world[2:, 1:-1] - world[:-2, 1:-1]
    normal = np.cross(du, dv)
    length = np.linalg.norm(normal, axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        cos_up = np.abs(normal[..., 2]) / length
    ok = np.nan_to_num(cos_up) > np.cos(np.radians(max_tilt_deg))
    inner = world[1:-1, 1:-1]
    return inner[ok & np.isfinite(inner).all(axis=-1)]


def _fill(grid: np.ndarray) -> np.ndarray:
    """Unseen cells (NaN) take the mean of the seen cells around them, in growing windows."""
    out = grid.copy()
    missing = ~np.isfinite(out)
    if not missing.any():
        return out
    if missing.all():
        return np.zeros_like(out)
    size = 3
    while missing.any() and size < 4 * max(out.shape):
        seen = (~missing).astype(np.float32)
        total = cv2.boxFilter(np.where(missing, 0, out).astype(np.float32), -1, (size, size), normalize=False)
        count = cv2.boxFilter(seen, -1, (size, size), normalize=False)
        fill = missing & (count > 0)
        out[fill] = total[fill] / count[fill]
        missing = ~np.isfinite(out)
        size = 2 * size + 1
    out[missing] = float(np.nanmedian(grid))
    return out


def _smooth(grid: np.ndarray, cells: int) -> np.ndarray:
    if cells <= 1 or min(grid.shape) < 2:
        return grid.astype(np.float32)
    k = cells if cells % 2 else cells + 1
    return cv2.medianBlur(grid.astype(np.float32), min(k, 5))
