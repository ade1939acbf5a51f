"""Colors onto meshes: the paper's 3-NN color transfer and a texture baked into xatlas UVs."""

from __future__ import annotations

import cv2
import numpy as np
from scipy.spatial import cKDTree

from rose_usd.core.color import linear_to_srgb8


def transfer_colors(
    vertices: np.ndarray, points: np.ndarray, colors: np.ndarray, k: int = 3, *, tree: cKDTree | None = None
) -> np.ndarray:
    """Distance-weighted mean color of the k nearest fused points (the paper's rule); ``tree``:
    a cKDTree of ``points`` already built."""
    d, idx = (tree if tree is not None else cKDTree(points)).query(vertices, k=k, workers=-1)
    w = 1.0 / np.maximum(d, 1e-6)
    return (colors[idx] * w[..., None]).sum(axis=1) / w.sum(axis=1, keepdims=True)


TEXEL_CHUNK = 1 << 19
"""Texels whose positions and colors are made at once: a 2048 px texture has up to 4.2M, and
their float64 positions, barycentric weights and temporaries took about 1 GB in one go."""


def bake_texture(
    vertices: np.ndarray, faces: np.ndarray, points: np.ndarray, colors: np.ndarray, size: int, texel_colors=None
):
    """xatlas UVs and a texture whose every texel takes the 3-NN color of the fused points at its
    3D position (sharper than interpolating vertex colors), or, with ``texel_colors`` (texel
    positions (N, 3), normals (N, 3) -> linear colors (N, 3), seen (N,) bool), that color where
    seen. Texels are colored ``TEXEL_CHUNK`` at a time (each texel's color depends on it alone).
    Returns the seam-split mesh's (vertices, faces, uv, vertex colors) and the sRGB8 texture
    (size, size, 3)."""
    import xatlas

    vmap, new_faces, uv = xatlas.parametrize(vertices.astype(np.float32), faces.astype(np.uint32))
    verts = vertices[vmap]
    px = uv * (size - 1)
    px[:, 1] = (size - 1) - px[:, 1]  # image rows grow downward, v upward
    tri_id = np.full((size, size), -1, np.int32)
    for i, tri in enumerate(np.round(px[new_faces] * 4).astype(np.int32)):
        cv2.fillConvexPoly(tri_id, tri, i, lineType=cv2.LINE_8, shift=2)
    tri_id = dilate_ids(tri_id, 2)  # bleed past seams so filtering never reads the empty background
    ys, xs = np.nonzero(tri_id >= 0)
    tex = np.zeros((size, size, 3), np.uint8)
    tree = None
    for start in range(0, len(ys), TEXEL_CHUNK):
        y, x = ys[start : start + TEXEL_CHUNK], xs[start : start + TEXEL_CHUNK]
        f = new_faces[tri_id[y, x]]
        texel_xyz = _texel_points(px, verts, f, x, y)
        texel_rgb, seen = np.zeros((len(texel_xyz), 3)), np.zeros(len(texel_xyz), bool)
        if texel_colors is not None:
            normals = np.cross(verts[f[:, 1]] - verts[f[:, 0]], verts[f[:, 2]] - verts[f[:, 0]])
            normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
            texel_rgb, seen = texel_colors(texel_xyz, normals)
        if not seen.all():  # the 3-NN rule only where no frame saw the texel
            tree = cKDTree(points) if tree is None else tree
            texel_rgb[~seen] = transfer_colors(texel_xyz[~seen], points, colors, tree=tree)
        tex[y, x] = linear_to_srgb8(texel_rgb)
    vertex_colors = transfer_colors(verts, points, colors, tree=tree)
    return verts, new_faces.astype(np.int64), uv.astype(float), vertex_colors, tex


def _texel_points(px: np.ndarray, verts: np.ndarray, f: np.ndarray, xs: np.ndarray, ys: np.ndarray) -> np.ndarray:
    """3D positions (N, 3) of texels (xs, ys) on their triangles ``f`` (N, 3): barycentric in the
    triangles' texture-space corners ``px``, clipped to the triangle."""
    a, b, c = px[f[:, 0]], px[f[:, 1]], px[f[:, 2]]
    q = np.stack([xs, ys], axis=1).astype(float)
    v0, v1, v2 = b - a, c - a, q - a
    den = v0[:, 0] * v1[:, 1] - v1[:, 0] * v0[:, 1]
    den = np.where(np.abs(den) < 1e-12, 1e-12, den)
    wb = np.clip((v2[:, 0] * v1[:, 1] - v1[:, 0] * v2[:, 1]) / den, 0, 1)
    wc = np.clip((v0[:, 0] * v2[:, 1] - v2[:, 0] * v0[:, 1]) / den, 0, 1)
    wa = np.clip(1.0 - wb - wc, 0, 1)
    s = (wa + wb + wc)[:, None]
    return (verts[f[:, 0]] * wa[:, None] + verts[f[:, 1]] * wb[:, None] + verts[f[:, 2]] * wc[:, None]) / s


def dilate_ids(ids: np.ndarray, steps: int) -> np.ndarray:
    for _ in range(steps):
        empty = ids < 0
        if not empty.any():
            break
        grown = ids.copy()
        for dy, dx in ((0, 1), (0, -1), (1, 0), (-1, 0)):
            shifted = np.roll(ids, (dy, dx), axis=(0, 1))
            take = empty & (grown < 0) & (shifted >= 0)
            grown[take] = shifted[take]
        ids = grown
    return ids
