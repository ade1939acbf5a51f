"""Antipodal grasps of a parallel-jaw gripper on a triangle mesh, without learned weights.

Two surface points make an antipodal grasp when the line between them lies inside the friction
cone at both (Nguyen's force-closure test for two soft point contacts): with outward normals n1,
n2 and d the unit direction from p1 to p2, the finger at p1 pushes along d, so ``d . -n1 >=
cos(atan(mu))``, and the one at p2 along -d, so ``-d . -n2 >= cos(atan(mu))``. Every candidate
pair of a point sample is tested at once (numpy, no loop per candidate). A grasp is then a tool
frame: its origin the pair's midpoint, its y axis the closing direction, its z axis the approach
direction, which may turn about the closing axis; :func:`grasp_frames` samples those turns.

:func:`boxes_hit` tests gripper boxes placed at many tool frames against a point cloud (the scene
collider and the object), again all at once.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def sample_surface(
    vertices: np.ndarray, faces: np.ndarray, n: int, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """``n`` points uniformly on a mesh's area, with the outward normals of their triangles.

    Args:
        vertices: (V, 3) [m].
        faces: (F, 3) vertex indices, counter-clockwise seen from outside.

    Returns:
        points (n, 3) [m] and unit normals (n, 3).
    """
    tri = np.asarray(vertices, dtype=float)[np.asarray(faces)]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area = np.linalg.norm(cross, axis=1)
    keep = area > 1e-14
    tri, cross, area = tri[keep], cross[keep], area[keep]
    which = rng.choice(len(tri), size=n, p=area / area.sum())
    u, v = rng.random(n), rng.random(n)
    flip = u + v > 1
    u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
    t = tri[which]
    points = t[:, 0] + u[:, None] * (t[:, 1] - t[:, 0]) + v[:, None] * (t[:, 2] - t[:, 0])
    return points, cross[which] / area[which, None]


@dataclass(frozen=True)
class Antipodal:
    """Antipodal point pairs: contact points, closing directions and widths."""

    p1: np.ndarray
    """(G, 3) first contact [m]."""
    p2: np.ndarray
    """(G, 3) second contact [m]."""
    alignment: np.ndarray
    """(G,) cosine of the larger angle between the closing line and a contact's inward normal
    (1: both fingers push straight into the surface)."""

    @property
    def center(self) -> np.ndarray:
        """(G, 3) midpoints [m]."""
        return (self.p1 + self.p2) / 2

    @property
    def width(self) -> np.ndarray:
        """(G,) distance between the contacts [m]."""
        return np.linalg.norm(self.p2 - self.p1, axis=1)

    @property
    def axis(self) -> np.ndarray:
        """(G, 3) unit closing directions, from p1 to p2."""
        return (self.p2 - self.p1) / self.width[:, None]

    def __len__(self) -> int:
        return len(self.p1)


def antipodal_pairs(
    points: np.ndarray,
    normals: np.ndarray,
    *,
    friction: float,
    max_width_m: float,
    min_width_m: float = 0.005,
) -> Antipodal:
    """Every pair (i < j) of surface points that is antipodal within the friction cone and whose
    distance lies in [min_width_m, max_width_m].

    Args:
        points: (N, 3) surface points [m].
        normals: (N, 3) their outward unit normals.
        friction: Coulomb friction coefficient at the contacts (the cone's half angle is atan of it).
    """
    points, normals = np.asarray(points, dtype=float), np.asarray(normals, dtype=float)
    delta = points[None, :, :] - points[:, None, :]  # (N, N, 3): from i to j
    dist = np.linalg.norm(delta, axis=2)
    with np.errstate(invalid="ignore", divide="ignore"):
        d = delta / dist[..., None]
    cos_cone = np.cos(np.arctan(friction))
    at_i = -np.einsum("ijk,ik->ij", d, normals)  # d . -n_i
    at_j = np.einsum("ijk,jk->ij", d, normals)  # -d . -n_j
    ok = (at_i >= cos_cone) & (at_j >= cos_cone) & (dist >= min_width_m) & (dist <= max_width_m)
    ok &= np.triu(np.ones_like(ok), k=1)
    i, j = np.nonzero(ok)
    return Antipodal(points[i], points[j], np.minimum(at_i[i, j], at_j[i, j]))


def levelled(pairs: Antipodal, up: np.ndarray, friction: float) -> Antipodal:
    """The pairs with their closing line turned level (perpendicular to ``up`` (3,)) about its
    midpoint, the width kept, where the turn keeps the line inside both friction cones: the pads of
    a gripper coming from above close level, and the few sampled chords that are level are what
    holds a thin object lying on the support. A turn by a moves the line's angle to each contact's
    normal by at most a, so a pair stays antipodal when its larger angle plus a is within the cone."""
    up = np.asarray(up, dtype=float) / np.linalg.norm(up)
    d = pairs.axis
    flat = d - (d @ up)[:, None] * up
    norm = np.linalg.norm(flat, axis=1)
    tilt = np.arcsin(np.clip(np.abs(d @ up), 0.0, 1.0))
    worst = np.arccos(np.clip(pairs.alignment, -1.0, 1.0)) + tilt
    keep = (norm > 1e-6) & (tilt > np.radians(0.5)) & (worst <= np.arctan(friction))
    flat = flat[keep] / norm[keep, None]
    half = pairs.width[keep, None] / 2
    c = pairs.center[keep]
    return Antipodal(c - half * flat, c + half * flat, np.cos(worst[keep]))


def grasp_frames(pairs: Antipodal, n_turns: int, down: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Tool frames (G * n_turns, 4, 4) of the pairs: origin at the midpoint, y along the closing
    axis, z (the approach) turned about it by ``n_turns`` angles evenly spread over a full turn,
    the first as near ``down`` (3,) (default -z) as the closing axis allows.
    Returns the frames and the index of the pair each one belongs to."""
    y = pairs.axis
    down = np.array([0.0, 0.0, -1.0]) if down is None else np.asarray(down, dtype=float) / np.linalg.norm(down)
    other = np.array([1.0, 0.0, 0.0] if abs(down[0]) < 0.9 else [0.0, 1.0, 0.0])
    other -= (other @ down) * down  # for a closing axis along ``down``: a direction across it
    ref = np.where(np.abs(y @ down)[:, None] < 0.9, down[None], other[None] / np.linalg.norm(other))
    z0 = ref - np.sum(ref * y, axis=1, keepdims=True) * y
    z0 /= np.linalg.norm(z0, axis=1, keepdims=True)
    x0 = np.cross(y, z0)
    angles = np.arange(n_turns) * (2 * np.pi / n_turns)
    c, s = np.cos(angles)[None, :, None], np.sin(angles)[None, :, None]
    z = c * z0[:, None, :] + s * x0[:, None, :]  # (G, T, 3)
    yy = np.broadcast_to(y[:, None, :], z.shape)
    x = np.cross(yy, z)
    frames = np.zeros(z.shape[:2] + (4, 4))
    frames[..., :3, 0], frames[..., :3, 1], frames[..., :3, 2] = x, yy, z
    frames[..., :3, 3] = pairs.center[:, None, :]
    frames[..., 3, 3] = 1.0
    index = np.repeat(np.arange(len(pairs)), n_turns)
    return frames.reshape(-1, 4, 4), index


def boxes_hit(
    frames: np.ndarray, centers: np.ndarray, half_extents: np.ndarray, points: np.ndarray, *, chunk: int = 128
) -> np.ndarray:
    """Whether any point lies inside any of the boxes placed at each frame.

    Args:
        frames: (G, 4, 4) tool frames in the points' coordinates.
        centers: (B, 3) box centres in the tool frame [m].
        half_extents: (B, 3) box half extents [m] (axis-aligned in the tool frame).
        points: (P, 3) [m].

    Returns:
        (G,) bool.
    """
    frames = np.asarray(frames, dtype=np.float32)
    out = np.zeros(len(frames), dtype=bool)
    points = np.asarray(points, dtype=np.float32)
    if len(frames) == 0 or len(points) == 0:
        return out
    # only points within reach of a box matter: those near some frame's origin
    reach = float(np.max(np.linalg.norm(np.abs(centers) + half_extents, axis=1)))
    origins = frames[:, :3, 3]
    lo, hi = origins.min(axis=0) - reach, origins.max(axis=0) + reach
    points = points[np.all((points >= lo) & (points <= hi), axis=1)]
    if len(points) == 0:
        return out
    centers = np.asarray(centers, dtype=np.float32)
    half_extents = np.asarray(half_extents, dtype=np.float32)
    for start in range(0, len(frames), chunk):
        f = frames[start : start + chunk]
        # points in each tool frame: (p - t) R, batched as one matrix product per frame
        local = (points[None, :, :] - f[:, None, :3, 3]) @ f[:, :3, :3]
        hit = np.zeros(len(f), dtype=bool)
        for c, h in zip(centers, half_extents, strict=True):
            hit |= np.all(np.abs(local - c) <= h, axis=2).any(axis=1)
        out[start : start + chunk] = hit
    return out


def closing_extent(
    frames: np.ndarray,
    points: np.ndarray,
    half_x: float,
    z_range: tuple[float, float],
    *,
    chunk: int = 128,
) -> tuple[np.ndarray, np.ndarray]:
    """How far apart flat pads must open to take the object at each frame: the extent along the
    closing axis (y) of the points between the pads (|x| <= ``half_x``, z in ``z_range`` in the
    tool frame). A chord inside the friction cone can be shorter than that: flat pads touch the
    object where it is widest across them, not at the chord's ends. (G,) [m], 0 where no point
    lies between the pads; and (G,) how far the object reaches from the tool frame's origin along
    the closing axis, to the farther side [m]: the pads, opening evenly about the origin, must open
    twice that to pass it."""
    frames = np.asarray(frames, dtype=np.float32)
    points = np.asarray(points, dtype=np.float32)
    out, far = np.zeros(len(frames)), np.zeros(len(frames))
    for start in range(0, len(frames), chunk):
        f = frames[start : start + chunk]
        local = (points[None, :, :] - f[:, None, :3, 3]) @ f[:, :3, :3]
        between = (np.abs(local[..., 0]) <= half_x) & (local[..., 2] >= z_range[0]) & (local[..., 2] <= z_range[1])
        y = local[..., 1]
        hi = np.where(between, y, -np.inf).max(axis=1)
        lo = np.where(between, y, np.inf).min(axis=1)
        out[start : start + chunk] = np.where(np.isfinite(hi), hi - lo, 0.0)
        far[start : start + chunk] = np.where(np.isfinite(hi), np.maximum(hi, -lo), 0.0)
    return out, far
