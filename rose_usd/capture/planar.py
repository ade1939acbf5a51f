"""A near-static camera (hand-held, shaking by a few pixels) tracked against its support plane.

Structure from motion needs parallax, which a camera held still does not give ("no good initial
image pair"); treating it as static leaves its shake in every re-rendered frame. Corners of the
reference frame that lie on the support plane have known 3D points once the plane is known (its
normal from gravity, its distance the unit: the world is scaled later), so each frame's pose is a
PnP problem: the corners are tracked from the reference frame into every frame by pyramidal
Lucas-Kanade (from the reference image each time, started from the last frame's positions, so the
track does not drift), and the pose found by RANSAC PnP. Corners off the plane (a keyboard, the
hand) are outliers, or agree anyway when the camera only turns.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np

from rose_usd.core import se3


def plane_points(
    uv: np.ndarray, K: np.ndarray, up_cam: np.ndarray, height: float = 1.0
) -> tuple[np.ndarray, np.ndarray]:
    """3D points (camera axes) where the pixels' rays meet the plane ``height`` below the camera
    (normal ``up_cam``), and which rays meet it (below the horizon, within 20 heights)."""
    rays = np.column_stack([(uv[:, 0] - K[0, 2]) / K[0, 0], (uv[:, 1] - K[1, 2]) / K[1, 1], np.ones(len(uv))])
    down = rays @ up_cam
    ok = down < -1e-3
    s = np.where(ok, -height / np.where(ok, down, -1.0), 0.0)
    pts = rays * s[:, None]
    ok &= np.linalg.norm(pts, axis=1) < 20 * height
    return pts, ok


@dataclass(frozen=True)
class _Frames:
    """The video as the tracker sees it: grey frames scaled by ``s`` to ``size`` (w, h) [px], corners
    sought where ``keep`` (uint8 at ``size``, or None) is set, put on the plane by ``K`` and ``up_cam``."""

    rgb_of: Callable[[int], np.ndarray]
    s: float
    size: tuple[int, int]
    keep: np.ndarray | None
    K: np.ndarray
    up_cam: np.ndarray

    def gray(self, t: int) -> np.ndarray:
        """Frame ``t`` grey (uint8), at the tracking size."""
        g = cv2.cvtColor(self.rgb_of(t), cv2.COLOR_RGB2GRAY)
        return cv2.resize(g, self.size, interpolation=cv2.INTER_AREA) if self.s < 1 else g

    def seed(self, g: np.ndarray, world_from_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Corners of a frame (M, 2) [px at the tracking size] and their points on the plane (M, 3)
        (reference camera axes)."""
        corners = cv2.goodFeaturesToTrack(g, maxCorners=1200, qualityLevel=0.005, minDistance=8, mask=self.keep)
        if corners is None:
            return np.zeros((0, 2), np.float32), np.zeros((0, 3))
        uv = corners.reshape(-1, 2).astype(np.float32)
        full = (uv.astype(float) + 0.5) / self.s - 0.5
        up_here = world_from_cam[:3, :3].T @ self.up_cam
        height = 1.0 + float(self.up_cam @ world_from_cam[:3, 3])  # this camera's height over the plane
        pts, on = plane_points(full, self.K, up_here, height)
        return uv[on], (pts[on] @ world_from_cam[:3, :3].T) + world_from_cam[:3, 3]


def _flow(g_prev: np.ndarray, g: np.ndarray, uv: np.ndarray, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The corners ``uv`` (M, 2) moved into ``g`` by Lucas-Kanade, those that come back within 0.5 px
    kept with their plane points ``pts`` (M, 3)."""
    moved, st, _ = cv2.calcOpticalFlowPyrLK(g_prev, g, uv, None, winSize=(21, 21), maxLevel=3)
    back, st2, _ = cv2.calcOpticalFlowPyrLK(g, g_prev, moved, None, winSize=(21, 21), maxLevel=3)
    ok = (st.ravel() == 1) & (st2.ravel() == 1) & (np.linalg.norm(back - uv, axis=1) < 0.5)
    return moved[ok], pts[ok]


def _pnp(uv, pts, K: np.ndarray, s: float, t: int, rvec, tvec, last_pose: np.ndarray):
    """Frame ``t``'s pose from its corners ``uv`` (tracking size) and their plane points ``pts``,
    RANSAC PnP from the last pose (``rvec``, ``tvec``, ``last_pose``), refined on the inliers:
    (inlier indices, rvec, tvec, pose (4, 4), median reprojection error [px]), or None with fewer
    than 12 inliers."""
    img = (uv.astype(float) + 0.5) / s - 0.5
    cv2.setRNGSeed(t)  # RANSAC's samples: the same run to run
    found, r, tv, inl = cv2.solvePnPRansac(
        pts, img, K, None, rvec.copy(), tvec.copy(), useExtrinsicGuess=True,
        reprojectionError=2.0 / s, iterationsCount=200, flags=cv2.SOLVEPNP_ITERATIVE,
    )  # fmt: skip
    if found and inl is not None and len(inl) >= 12:
        jump = se3.invert(last_pose) @ se3.invert(se3.make_pose(cv2.Rodrigues(r)[0], tv.ravel()))
        # a hand-held camera moves a fraction of its height and a few degrees per frame:
        # more is RANSAC settling on a wrong minimal solution
        found = np.linalg.norm(jump[:3, 3]) < 0.15 and se3.rotation_angle_deg(jump[:3, :3]) < 8.0
    if not (found and inl is not None and len(inl) >= 12):
        # the last pose's reprojection picks the inliers instead
        proj = cv2.projectPoints(pts, rvec, tvec, K, None)[0].reshape(-1, 2)
        inl = np.flatnonzero(np.linalg.norm(proj - img, axis=1) < 4.0 / s)[:, None]
        r, tv = rvec, tvec
    if len(inl) < 12:
        return None
    idx = inl.ravel()
    rvec, tvec = cv2.solvePnPRefineLM(pts[idx], img[idx], K, None, r.copy(), tv.copy())
    pose = se3.invert(se3.make_pose(cv2.Rodrigues(rvec)[0], tvec.ravel()))
    proj = cv2.projectPoints(pts[idx], rvec, tvec, K, None)[0].reshape(-1, 2)
    return idx, rvec, tvec, pose, float(np.median(np.linalg.norm(proj - img[idx], axis=1)))


def _reseed(frames: _Frames, g: np.ndarray, pose: np.ndarray, uv: np.ndarray, pts: np.ndarray):
    """The corners ``uv`` and plane points ``pts`` with the frame's new corners (posed by ``pose``)
    more than 8 px from them added."""
    new_uv, new_pts = frames.seed(g, pose)
    if len(uv):
        near = np.min(np.linalg.norm(new_uv[:, None] - uv[None], axis=2), axis=1) > 8 if len(new_uv) else []
        new_uv, new_pts = new_uv[near], new_pts[near]
    return np.concatenate([uv, new_uv]), np.concatenate([pts, new_pts])


def _track_one_way(frames: _Frames, order, ref: int, first, g_ref, poses, inliers, errors, min_points: int) -> int:
    """Poses of the frames in ``order`` (forward or backward from ``ref``), written into ``poses``
    (n, 4, 4) with each frame's ``inliers`` and ``errors`` (n,); the corners start from ``first``
    (uv, pts) in ``g_ref``. Returns how many times corners were added."""
    uv, pts, g_prev = first[0].copy(), first[1].copy(), g_ref
    rvec, tvec = np.zeros((3, 1)), np.zeros((3, 1))
    last, reseeded = ref, 0
    for t in order:
        g = frames.gray(t)
        if len(uv) >= 12:
            uv, pts = _flow(g_prev, g, uv, pts)
        poses[t] = poses[last]
        if len(uv) >= 12:
            got = _pnp(uv, pts, frames.K, frames.s, t, rvec, tvec, poses[last])
            if got is not None:
                idx, rvec, tvec, poses[t], errors[t] = got
                inliers[t] = len(idx)
                uv, pts = uv[idx], pts[idx]  # outliers (the hand, what moves) are dropped
        if len(uv) < min_points:
            uv, pts = _reseed(frames, g, poses[t], uv, pts)
            reseeded += 1
        g_prev, last = g, t
    return reseeded


def track_planar(
    rgb_of: Callable[[int], np.ndarray],
    n: int,
    ref: int,
    K: np.ndarray,
    up_cam: np.ndarray,
    *,
    exclude: np.ndarray | None = None,
    max_side: int = 960,
    min_points: int = 150,
) -> tuple[np.ndarray, dict]:
    """Poses (n, 4, 4), reference-camera-from-camera (the reference camera is the identity; unit:
    its height over the plane), and what to record (inliers, reprojection error).

    Corners are tracked frame to frame (pyramidal Lucas-Kanade, forward-backward checked) from the
    reference frame forward, then backward; each frame's pose is RANSAC PnP of the tracked corners'
    plane points. When fewer than ``min_points`` corners remain (lost, or left the view), new ones
    are found in the frame and put on the plane through its pose."""
    h, w = rgb_of(ref).shape[:2]
    s = min(1.0, max_side / max(w, h))
    size = (int(round(w * s)), int(round(h * s)))
    keep = None
    if exclude is not None:
        keep = (~cv2.resize(exclude.astype(np.uint8), size, interpolation=cv2.INTER_NEAREST).astype(bool)).astype(
            np.uint8
        )
    frames = _Frames(rgb_of, s, size, keep, K, up_cam)
    poses = np.repeat(np.eye(4)[None], n, axis=0)
    inliers, errors = np.zeros(n), np.zeros(n)
    g_ref = frames.gray(ref)
    first_uv, first_pts = frames.seed(g_ref, poses[ref])
    inliers[ref] = len(first_uv)
    reseeded = 0
    for order in (range(ref + 1, n), range(ref - 1, -1, -1)):
        reseeded += _track_one_way(frames, order, ref, (first_uv, first_pts), g_ref, poses, inliers, errors, min_points)
    return poses, {
        "planar_corners": int(len(first_uv)),
        "planar_inliers_min": int(inliers.min()),
        "planar_inliers_median": int(np.median(inliers)),
        "planar_reprojection_px_median": round(float(np.median(errors)), 3),
        "planar_reseeded": reseeded,
    }


def image_motion(rgb_of: Callable[[int], np.ndarray], n: int, ref: int, *, samples: int = 12) -> float:
    """The largest, over frames spread through the video, of the displacement of the reference
    frame's corners (its lower quartile), as a fraction of the image's width: how far the camera
    looks away. The quartile, not the median: on a bare table most corners can lie on the hands and
    objects that move (sam2-cups, a still camera: median 0.107 of the width, quartile 0.029)."""
    g0 = cv2.cvtColor(rgb_of(ref), cv2.COLOR_RGB2GRAY)
    scale = min(1.0, 640 / g0.shape[1])
    g0 = cv2.resize(g0, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
    corners = cv2.goodFeaturesToTrack(g0, maxCorners=400, qualityLevel=0.01, minDistance=8)
    if corners is None or len(corners) < 20:
        return 1.0
    worst = 0.0
    for t in np.linspace(0, n - 1, min(samples, n)).round().astype(int):
        g = cv2.resize(
            cv2.cvtColor(rgb_of(int(t)), cv2.COLOR_RGB2GRAY), (g0.shape[1], g0.shape[0]), interpolation=cv2.INTER_AREA
        )
        moved, status, _ = cv2.calcOpticalFlowPyrLK(g0, g, corners, None, winSize=(21, 21), maxLevel=4)
        ok = status.ravel() == 1
        if ok.sum() < 0.3 * len(corners):
            return 1.0  # most corners lost: the view changed
        d = np.linalg.norm((moved - corners).reshape(-1, 2)[ok], axis=1)
        worst = max(worst, float(np.percentile(d, 25)) / g0.shape[1])
    return worst
