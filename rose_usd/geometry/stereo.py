"""Dense depth from a moving camera's frames alone: plane-sweep stereo with several source views.

For a reference frame, planes parallel to its image (``planes`` of them, even in inverse depth
between ``near_m`` and ``far_m``) are swept through the scene; at each, every source frame is
warped into the reference by the plane's homography and compared with it by zero-mean normalized
cross-correlation (ZNCC) over ``window_px`` windows (box filters, so the whole image at once). A
pixel's cost at a plane is the mean of its ``best_views`` best sources' (1 - ZNCC), which lets a
source that sees an occluder there (or has no view of it) drop out. The depth is the plane of
least cost, refined between its neighbours by a parabola in inverse depth; it is kept where the
best ZNCC is at least ``min_zncc`` and the image has texture (``min_texture``: the window's
standard deviation in 8-bit levels). Pixels marked as moving (the object, the hand) in the
reference are left out, and a source's moving pixels take no part in a cost.

``consistent`` then keeps a depth map's pixels that other frames' depth maps agree with (the point
projected into them lands on a depth within ``rel_tol`` of its own), as multi-view stereo's fusion
does: a wrong match seldom agrees with a second pair's.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from rose_usd.core import se3
from rose_usd.core.pinhole import backproject


@dataclass(frozen=True)
class View:
    """A frame as stereo sees it: gray levels (H, W) float32 [0-255], intrinsics (3, 3) [px] at
    that size, pose world_from_cv (4, 4), and its moving pixels (H, W) bool (or None)."""

    gray: np.ndarray
    K: np.ndarray
    world_from_cv: np.ndarray
    moving: np.ndarray | None = None


@dataclass(frozen=True)
class SweepParams:
    planes: int = 128
    """Depth planes between near and far, even in inverse depth."""
    window_px: int = 7
    """ZNCC window side [px]."""
    best_views: int = 2
    """A pixel's cost is the mean over this many of its best source views."""
    min_zncc: float = 0.5
    """A depth is kept where its best ZNCC (mean over the best views) is at least this."""
    min_texture: float = 2.0
    """... and where the reference's window has at least this standard deviation [8-bit levels]."""


def _box(image: np.ndarray, k: int) -> np.ndarray:
    return cv2.boxFilter(image, cv2.CV_32F, (k, k), borderType=cv2.BORDER_REFLECT)


def _homography(ref: View, src: View, depth_m: float) -> np.ndarray:
    """The homography mapping a reference pixel to the source pixel that sees the same point of
    the plane z = depth_m in the reference camera."""
    src_from_ref = se3.invert(src.world_from_cv) @ ref.world_from_cv
    R, t = src_from_ref[:3, :3], src_from_ref[:3, 3]
    n = np.array([0.0, 0.0, 1.0])
    return src.K @ (R + np.outer(t, n) / depth_m) @ np.linalg.inv(ref.K)


def _mean_of_smallest(values: np.ndarray, k: int) -> np.ndarray:
    """The mean over axis 0 of its ``k`` smallest values (values (S, H, W)): kept sorted pixel
    by pixel while the S layers stream in, a few whole-image passes where ``np.partition`` along
    a short first axis walks the array pixel by pixel."""
    if k >= len(values):
        return values.mean(axis=0)
    smallest = [np.full(values.shape[1:], np.inf, values.dtype) for _ in range(k)]
    for layer in values:
        carry = layer
        for i in range(k):  # insert: each slot keeps the lesser, passes the greater on
            smallest[i], carry = np.minimum(smallest[i], carry), np.maximum(smallest[i], carry)
    return np.mean(np.stack(smallest), axis=0)


def plane_depths(near_m: float, far_m: float, planes: int) -> np.ndarray:
    """``planes`` depths [m] from near to far, even in inverse depth."""
    return 1.0 / np.linspace(1.0 / near_m, 1.0 / far_m, planes)


def sweep(ref: View, sources: list[View], near_m: float, far_m: float, params: SweepParams = SweepParams()):
    """The reference frame's depth (H, W) float32 [m] (0 where not kept) and its best ZNCC (H, W)."""
    h, w = ref.gray.shape
    k = params.window_px
    ref_mean = _box(ref.gray, k)
    ref_var = np.maximum(_box(ref.gray * ref.gray, k) - ref_mean * ref_mean, 0.0)
    ref_std = np.sqrt(ref_var)
    depths = plane_depths(near_m, far_m, params.planes)
    best = min(params.best_views, len(sources))
    costs = np.empty((params.planes, h, w), np.float32)
    per_view = np.empty((len(sources), h, w), np.float32)
    stills = [np.ones((h, w), np.float32) if v.moving is None else (~v.moving).astype(np.float32) for v in sources]
    for p, z in enumerate(depths):
        for s, src in enumerate(sources):
            H = _homography(ref, src, float(z))
            flags = cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP
            warped = cv2.warpPerspective(src.gray, H, (w, h), flags=flags, borderMode=cv2.BORDER_REPLICATE)
            # the source's pixels that see the reference's, still ones only: outside the image the
            # constant border (0) leaves them out as well
            seen = cv2.warpPerspective(stills[s], H, (w, h), flags=cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP)
            m = _box(warped, k)
            var = np.maximum(_box(warped * warped, k) - m * m, 0.0)
            cov = _box(ref.gray * warped, k) - ref_mean * m
            zncc = cov / np.maximum(ref_std * np.sqrt(var), 1e-3)
            # a window that leaves the source image (or meets its moving pixels) does not count
            valid = _box(seen, k) > 0.999
            per_view[s] = np.where(valid, 1.0 - zncc, 4.0)
        costs[p] = _mean_of_smallest(per_view, best)
    idx = np.argmin(costs, axis=0)
    rows, cols = np.indices((h, w))
    c0 = costs[idx, rows, cols]
    # parabola through the neighbouring planes' costs, in inverse depth (even steps)
    inv = 1.0 / depths
    lo, hi = np.clip(idx - 1, 0, params.planes - 1), np.clip(idx + 1, 0, params.planes - 1)
    cl, ch = costs[lo, rows, cols], costs[hi, rows, cols]
    denom = cl - 2 * c0 + ch
    inner = (idx > 0) & (idx < params.planes - 1) & (denom > 1e-6)
    offset = np.where(inner, 0.5 * (cl - ch) / np.where(inner, denom, 1.0), 0.0)
    step = inv[1] - inv[0] if params.planes > 1 else 0.0
    inv_best = inv[idx] + np.clip(offset, -0.5, 0.5) * step
    depth = (1.0 / inv_best).astype(np.float32)
    zncc_best = 1.0 - c0
    keep = (zncc_best >= params.min_zncc) & (ref_std >= params.min_texture) & inner
    if ref.moving is not None:
        keep &= ~ref.moving
    return np.where(keep, depth, 0.0).astype(np.float32), zncc_best.astype(np.float32)


def consistent(
    depth: np.ndarray, view: View, others: list[tuple[np.ndarray, View]], *, rel_tol: float = 0.01, min_agree: int = 1
) -> np.ndarray:
    """``depth``'s pixels (bool, H x W) that at least ``min_agree`` of ``others`` (their depth maps
    and views) agree with: projected into one, the point lands on a pixel whose depth is within
    ``rel_tol`` of the point's own depth there."""
    h, w = depth.shape
    v, u = np.nonzero(depth > 0)
    z = depth[v, u].astype(np.float64)
    world = se3.transform_points(view.world_from_cv, backproject(u, v, z, view.K))
    agree = np.zeros(len(z), np.int32)
    for other_depth, other in others:
        cam = se3.transform_points(se3.invert(other.world_from_cv), world)
        front = cam[:, 2] > 1e-6
        pix = cam @ other.K.T
        x = np.rint(pix[:, 0] / np.where(front, pix[:, 2], 1.0)).astype(np.int64)
        y = np.rint(pix[:, 1] / np.where(front, pix[:, 2], 1.0)).astype(np.int64)
        oh, ow = other_depth.shape
        inside = front & (x >= 0) & (y >= 0) & (x < ow) & (y < oh)
        d = np.zeros(len(z))
        d[inside] = other_depth[y[inside], x[inside]]
        agree += (d > 0) & (np.abs(d - cam[:, 2]) <= rel_tol * cam[:, 2])
    out = np.zeros((h, w), bool)
    out[v, u] = agree >= min_agree
    return out
