"""The static world's depth as each frame would see it, from the other frames.

Moving things (the hand, the object while it moves) stand in front of the static scene. For a
frame t, the depth of reference frames spread over the whole video is warped into t (z-buffered
splats at reduced resolution); per pixel, a far percentile over the references is the static
surface: a pixel that the hand or the object covers in some references is seen bare in the
others. A pixel is foreground when it is nearer than that by more than ``tau``; it is compared
against the nearest background within a small window, so the edges of static things (the table's
rim over the floor) are not mistaken for foreground after upsampling.
"""

from __future__ import annotations

import threading
from collections.abc import Callable

import cv2
import numpy as np

from rose_usd.core import se3
from rose_usd.core.pinhole import backproject, project


class StaticBackground:
    def __init__(
        self,
        depth_of: Callable[[int], np.ndarray],
        world_from_cv: np.ndarray,
        K: np.ndarray,
        width: int,
        height: int,
        *,
        n_refs: int = 16,
        stride: int = 4,
        percentile: float = 90.0,
        depth_max_m: float = 4.0,
    ):
        self.poses = np.asarray(world_from_cv, dtype=float)
        self.K = np.asarray(K, dtype=float).reshape(-1, 3, 3)
        self.width, self.height, self.stride, self.percentile = width, height, stride, percentile
        self.h, self.w = height // stride, width // stride
        n = len(self.poses)
        self.refs = sorted(set(np.linspace(0, n - 1, min(n, n_refs)).round().astype(int).tolist()))
        self._last: dict[int, np.ndarray] = {}  # the latest frames' static depth (asked for 2-3 times each)
        self._lock = threading.Lock()
        self._ref_points = []
        for r in self.refs:
            d = depth_of(r)[: self.h * stride : stride, : self.w * stride : stride]
            v, u = np.nonzero((d > 0) & (d < depth_max_m))
            z = d[v, u].astype(np.float64)
            self._ref_points.append(
                se3.transform_points(self.poses[r], backproject(u * stride, v * stride, z, self._K(r)))
            )

    def _K(self, t: int) -> np.ndarray:
        return self.K[t] if len(self.K) > 1 else self.K[0]

    def depth(self, t: int) -> np.ndarray:
        """Static depth seen from frame t at full resolution (H, W) [m], 0 where no reference sees
        it (read-only: the latest few frames' are kept and handed out again)."""
        with self._lock:
            kept = self._last.get(t)
        if kept is not None:
            return kept
        depth = self._depth(t)
        depth.setflags(write=False)
        with self._lock:  # a prefetching thread may be keeping the next frame's
            while len(self._last) >= 3:
                del self._last[next(iter(self._last))]
            self._last[t] = depth
        return depth

    def _depth(self, t: int) -> np.ndarray:
        pose, k = self.poses[t], self._K(t)
        rot, center = pose[:3, :3], pose[:3, 3]
        stack = np.full((len(self.refs), self.h * self.w), np.inf, dtype=np.float32)
        s = self.stride
        for i, (r, pts) in enumerate(zip(self.refs, self._ref_points)):
            if r == t:
                continue
            cam = (pts - center) @ rot
            ok = cam[:, 2] > 0.05
            cam[~ok, 2] = 1.0  # not in front: projected somewhere finite, then left out (no copy of the rest)
            fu, fv = project(cam, k)
            u = (fu / s).round().astype(np.int64)
            v = (fv / s).round().astype(np.int64)
            inside = ok & (u >= 0) & (u < self.w) & (v >= 0) & (v < self.h)
            # a z-buffer: the nearest splat of each pixel (13x faster than writing them far first)
            np.minimum.at(stack[i], v[inside] * self.w + u[inside], cam[inside, 2].astype(np.float32))
        # the far percentile over the references that see each pixel (NaN sorts last)
        stack[np.isinf(stack)] = np.nan
        stack.sort(axis=0)
        count = np.sum(~np.isnan(stack), axis=0)
        pick = np.clip(np.floor(self.percentile / 100.0 * (count - 1) + 0.5).astype(np.int64), 0, None)
        bg = np.take_along_axis(stack, pick[None], axis=0)[0]
        bg[count == 0] = np.nan
        bg = np.nan_to_num(bg, nan=0.0).reshape(self.h, self.w).astype(np.float32)
        return cv2.resize(bg, (self.width, self.height), interpolation=cv2.INTER_NEAREST)

    def foreground(
        self, t: int, depth: np.ndarray, *, tau_m: float = 0.015, window_px: int = 9
    ) -> tuple[np.ndarray, np.ndarray]:
        """(foreground, static): pixels nearer than the static surface by more than ``tau_m``
        (plus 1 % of the depth), and pixels that agree with it. Pixels without a reference are neither."""
        bg = self.depth(t)
        far = np.where(bg > 0, bg, np.float32(1e6))
        kernel = np.ones((window_px, window_px), np.uint8)
        nearest_bg = cv2.erode(far, kernel)  # the nearest static surface in the window
        farthest_bg = cv2.dilate(np.where(bg > 0, bg, 0).astype(np.float32), kernel)
        valid = depth > 0
        known = nearest_bg < 1e5
        # depth that is not a sensor's (MegaSaM's) drifts in scale from frame to frame and is
        # noisier: most pixels are static, so their ratio to the static surface gives the frame's
        # scale (divided out) and its relative noise (which widens the tolerance)
        both = valid & (bg > 0)
        rel = 0.01
        if np.count_nonzero(both) > 1000:
            ratio = depth[both][::7] / bg[both][::7]
            scale = float(np.median(ratio))
            if abs(scale - 1.0) > 0.002:
                depth = depth / np.float32(scale)
            rel = max(rel, 3.0 * 1.4826 * float(np.median(np.abs(ratio / scale - 1.0))))
        tol = tau_m + rel * depth
        fg = valid & known & (depth < nearest_bg - tol)
        static = valid & known & (depth > nearest_bg - tol) & (depth < farthest_bg + tol)
        return fg, static
