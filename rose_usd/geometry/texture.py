"""Colors onto meshes: the paper's 3-NN color transfer and a texture baked into xatlas UVs."""

from __future__ import annotations

import cv2
import numpy as np
from scipy.spatial import cKDTree

from rose_usd.core.color import linear_to_srgb8


def transfer_colors(vertices: np.ndarray, points: np.ndarray, colors: np.ndarray, k: int = 3) -> np.ndarray:
    """Distance-weighted mean color of the k nearest fused points (the paper's rule)."""
    d, idx = cKDTree(points).query(vertices, k=k, workers=-1)
    w = 1.0 / np.maximum(d, 1e-6)
    return (colors[idx] * w[..., None]).sum(axis=1) / w.sum(axis=1, keepdims=True)


def bake_texture(
    vertices: np.ndarray, faces: np.ndarray, points: np.ndarray, colors: np.ndarray, size: int, texel_colors=None
):
    """xatlas UVs and a texture whose every texel takes the 3-NN color of the fused points at its
    3D position (sharper than interpolating vertex colors), or, with ``texel_colors`` (texel
    positions (N, 3), normals (N, 3) -> linear colors (N, 3), seen (N,) bool), that color where
    seen. Returns the seam-split mesh's (vertices, faces, uv, vertex colors) and the sRGB8
    texture (size, size, 3)."""
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
    f = new_faces[tri_id[ys, xs]]
    a, b, c = px[f[:, 0]], px[f[:, 1]], px[f[:, 2]]
    q = np.stack([xs, ys], axis=1).astype(float)
    v0, v1, v2 = b - a, c - a, q - a
    den = v0[:, 0] * v1[:, 1] - v1[:, 0] * v0[:, 1]
    den = np.where(np.abs(den) < 1e-12, 1e-12, den)
    wb = np.clip((v2[:, 0] * v1[:, 1] - v1[:, 0] * v2[:, 1]) / den, 0, 1)
    wc = np.clip((v0[:, 0] * v2[:, 1] - v2[:, 0] * v0[:, 1]) / den, 0, 1)
    wa = np.clip(1.0 - wb - wc, 0, 1)
    s = (wa + wb + wc)[:, None]
    texel_xyz = (verts[f[:, 0]] * wa[:, None] + verts[f[:, 1]] * wb[:, None] + verts[f[:, 2]] * wc[:, None]) / s
    texel_rgb, seen = np.zeros((len(texel_xyz), 3)), np.zeros(len(texel_xyz), bool)
    if texel_colors is not None:
        normals = np.cross(verts[f[:, 1]] - verts[f[:, 0]], verts[f[:, 2]] - verts[f[:, 0]])
        normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
        texel_rgb, seen = texel_colors(texel_xyz, normals)
    if not seen.all():  # the 3-NN rule only where no frame saw the texel
        texel_rgb[~seen] = transfer_colors(texel_xyz[~seen], points, colors)
    tex = np.zeros((size, size, 3), np.uint8)
    tex[ys, xs] = linear_to_srgb8(texel_rgb)
    return verts, new_faces.astype(np.int64), uv.astype(float), transfer_colors(verts, points, colors), tex


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
