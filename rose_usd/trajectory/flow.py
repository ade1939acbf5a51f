"""Image motion of the object's texture between consecutive frames, as constraints on its pose.

Depth alone leaves directions free: a cup's wall seen from above fits its depth at any position
along its axis and at any spin about it. Its printed pattern does not: corners of the object's
previous frame, tracked into this one by Lucas-Kanade (kept when they come back within
``FB_PX``), are 3-D points on the object (the previous frame's depth, carried back by its pose)
with the pixel where this frame sees them. ``terms`` turns them into Gauss-Newton rows for the
tracker's ICP, in the same metric units as its point-to-plane residuals.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from rose_usd.core import se3
from rose_usd.core.pinhole import backproject, project

FB_PX = 0.5
"""A corner tracked into the next frame and back must land within this of where it started [px]."""
CAUCHY_PX = 2.0
"""Reprojection residuals are down-weighted beyond about this [px]."""
MIN_FEATURES = 8
"""Fewer tracked corners than this are no constraint."""
QUALITY = 0.01
"""Corners weaker than this fraction of the frame's strongest are not taken."""
WINDOW_PX = 15
"""Lucas-Kanade's window [px]."""


@dataclass(frozen=True)
class Features:
    """Object points and where the current frame sees them."""

    points: np.ndarray
    """(M, 3) on the object at its frame-0 pose (world coordinates)."""
    pixels: np.ndarray
    """(M, 2) pixel centers in the current frame."""
    cv_from_world: np.ndarray
    K: np.ndarray

    def __len__(self) -> int:
        return len(self.points)

    def subset(self, keep: np.ndarray) -> Features | None:
        """Those where ``keep`` holds; None when fewer than ``MIN_FEATURES``."""
        if np.count_nonzero(keep) < MIN_FEATURES:
            return None
        return Features(self.points[keep], self.pixels[keep], self.cv_from_world, self.K)


def track_features(
    prev: tuple[np.ndarray, np.ndarray, np.ndarray],
    gray: np.ndarray,
    view_prev: tuple[np.ndarray, np.ndarray],
    view: tuple[np.ndarray, np.ndarray],
    motion_prev: np.ndarray,
    *,
    region: np.ndarray,
    max_corners: int = 200,
) -> Features | None:
    """Corners of the previous frame's object, tracked into ``gray``. ``prev``: that frame's grey
    image, the object's pixels in it (bool; the hand and its border already removed) and its
    metric depth; ``view_prev``/``view``: (world_from_cv, K) of the two frames; ``motion_prev``:
    the previous frame's D_t; ``region``: where in this frame the object may be seen (bool).
    None when fewer than ``MIN_FEATURES`` survive."""
    gray_prev, where_prev, depth_prev = prev
    corners = cv2.goodFeaturesToTrack(
        gray_prev, maxCorners=max_corners, qualityLevel=QUALITY, minDistance=5, mask=where_prev.astype(np.uint8)
    )
    if corners is None or len(corners) < MIN_FEATURES:
        return None
    uv = corners.reshape(-1, 2).astype(np.float32)
    moved, st, _ = cv2.calcOpticalFlowPyrLK(gray_prev, gray, uv, None, winSize=(WINDOW_PX, WINDOW_PX), maxLevel=3)
    back, st2, _ = cv2.calcOpticalFlowPyrLK(gray, gray_prev, moved, None, winSize=(WINDOW_PX, WINDOW_PX), maxLevel=3)
    ok = (st.ravel() == 1) & (st2.ravel() == 1) & (np.linalg.norm(back - uv, axis=1) < FB_PX)
    h, w = gray.shape
    iu, iv = np.round(moved[:, 0]).astype(int), np.round(moved[:, 1]).astype(int)
    inside = (iu >= 0) & (iu < w) & (iv >= 0) & (iv < h)
    ok &= inside
    ok[ok] = region[iv[ok], iu[ok]]
    pu, pv = np.round(uv[:, 0]).astype(int), np.round(uv[:, 1]).astype(int)
    z = depth_prev[pv, pu]
    ok &= z > 0
    if ok.sum() < MIN_FEATURES:
        return None
    world_from_cv_prev, K_prev = view_prev
    cam_points = backproject(uv[ok, 0].astype(float), uv[ok, 1].astype(float), z[ok], K_prev)  # where the corner is
    on_object = se3.transform_points(se3.invert(motion_prev) @ world_from_cv_prev, cam_points)
    world_from_cv, K = view
    return Features(on_object, moved[ok].astype(float), se3.invert(world_from_cv), K)


def terms(features: Features, motion: np.ndarray, center: np.ndarray, weight: float) -> tuple[np.ndarray, np.ndarray]:
    """Gauss-Newton normal equations (H (6, 6), g (6,)) of the features' reprojection residuals at
    ``motion``, for the tracker's update (rotation vector, translation) about ``center`` applied
    on the model side (``inv <- step @ inv``). Residuals are pixels scaled by depth / focal length
    (meters on the object, as the depth residuals are), Cauchy-weighted, each corner ``weight``."""
    a = features.points - center
    R = motion[:3, :3]
    world = se3.transform_points(motion, features.points)
    q = se3.transform_points(features.cv_from_world, world)
    z = q[:, 2]
    K = features.K
    fx, fy = K[0, 0], K[1, 1]
    pred = np.stack(project(q, K), axis=1)
    r = (pred - features.pixels).ravel()
    # d world / d xi: the model-side step moves a point by -(w x a + v), carried to the world by R
    skew = np.zeros((len(a), 3, 3))
    skew[:, 0, 1], skew[:, 0, 2], skew[:, 1, 2] = -a[:, 2], a[:, 1], -a[:, 0]
    skew[:, 1, 0], skew[:, 2, 0], skew[:, 2, 1] = a[:, 2], -a[:, 1], a[:, 0]
    dworld = np.concatenate([R @ skew, np.broadcast_to(-R, (len(a), 3, 3))], axis=2)  # (M, 3, 6)
    dq = features.cv_from_world[:3, :3] @ dworld
    proj = np.zeros((len(a), 2, 3))
    proj[:, 0, 0], proj[:, 0, 2] = fx / z, -fx * q[:, 0] / z**2
    proj[:, 1, 1], proj[:, 1, 2] = fy / z, -fy * q[:, 1] / z**2
    J = (proj @ dq).reshape(-1, 6)
    scale = np.stack([z / fx, z / fy], axis=1).ravel()  # pixels -> meters at the point's depth
    wt = weight / (1.0 + (r / CAUCHY_PX) ** 2)
    J, r = J * scale[:, None], r * scale
    return (J * wt[:, None]).T @ J, (J * wt[:, None]).T @ r
