"""Silhouettes are the pixels whose centers the shape covers: no pixel more, none less, so a
shape fitted to a mask is not shrunk by the rasterizer's edge rule (cv2.fillConvexPoly also takes
the pixels its edges pass through: half a pixel on every side)."""

from __future__ import annotations

import numpy as np
import pytest

from rose_usd.core import se3
from rose_usd.core.pinhole import silhouette
from rose_usd.core.raster import fill_convex, fill_triangles


def centers_inside(polygon: np.ndarray, width: int, height: int) -> np.ndarray:
    """The brute-force answer: every pixel center tested against each edge of a convex polygon."""
    ys, xs = np.mgrid[0:height, 0:width]
    p = np.stack([xs, ys], axis=-1).astype(float)
    a, b = polygon, np.roll(polygon, -1, axis=0)
    cross = (b[:, 0] - a[:, 0]) * (p[..., None, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (p[..., None, 0] - a[:, 0])
    return np.all(cross >= -1e-9, axis=-1) | np.all(cross <= 1e-9, axis=-1)


def random_convex(rng, n: int, center, radius: float) -> np.ndarray:
    from scipy.spatial import ConvexHull

    pts = np.asarray(center) + rng.uniform(-radius, radius, (n, 2))
    return pts[ConvexHull(pts).vertices]


@pytest.mark.parametrize("seed", range(6))
def test_convex_fill_is_the_centers_inside(seed):
    rng = np.random.default_rng(seed)
    poly = random_convex(rng, rng.integers(3, 12), rng.uniform(10, 50, 2), rng.uniform(2, 25))
    got = fill_convex(poly, 64, 48)
    assert np.array_equal(got, centers_inside(poly, 64, 48))


def test_convex_fill_clips_to_the_image():
    poly = np.array([[-20.3, -5.2], [70.4, 10.1], [30.0, 90.6]])
    assert np.array_equal(fill_convex(poly, 64, 48), centers_inside(poly, 64, 48))
    assert not fill_convex(np.array([[-9.0, -9.0], [-2.0, -9.0], [-5.0, -1.0]]), 64, 48).any()


def test_square_area_is_its_size():
    """A 10 px square at any offset and angle covers 100 pixel centers on average, not 121."""
    rng = np.random.default_rng(0)
    areas = []
    for _ in range(200):
        th = rng.uniform(0, np.pi / 2)
        corners = np.array([[-5, -5], [5, -5], [5, 5], [-5, 5]], float) @ np.array(
            [[np.cos(th), np.sin(th)], [-np.sin(th), np.cos(th)]]
        )
        areas.append(fill_convex(corners + rng.uniform(20, 21, 2), 48, 48).sum())
    assert abs(np.mean(areas) - 100.0) < 1.5


def test_triangles_fill_is_their_union():
    rng = np.random.default_rng(3)
    pts = rng.uniform(-5, 70, (30, 2))
    tri = rng.integers(0, 30, (25, 3))
    want = np.zeros((48, 64), bool)
    for t in tri:
        want |= centers_inside(pts[t], 64, 48)
    assert np.array_equal(fill_triangles(pts, tri, 64, 48), want)


def test_mesh_silhouette_matches_its_centers():
    """A box seen by a camera: the silhouette's pixels are those whose rays hit the box."""
    import trimesh

    box = trimesh.creation.box(extents=(0.1, 0.08, 0.06))
    K = np.array([[120.0, 0, 40.3], [0, 120.0, 29.7], [0, 0, 1]])
    rot = se3.rotation_about(np.array([1.0, 1.0, 0.2]), 0.4)
    world_from_cv = se3.make_pose(rot, -rot @ np.array([0.01, -0.02, 0.5]))  # the box 0.5 m ahead
    sil = silhouette(box.vertices, box.faces, world_from_cv, K, 80, 60, closed=True)
    ys, xs = np.mgrid[0:60, 0:80]
    rays = np.stack([(xs - K[0, 2]) / K[0, 0], (ys - K[1, 2]) / K[1, 1], np.ones_like(xs, float)], axis=-1)
    dirs = rays.reshape(-1, 3) @ world_from_cv[:3, :3].T
    origins = np.broadcast_to(world_from_cv[:3, 3], dirs.shape)
    hit = box.ray.intersects_any(origins, dirs).reshape(60, 80)
    assert hit.sum() > 300
    assert np.sum(sil != hit) <= 2  # rays grazing an edge


@pytest.mark.parametrize("soft", [False, True])
def test_convex_iou_from_row_spans_is_the_drawn_one(soft):
    """The fits' IoU of a convex shape, counted from its row spans, equals the one counted on its
    drawn silhouette, with ignored pixels and a soft mask."""
    import trimesh

    from rose_usd.geometry.silhouette import View, iou

    rng = np.random.default_rng(1)
    box = trimesh.creation.box(extents=(0.1, 0.07, 0.05))
    K = np.array([[150.0, 0, 50.2], [0, 150.0, 39.6], [0, 0, 1]])
    rot = se3.rotation_about(np.array([0.3, 1.0, 0.1]), 0.5)
    cam = se3.make_pose(rot, -rot @ np.array([0.0, 0.0, 0.6]))
    mask = fill_convex(np.array([[30.3, 20.1], [70.8, 25.2], [66.1, 60.7], [28.4, 55.5]]), 100, 80)
    view = View(mask, rng.random((80, 100)) < 0.1, K, cam, soft=rng.random((80, 100)) if soft else None)
    for shift in ([0, 0, 0], [0.02, -0.01, 0.0], [0.3, 0.0, 0.0]):
        v = box.vertices + shift
        drawn = view.render(v, box.faces, convex=True)
        keep = ~view.ignore
        if soft:
            s = np.where(keep, view.soft, 0.0)
            inter = s[drawn & keep].sum()
            want = inter / ((drawn & keep).sum() + s.sum() - inter)
        else:
            want = (drawn & mask & keep).sum() / ((drawn | mask) & keep).sum()
        assert iou([view], v, box.faces, convex=True) == pytest.approx(want, abs=1e-12)


@pytest.mark.parametrize("closed", [True, False])
def test_a_mesh_drawn_in_one_kernel_is_the_mesh_projected_first(closed):
    """``fill_mesh`` projects and culls in its kernel: the same pixels as projecting the camera
    points in NumPy, leaving out the triangles with a corner too near and (closed) those facing
    away, and filling the rest, in a window too."""
    import trimesh

    from rose_usd.core.pinhole import project
    from rose_usd.core.raster import fill_mesh

    rng = np.random.default_rng(5)
    K = np.array([[210.0, 0, 61.7], [0, 205.0, 44.2], [0, 0, 1]])
    drawn = 0
    for trial in range(20):
        mesh = trimesh.creation.icosphere(subdivisions=2, radius=rng.uniform(0.03, 0.1))
        faces = mesh.faces[mesh.triangles_center @ rng.normal(size=3) > -0.02]  # open: a cap, its inside seen
        cam = mesh.vertices + np.array([*rng.uniform(-0.05, 0.05, 2), rng.uniform(0.02, 0.4)])
        if trial % 2:
            cam = cam + rng.normal(0, 0.004, cam.shape)  # a bumpy one
        x0, y0 = (int(rng.integers(0, 20)), int(rng.integers(0, 15))) if trial % 3 else (0, 0)
        u, v = project(np.where(cam[:, 2:3] > 0.05, cam, 1.0), K)
        tri = faces[np.all(cam[faces, 2] > 0.05, axis=1)]
        if closed:
            a, b, c = cam[tri[:, 0]], cam[tri[:, 1]], cam[tri[:, 2]]
            tri = tri[np.einsum("ij,ij->i", np.cross(b - a, c - a), a) < 0.0]
        want = fill_triangles(np.column_stack([u - x0, v - y0]), tri, 100 - x0, 80 - y0)
        got = fill_mesh(cam, faces, K, 100 - x0, 80 - y0, min_z=0.05, closed=closed, origin=(x0, y0))
        assert np.array_equal(got, want), trial
        drawn += int(want.any())
    assert drawn >= 15
    assert not fill_mesh(cam, faces, K, 100, 80, min_z=5.0, closed=closed).any()
