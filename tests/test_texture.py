"""The scene's texture bake (geometry.texture): texels take the colors of the surface they lie on,
and coloring them a chunk at a time gives the texture made in one go."""

import numpy as np
import pytest
import trimesh

from rose_usd.core.color import srgb8_to_linear
from rose_usd.geometry import texture

FACE_COLORS = np.array([[230, 20, 20], [20, 230, 20], [20, 20, 230], [230, 230, 20], [20, 230, 230], [230, 20, 230]])


def _cube_points(per_face: int = 40) -> tuple[np.ndarray, np.ndarray]:
    """Points on a 10 cm cube's six faces (a grid on each) with each face's own linear color."""
    g = np.linspace(-0.05, 0.05, per_face)
    a, b = (v.ravel() for v in np.meshgrid(g, g))
    points, colors = [], []
    for k, (axis, side) in enumerate((ax, s) for ax in range(3) for s in (-0.05, 0.05)):
        p = np.zeros((len(a), 3))
        p[:, axis] = side
        p[:, [i for i in range(3) if i != axis]] = np.column_stack([a, b])
        points.append(p)
        colors.append(np.tile(srgb8_to_linear(FACE_COLORS[k].astype(np.uint8)[None]), (len(a), 1)))
    return np.concatenate(points), np.concatenate(colors)


def _cube_mesh() -> trimesh.Trimesh:
    return trimesh.creation.box(extents=(0.1, 0.1, 0.1)).subdivide().subdivide()


def test_texels_take_the_color_of_their_face():
    mesh = _cube_mesh()
    points, colors = _cube_points()
    verts, faces, uv, _, tex = texture.bake_texture(mesh.vertices, mesh.faces, points, colors, 256)
    size = tex.shape[0]
    tri = verts[faces]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    centroid_uv = uv[faces].mean(axis=1)
    col = np.round(centroid_uv[:, 0] * (size - 1)).astype(int)
    row = np.round((size - 1) - centroid_uv[:, 1] * (size - 1)).astype(int)
    got = tex[row, col].astype(int)
    for k, (axis, sign) in enumerate((ax, s) for ax in range(3) for s in (-1, 1)):
        on_face = sign * normal[:, axis] > 0.99
        assert on_face.sum() >= 8
        assert np.abs(got[on_face] - FACE_COLORS[k]).max() <= 2, k


def test_chunked_bake_equals_one_go(monkeypatch):
    mesh = _cube_mesh()
    points, colors = _cube_points()

    def frames_see_the_upper_half(xyz, normals):
        seen = xyz[:, 2] > 0.0
        return np.column_stack([0.5 + 4 * xyz[:, 0], 0.5 + 4 * xyz[:, 1], 0.2 + 0 * xyz[:, 2]]) * seen[:, None], seen

    whole = texture.bake_texture(mesh.vertices, mesh.faces, points, colors, 256, frames_see_the_upper_half)
    monkeypatch.setattr(texture, "TEXEL_CHUNK", 997)
    chunked = texture.bake_texture(mesh.vertices, mesh.faces, points, colors, 256, frames_see_the_upper_half)
    assert (whole[4] > 0).any()
    for a, b in zip(whole, chunked):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("k", [3, 5])
def test_transfer_colors_with_a_built_tree_is_the_same(k):
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(0)
    points, colors, queries = rng.random((500, 3)), rng.random((500, 3)), rng.random((50, 3))
    np.testing.assert_array_equal(
        texture.transfer_colors(queries, points, colors, k),
        texture.transfer_colors(queries, points, colors, k, tree=cKDTree(points)),
    )
