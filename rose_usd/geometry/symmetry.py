"""A mesh's shape symmetries and the choice among them by colour.

A silhouette (or a depth map) cannot tell apart the orientations of a shape that maps onto itself:
a cube's 24, a plain can's turns about its axis. A textured object can: each such orientation
shows another part of its print where the video shows one. ``shape_symmetries`` finds the rigid
transforms of the mesh's frame that leave its shape in place (among the 24 turns of its oriented
bounding box's axes), and ``symmetry_scores`` says how well the mesh's colours under each of them
match a frame: the visible surface points at the fitted pose are the same for all of them, only the
colour each shows changes (a point q shows the colour of T^-1 q under the pose P T).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import cv2
import numpy as np
import trimesh
from scipy.spatial import cKDTree

from rose_usd.core import se3
from rose_usd.core.color import linear_to_srgb8


def _box_turns() -> np.ndarray:
    """The 24 proper rotations that map the coordinate axes onto themselves (signed permutations
    with determinant +1), identity first."""
    turns = []
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((1.0, -1.0), repeat=3):
            r = np.zeros((3, 3))
            r[range(3), perm] = signs
            if np.linalg.det(r) > 0:
                turns.append(r)
    return np.asarray(turns)


def shape_symmetries(vertices: np.ndarray, faces: np.ndarray, *, tol: float = 0.01, samples: int = 20000) -> np.ndarray:
    """The rigid transforms T (K, 4, 4) of the mesh's frame with T(mesh) = mesh, identity first:
    the turns of its oriented bounding box's axes about the box's centre under which its surface
    samples lie, on average, within ``tol`` of its size from the others (and 95 % of them within
    3 ``tol``; beyond the samples' own spacing). A mesh with no symmetry gives the identity alone."""
    mesh = trimesh.Trimesh(np.asarray(vertices, float), np.asarray(faces, np.int64), process=False)
    box = mesh.bounding_box_oriented.primitive
    box_from_mesh = np.linalg.inv(np.asarray(box.transform, float))
    size = float(np.linalg.norm(box.extents))
    points, _ = trimesh.sample.sample_surface(mesh, samples, seed=0)
    local = se3.transform_points(box_from_mesh, np.asarray(points, float))
    tree = cKDTree(local)
    spacing = float(np.sqrt(mesh.area / samples))
    probe = local[:: max(1, samples // 2000)]
    found = []
    for turn in _box_turns():
        d, _ = tree.query(probe @ turn.T, k=1)
        if d.mean() <= tol * size + 0.5 * spacing and np.percentile(d, 95) <= 3 * tol * size + spacing:
            found.append(np.linalg.inv(box_from_mesh) @ se3.make_pose(turn, np.zeros(3)) @ box_from_mesh)
    return np.asarray(found) if found else np.eye(4)[None]


@dataclass(frozen=True)
class ColouredSamples:
    """Points spread evenly over a mesh's surface, in its frame, with their outward normals and the
    sRGB8 colour its texture or vertex colours give them."""

    points: np.ndarray
    normals: np.ndarray
    colours: np.ndarray
    """(N, 3) float sRGB 0-255."""


def coloured_samples(
    vertices: np.ndarray,
    faces: np.ndarray,
    *,
    uv: np.ndarray | None = None,
    image: np.ndarray | None = None,
    linear_colours: np.ndarray | None = None,
    count: int = 30000,
) -> ColouredSamples:
    """``count`` samples of the mesh with the colour of its texture ``image`` (uint8 (H, W, 3), ``uv``
    per vertex with the origin bottom-left) or of its per-vertex ``linear_colours`` (linear RGB)."""
    mesh = trimesh.Trimesh(np.asarray(vertices, float), np.asarray(faces, np.int64), process=False)
    points, face, bary = trimesh.sample.sample_surface(mesh, count, return_barycentric=True, seed=0)
    corners = mesh.faces[face]
    if image is not None and uv is not None:
        st = np.einsum("nk,nkc->nc", bary, np.asarray(uv, float)[corners])
        h, w = image.shape[:2]
        x = np.clip(st[:, 0] % 1.0, 0, 1) * (w - 1)
        y = (1.0 - np.clip(st[:, 1] % 1.0, 0, 1)) * (h - 1)
        colours = cv2.remap(
            np.ascontiguousarray(image[..., :3]),
            x.astype(np.float32)[None],
            y.astype(np.float32)[None],
            cv2.INTER_LINEAR,
        )[0].astype(float)
    elif linear_colours is not None:
        per_vertex = linear_to_srgb8(np.asarray(linear_colours, float)).astype(float)
        colours = np.einsum("nk,nkc->nc", bary, per_vertex[corners])
    else:
        raise ValueError("coloured_samples: no texture and no vertex colours")
    return ColouredSamples(np.asarray(points, float), np.asarray(mesh.face_normals[face], float), colours)


def visible_samples(
    samples: ColouredSamples,
    world_from_object: np.ndarray,
    world_from_cv: np.ndarray,
    K: np.ndarray,
    mask: np.ndarray,
    *,
    depth_slack: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Which samples the camera sees at the pose, inside ``mask`` (bool (H, W)): facing it and
    within ``depth_slack`` [m] of the nearest sample drawn at their pixel (a 3x3 minimum, so that a
    far face's samples do not show through the gaps between a near face's); (indices, pixels (M, 2)
    as (x, y))."""
    cam_from_object = np.linalg.inv(world_from_cv) @ world_from_object
    cam = se3.transform_points(cam_from_object, samples.points)
    normals = samples.normals @ cam_from_object[:3, :3].T
    h, w = mask.shape
    z = cam[:, 2]
    ok = (z > 1e-3) & (np.einsum("nc,nc->n", normals, cam) < 0)
    u = np.full(len(z), -1, np.int64)
    v = np.full(len(z), -1, np.int64)
    u[ok] = np.round(K[0, 0] * cam[ok, 0] / z[ok] + K[0, 2]).astype(np.int64)
    v[ok] = np.round(K[1, 1] * cam[ok, 1] / z[ok] + K[1, 2]).astype(np.int64)
    ok &= (u >= 0) & (u < w) & (v >= 0) & (v < h)
    idx = np.flatnonzero(ok)
    nearest = np.full((h, w), np.inf, np.float32)
    np.minimum.at(nearest, (v[idx], u[idx]), z[idx].astype(np.float32))
    nearest = cv2.erode(nearest, np.ones((3, 3), np.uint8))
    seen = idx[(z[idx] <= nearest[v[idx], u[idx]] + depth_slack) & mask[v[idx], u[idx]]]
    return seen, np.stack([u[seen], v[seen]], axis=1)


@dataclass(frozen=True)
class SymmetricLook:
    """A mesh's coloured samples and its symmetries, with the sample whose colour each sample's
    place shows under each symmetry (``symmetric_look``)."""

    samples: ColouredSamples
    symmetries: np.ndarray
    """(K, 4, 4), identity first (``shape_symmetries``)."""
    sources: np.ndarray
    """(K, N): under the pose P T_k, the point of sample i shows the colour of sample sources[k, i]
    (the nearest to T_k^-1 of it)."""


def symmetric_look(samples: ColouredSamples, symmetries: np.ndarray) -> SymmetricLook:
    tree = cKDTree(samples.points)
    sources = np.stack(
        [tree.query(se3.transform_points(np.linalg.inv(sym), samples.points), k=1)[1] for sym in symmetries]
    )
    return SymmetricLook(samples, np.asarray(symmetries), sources)


def symmetry_scores(
    look: SymmetricLook,
    world_from_object: np.ndarray,
    world_from_cv: np.ndarray,
    K: np.ndarray,
    image: np.ndarray,
    mask: np.ndarray,
    *,
    min_points: int = 200,
) -> np.ndarray | None:
    """How well the object's colours under each of its symmetries at the pose match ``image``
    (uint8 (H, W, 3)) where ``mask`` shows it: the Pearson correlation of the shown and the seen
    colours, per channel, averaged (a gain and an offset, the light's and the camera's, change
    nothing); (K,), or None when fewer than ``min_points`` samples are seen."""
    samples = look.samples
    size = float(np.ptp(samples.points, axis=0).max())
    seen, px = visible_samples(samples, world_from_object, world_from_cv, K, mask, depth_slack=0.05 * size)
    if len(seen) < min_points:
        return None
    observed = image[px[:, 1], px[:, 0], :3].astype(float)
    return np.array([_correlation(samples.colours[src], observed) for src in look.sources[:, seen]])


def _correlation(a: np.ndarray, b: np.ndarray) -> float:
    """Mean over channels of the Pearson correlation of a and b (N, 3); a flat channel counts 0."""
    a = a - a.mean(axis=0)
    b = b - b.mean(axis=0)
    den = np.sqrt((a * a).sum(axis=0) * (b * b).sum(axis=0))
    return float(np.mean(np.where(den > 1e-9, (a * b).sum(axis=0) / np.maximum(den, 1e-9), 0.0)))
