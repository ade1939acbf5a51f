"""Rigid motion of a segmented object's world points between frames (the segmenter's
propagation step): translation-only ICP robust to occlusion, then a turn where it clearly fits
better."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation


class Nearest:
    """Nearest-neighbour queries against fixed points (Open3D's KNN search: the same pairs and
    distances as SciPy's ``cKDTree.query``, in half its time on two cores)."""

    def __init__(self, points: np.ndarray):
        import open3d.core as o3c

        self._o3c = o3c
        self._nns = o3c.nns.NearestNeighborSearch(o3c.Tensor(np.ascontiguousarray(points, dtype=np.float64)))
        self._nns.knn_index()

    def query(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(distance, index) of each point of ``x`` (N, 3) to its nearest point."""
        idx, d2 = self._nns.knn_search(self._o3c.Tensor(np.ascontiguousarray(x, dtype=np.float64)), 1)
        return np.sqrt(d2.numpy()[:, 0]), idx.numpy()[:, 0].astype(np.intp)


def subsample(points: np.ndarray, k: int = 4000, seed: int = 0) -> np.ndarray:
    if len(points) <= k:
        return points
    return points[np.random.default_rng(seed).choice(len(points), k, replace=False)]


def diameter(points: np.ndarray) -> float:
    p = subsample(points, 1500)
    lo, hi = np.percentile(p, 2, axis=0), np.percentile(p, 98, axis=0)
    return float(np.linalg.norm(hi - lo))


def translation(old: np.ndarray, new: np.ndarray, iterations: int = 5) -> np.ndarray:
    """How far the points moved from ``old`` to ``new``: translation-only ICP (the median offset
    of each new point to its nearest old one), started from no motion and from the difference of
    the means, whichever ends nearer. The means alone are wrong under occlusion: a hand covering
    the top of a box that stands still moves the mean of what is seen down, and a velocity read
    from that carries the box's track into the table (the track is lost, and the scene fuses the
    box as a ghost)."""
    tree = Nearest(old)
    best, best_gap = np.zeros(3), np.inf
    for shift in (np.zeros(3), new.mean(axis=0) - old.mean(axis=0)):
        last = None
        for _ in range(iterations):
            _, nearest = tree.query(new - shift)
            if last is not None and np.array_equal(nearest, last):
                break  # the same pairs give the same shift: every further iteration repeats it
            shift, last = np.median(new - old[nearest], axis=0), nearest
        gap = float(np.median(tree.query(new - shift)[0]))
        if gap < best_gap:
            best, best_gap = shift, gap
    return best


def rotation_matrix(rotvec: np.ndarray) -> np.ndarray:
    return Rotation.from_rotvec(rotvec).as_matrix()


def rigid_motion(
    old: np.ndarray, new: np.ndarray, spin: np.ndarray, *, iterations: int = 6, max_turn_deg: float = 30.0
) -> tuple[np.ndarray, np.ndarray]:
    """The rigid motion (turn R about the old points' centre c, then shift t: x -> R (x - c) +
    c + t) that carries ``old`` onto ``new``. The shift alone first (``translation``: robust to what a
    hand hides); then, started from it and from the last turn ``spin``, point-to-point ICP with
    the turn (Kabsch on the pairs within their 80th-percentile gap). The turn is kept only where
    it brings the points nearer than the shift alone by 15 % of the median gap: the seen part of
    a still or sliding object must not turn with depth noise."""
    shift = translation(old, new)
    centre = np.median(old, axis=0)
    tree = Nearest(new)
    base = float(np.median(tree.query(old + shift)[0]))
    best = (np.eye(3), shift, base)
    for rot0 in (np.eye(3), rotation_matrix(spin)):
        rot, t = rot0, shift.copy()
        last = None
        for _ in range(iterations):
            moved = (old - centre) @ rot.T + centre + t
            d, idx = tree.query(moved)
            keep = d <= np.percentile(d, 80)
            if last is not None and np.array_equal(idx, last[0]) and np.array_equal(keep, last[1]):
                break  # the same pairs give the same turn and shift: a fixed point
            last = (idx, keep)
            a, b = old[keep] - centre, new[idx[keep]]
            ca, cb = a.mean(axis=0), b.mean(axis=0)
            u, _, vt = np.linalg.svd((a - ca).T @ (b - cb))
            rot = vt.T @ np.diag([1.0, 1.0, np.sign(np.linalg.det(vt.T @ u.T))]) @ u.T
            t = cb - rot @ ca - centre
        gap = float(np.median(tree.query((old - centre) @ rot.T + centre + t)[0]))
        angle = np.degrees(np.linalg.norm(Rotation.from_matrix(rot).as_rotvec()))
        if gap < best[2] - 0.15 * base and angle <= max_turn_deg:
            best = (rot, t, gap)
    return best[0], best[1]
