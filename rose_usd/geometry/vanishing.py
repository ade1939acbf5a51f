"""Gravity from one image: the vertical vanishing point of its straight lines (RGB only).

A static camera measures no 3D, so the up direction must come from the picture itself: man-made
scenes are full of vertical edges (door frames, monitor sides, a bottle) and of horizontal ones in
two directions (a table's and a keyboard's edges). Line segments are found by OpenCV's LSD. Each
segment and the camera center span an interpretation plane, with unit normal ``n = K^T l`` (``l``
the segment's homogeneous image line); a 3D direction ``d`` the segment may lie along satisfies
``n . d = 0``, so a vanishing direction is the least-squares null vector of its segments' normals
(no vanishing point at infinity is special).

1. **Vertical**: RANSAC over pairs of roughly upright segments (within 35 deg of the image's
   vertical: a camera is held with little roll), each pair's ``d = n1 x n2`` scored by the length
   of the segments within 1.5 deg of it, among directions within ``max_pitch_deg`` of image-up.
2. **Horizontal**: the same among the other segments, for directions within 10 deg of
   perpendicular to the vertical (the table's edges, the keyboard's), twice.
3. **Manhattan refinement**: the rotation whose axes best fit all three groups' segments (Gauss-
   Newton on SO(3)); without a second horizontal direction, the vertical and the first; without a
   vertical group, up is the cross product of two horizontal directions.

The uncertainty is the larger of two: the angle's standard error over the vertical group's
segments, at least 1 deg (correlated errors: lens distortion, leaning objects), 3 deg without a
vertical group; and the spread of the answer over bootstrap resamplings of the segments, which is
large where two line groups' frames compete (a few short lines on a small image, pens laid at
random beside a keyboard).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial

import cv2
import numpy as np

INLIER_DEG = 1.5
"""A segment lies along a direction when its interpretation plane is this near to containing it [deg]."""


@dataclass(frozen=True)
class UpEstimate:
    up_cam: np.ndarray
    """Unit up vector in OpenCV camera axes (x right, y down, z forward)."""
    uncertainty_deg: float
    vertical_segments: int
    horizontal_segments: int
    how: str
    """``vertical``, ``vertical+horizontal``, ``horizontal`` (two horizontal directions), ``manhattan``."""


def line_segments(gray: np.ndarray, *, min_length_frac: float = 0.03) -> np.ndarray:
    """LSD segments (N, 4) as x1, y1, x2, y2 [px], at least ``min_length_frac`` of the image diagonal long."""
    lsd = cv2.createLineSegmentDetector(cv2.LSD_REFINE_STD)
    found = lsd.detect(gray)[0]
    if found is None:
        return np.zeros((0, 4))
    seg = found.reshape(-1, 4).astype(float)
    length = np.hypot(seg[:, 2] - seg[:, 0], seg[:, 3] - seg[:, 1])
    return seg[length >= min_length_frac * np.hypot(*gray.shape)]


def plane_normals(segments: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Unit normals (N, 3) of the segments' interpretation planes (camera axes)."""
    p1 = np.column_stack([segments[:, :2], np.ones(len(segments))])
    p2 = np.column_stack([segments[:, 2:], np.ones(len(segments))])
    n = np.cross(p1, p2) @ K  # K^T l, row-wise
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def _null_direction(normals: np.ndarray, weights: np.ndarray) -> np.ndarray:
    m = (normals * weights[:, None]).T @ normals
    return np.linalg.eigh(m)[1][:, 0]


def _ransac(normals, weights, candidates, reject, *, iterations: int = 600, seed: int = 0):
    """The direction (unit 3-vector) supported by the most segment length among ``candidates``
    (indices), drawn from pairs of them, that ``reject`` (bool over rows of directions) allows;
    and its inliers (bool over all segments). None when nothing is allowed."""
    if len(candidates) < 2:
        return None, None
    rng = np.random.default_rng(seed)
    tol = np.sin(np.radians(INLIER_DEG))
    pairs = np.array([rng.choice(candidates, size=2, replace=False) for _ in range(iterations)])
    d = np.cross(normals[pairs[:, 0]], normals[pairs[:, 1]])
    norm = np.linalg.norm(d, axis=1)
    ok = norm >= 1e-6
    d = d[ok] / norm[ok, None]
    d = d[~reject(d)]
    if not len(d):
        return None, None
    score = weights[candidates] @ (np.abs(normals[candidates] @ d.T) < tol)
    best = d[int(np.argmax(score))]
    for _ in range(3):  # refit on the inliers
        inliers = np.zeros(len(normals), bool)
        inliers[candidates] = np.abs(normals[candidates] @ best) < tol
        d = _null_direction(normals[inliers], weights[inliers])
        best = d if d @ best > 0 else -d
    inliers = np.zeros(len(normals), bool)
    inliers[candidates] = np.abs(normals[candidates] @ best) < tol
    return best, inliers


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip(abs(a @ b) / (np.linalg.norm(a) * np.linalg.norm(b)), -1, 1))))


def _manhattan(axes: list[np.ndarray], groups: list[np.ndarray], normals, weights, iterations: int = 20):
    """Orthonormal axes (rows) nearest to ``axes`` (2 or 3 directions, the first the vertical) that
    best fit their segment groups (Gauss-Newton on the rotation)."""
    a = list(axes)
    if len(a) == 2:
        a.append(np.cross(a[0], a[1]))
    r = np.array(a, dtype=float)
    u, _, vt = np.linalg.svd(r)
    r = u @ vt  # nearest rotation (rows: the axes)
    for _ in range(iterations):
        jt_j, jt_r = np.zeros((3, 3)), np.zeros(3)
        for k, group in enumerate(groups):
            if group is None or not group.any():
                continue
            n, w = normals[group], weights[group]
            axis = r[k]
            res = n @ axis  # want 0; d(axis) = omega x axis
            jac = np.cross(axis, n)  # d(n . (omega x axis))/d omega = axis x n
            jt_j += (jac * w[:, None]).T @ jac
            jt_r += (jac * (w * res)[:, None]).sum(axis=0)
        step = -np.linalg.solve(jt_j + 1e-9 * np.eye(3), jt_r)
        angle = np.linalg.norm(step)
        if angle < 1e-9:
            break
        rot = cv2.Rodrigues(step)[0]
        r = r @ rot.T
    return r


def _directions(normals, weights, min_segments: int, directions: int) -> tuple[list, list]:
    """Up to ``directions`` vanishing directions (unit 3-vectors), each found by RANSAC among the
    segments not yet explained, and their inlier groups (bool over all segments)."""
    found, groups = [], []
    rest = np.ones(len(normals), bool)
    for k in range(directions):

        def known(d):  # within 5 deg of a direction already found
            if not found:
                return np.zeros(len(d), bool)
            return (np.abs(d @ np.array(found).T) > np.cos(np.radians(5.0))).any(axis=1)

        d, inl = _ransac(normals, weights, np.flatnonzero(rest), known, seed=k)
        if d is None or inl.sum() < min_segments:
            break
        found.append(d)
        groups.append(inl)
        rest &= ~inl
    return found, groups


def _plausible(u, *, max_pitch_deg: float, max_roll_deg: float, max_tilt_up_deg: float):
    """``u`` turned toward image-up when the camera it implies looks level or down and is rolled
    little enough; else None."""
    image_up = np.array([0.0, -1.0, 0.0])
    u = u if u @ image_up >= 0 else -u
    if _angle_deg(u, image_up) > max_pitch_deg or u[2] > np.sin(np.radians(max_tilt_up_deg)):
        return None
    if abs(u[0]) > np.sin(np.radians(max_roll_deg)) * np.hypot(u[0], u[1]):
        return None
    return u


def _best_candidate(found: list, support: np.ndarray, plausible):
    """The plausible up candidate (each direction, each cross product of two near perpendicular
    ones) whose Manhattan frame explains the most segment length: (score, up, along, across)
    with the indices of the directions along and across it; None when none is plausible."""
    candidates = [plausible(f) for f in found]
    for i in range(len(found)):
        for j in range(i + 1, len(found)):
            if _angle_deg(found[i], found[j]) > 80.0:
                c = np.cross(found[i], found[j])
                candidates.append(plausible(c / np.linalg.norm(c)))
    best = None
    for u in candidates:
        if u is None:
            continue
        along = [i for i, f in enumerate(found) if _angle_deg(f, u) < 5.0]
        across = [i for i, f in enumerate(found) if abs(90.0 - _angle_deg(f, u)) < 5.0]
        score = float(support[along].sum() + support[across].sum())
        if best is None or score > best[0]:
            best = (score, u, along, across)
    return best


def _refined(u, along, v_in, across, found, groups, normals, weights) -> tuple[np.ndarray, str]:
    """Up refined with the Manhattan frame of the directions ``along`` it (their segments ``v_in``,
    bool over all segments) and ``across`` it: (unit up, how)."""
    if along and across:
        axes = _manhattan([u] + [found[i] for i in across], [v_in] + [groups[i] for i in across], normals, weights)
        u = axes[0] if axes[0] @ u > 0 else -axes[0]
        how = "manhattan" if len(across) == 2 else "vertical+horizontal"
    elif len(across) == 2:
        axes = _manhattan([u] + [found[i] for i in across], [None] + [groups[i] for i in across], normals, weights)
        u = axes[0] if axes[0] @ u > 0 else -axes[0]
        how = "horizontal"
    else:
        how = "vertical"
    return u / np.linalg.norm(u), how


def _sigma_deg(normals: np.ndarray, v_in: np.ndarray, u: np.ndarray) -> float:
    """Up's uncertainty [deg]: the standard error over the vertical group's segments (``v_in``), at
    least 1 deg; 3 deg without a vertical group."""
    if v_in.any():
        residual = np.degrees(np.arcsin(np.clip(np.abs(normals[v_in] @ u), 0, 1)))
        return max(1.0, float(np.sqrt(np.mean(residual**2)) / np.sqrt(max(v_in.sum() - 1, 1)) * 3.0))
    return 3.0


def _candidate(segments: np.ndarray, K: np.ndarray, plausible, min_segments: int, directions: int):
    """The winning up candidate of these segments, before refinement: (up, along, across, found,
    groups, normals, weights, support), or None when they give none."""
    normals = plane_normals(segments, K)
    length = np.hypot(segments[:, 2] - segments[:, 0], segments[:, 3] - segments[:, 1])
    weights = length / length.max()
    found, groups = _directions(normals, weights, min_segments, directions)
    if not found:
        return None
    support = np.array([weights[g].sum() for g in groups])
    best = _best_candidate(found, support, plausible)
    if best is None:
        return None
    return best[1], best[2], best[3], found, groups, normals, weights, support


def _bootstrap_deg(segments, K, up, plausible, min_segments: int, directions: int, resamples: int) -> float:
    """RMS angle [deg] between ``up`` and the candidates won by ``resamples`` resamplings (with
    replacement) of the segments; a resampling that gives no candidate counts as 90 deg."""
    rng = np.random.default_rng(0)
    angles = []
    for _ in range(resamples):
        won = _candidate(
            segments[rng.integers(0, len(segments), len(segments))], K, plausible, min_segments, directions
        )
        angles.append(90.0 if won is None else _angle_deg(won[0], up))
    return float(np.sqrt(np.mean(np.square(angles))))


def up_from_lines(
    gray: np.ndarray,
    K: np.ndarray,
    *,
    max_pitch_deg: float = 85.0,
    max_roll_deg: float = 25.0,
    max_tilt_up_deg: float = 10.0,
    min_segments: int = 4,
    directions: int = 6,
    resamples: int = 24,
) -> UpEstimate | None:
    """The up direction of a single view from its line segments, None when its lines give none.

    Up to ``directions`` vanishing directions are found one after the other (RANSAC over pairs of
    the segments not yet explained). Every one of them, and the cross product of every two near
    perpendicular ones, is a candidate for up; a candidate is plausible when the camera it implies
    looks level or down (up to ``max_tilt_up_deg`` up; a table's edges that recede from the
    camera meet above the image, along +z in camera axes, where up has -z) and is rolled by at
    most ``max_roll_deg``. The plausible candidate whose Manhattan frame explains the most segment
    length (directions along it or perpendicular to it, within 5 deg) wins, and is refined with
    them (``_manhattan``). A camera looking steeply down at a table sees few vertical edges, but
    two perpendicular sets of horizontal ones (cards, a keyboard) whose cross product is up.

    The uncertainty is at least the RMS angle to the winners of ``resamples`` bootstrap
    resamplings of the segments: where another line group's frame nearly ties, the choice flips
    and the spread shows it."""
    segments = line_segments(gray)
    if len(segments) < min_segments:
        return None
    plausible = partial(
        _plausible, max_pitch_deg=max_pitch_deg, max_roll_deg=max_roll_deg, max_tilt_up_deg=max_tilt_up_deg
    )
    won = _candidate(segments, K, plausible, min_segments, directions)
    if won is None:
        return None
    chosen, along, across, found, groups, normals, weights, support = won
    v_in = np.zeros(len(segments), bool)
    for i in along:
        v_in |= groups[i]
    across = sorted(across, key=lambda i: -support[i])[:2]
    u, how = _refined(chosen, along, v_in, across, found, groups, normals, weights)
    if _angle_deg(u, chosen) > 5.0 or plausible(u) is None:  # the refinement ran off: keep the candidate
        u = chosen
    h_count = int(sum(groups[i].sum() for i in across))
    spread = _bootstrap_deg(segments, K, u, plausible, min_segments, directions, resamples) if resamples else 0.0
    return UpEstimate(u, max(_sigma_deg(normals, v_in, u), spread), int(v_in.sum()), h_count, how)


def upright_prior(pitch_deg: float = 30.0) -> np.ndarray:
    """The up vector of a level camera pitched down by ``pitch_deg`` (camera axes): the guess
    when the image has no usable lines."""
    p = np.radians(pitch_deg)
    return np.array([0.0, -np.cos(p), -np.sin(p)])
