"""Plane-sweep stereo (geometry.stereo) and the scene backend built on it (scene.stereo): analytic
scenes whose depth is known."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from rose_usd.core import se3
from rose_usd.geometry.stereo import View, consistent, plane_depths, sweep

W, H = 160, 120
K = np.array([[150.0, 0.0, 79.5], [0.0, 150.0, 59.5], [0.0, 0.0, 1.0]])
TEXTURE = cv2.GaussianBlur(np.random.default_rng(0).uniform(0, 255, (900, 900)).astype(np.float32), (0, 0), 2.0)


def _render_plane(world_from_cv: np.ndarray, z_m: float) -> np.ndarray:
    """Gray image of a textured plane z = z_m (world = first camera's axes) seen from a camera."""
    u, v = np.meshgrid(np.arange(W, dtype=float), np.arange(H, dtype=float))
    rays = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], -1) @ world_from_cv[:3, :3].T
    c = world_from_cv[:3, 3]
    s = (z_m - c[2]) / rays[..., 2]
    x = c + s[..., None] * rays
    return cv2.remap(
        TEXTURE,
        (x[..., 0] * 400 + 450).astype(np.float32),
        (x[..., 1] * 400 + 450).astype(np.float32),
        cv2.INTER_LINEAR,
    )


def _camera(dx: float, dy: float = 0.0, turn_deg: float = 0.0) -> np.ndarray:
    return se3.make_pose(cv2.Rodrigues(np.radians([0.0, turn_deg, 0.0]))[0], np.array([dx, dy, 0.0]))


def _views(z_m: float, offsets=(-0.06, -0.03, 0.03, 0.06)) -> tuple[View, list[View]]:
    ref = View(_render_plane(np.eye(4), z_m), K, np.eye(4))
    sources = []
    for dx in offsets:
        pose = _camera(dx, 0.01, 1.5 * np.sign(dx))
        sources.append(View(_render_plane(pose, z_m), K, pose))
    return ref, sources


def test_the_sweep_finds_a_textured_plane_s_depth():
    """A textured plane 1.2 m in front of the reference, seen from four cameras 3-6 cm aside:
    nearly every pixel gets a depth, the median within 0.5 % of 1.2 m and 95 % within 2 %."""
    ref, sources = _views(1.2)
    depth, zncc = sweep(ref, sources, 0.5, 4.0)
    kept = depth > 0
    assert kept.mean() > 0.9
    assert np.median(depth[kept]) == pytest.approx(1.2, rel=0.005)
    assert np.mean(np.abs(depth[kept] - 1.2) < 0.024) > 0.95
    assert np.median(zncc[kept]) > 0.9


def test_moving_pixels_get_no_depth():
    """Pixels marked moving in the reference keep no depth; the others still do."""
    ref, sources = _views(1.2)
    moving = np.zeros((H, W), bool)
    moving[40:80, 60:100] = True
    depth, _ = sweep(View(ref.gray, ref.K, ref.world_from_cv, moving), sources, 0.5, 4.0)
    assert not depth[moving].any()
    assert (depth[~moving] > 0).mean() > 0.85


def test_planes_are_even_in_inverse_depth():
    """The swept depths run from near to far with even steps of 1 / depth."""
    d = plane_depths(0.5, 4.0, 8)
    assert d[0] == pytest.approx(0.5) and d[-1] == pytest.approx(4.0)
    assert np.allclose(np.diff(1.0 / d), np.diff(1.0 / d)[0])


def test_consistency_keeps_what_another_view_agrees_with():
    """A plane's depth map agrees with a second view's map of the same plane; a map 5 % too deep
    (a wrong match) does not, and without another view nothing is kept."""
    pose = _camera(0.05)
    view_a, view_b = View(np.zeros((H, W), np.float32), K, np.eye(4)), View(np.zeros((H, W), np.float32), K, pose)
    depth_a = np.full((H, W), 1.2, np.float32)
    depth_b = np.full((H, W), 1.2, np.float32)  # fronto-parallel plane, a camera moved sideways: same depth
    agree = consistent(depth_a, view_a, [(depth_b, view_b)], rel_tol=0.01)
    assert agree[:, 10:].all()  # what view b sees too (it stands 5 cm to the right)
    assert not consistent(depth_a * 1.05, view_a, [(depth_b, view_b)], rel_tol=0.01).any()
    assert not consistent(depth_a, view_a, []).any()


def test_sources_are_the_nearest_frames_with_enough_baseline():
    """A camera 1 m from the origin sliding 1 cm a frame: with 4.8 cm baselines the sources of
    frame 10 are frames 5 and 0 before it (5 and 10 cm) and 15 and 20 after; a camera that turns
    more than the limit ends the search there; a camera that does not move has none."""
    from rose_usd.scene.stereo import choose_sources

    slide = np.stack([se3.make_pose(np.eye(3), np.array([0.01 * (t - 10), 0.0, -1.0])) for t in range(30)])
    assert choose_sources(slide, 10, count=4, min_baseline=0.048, max_turn_deg=30.0) == [0, 5, 15, 20]
    turning = slide.copy()
    turning[12:, :3, :3] = cv2.Rodrigues(np.radians([0.0, 40.0, 0.0]))[0]
    assert choose_sources(turning, 10, count=4, min_baseline=0.048, max_turn_deg=30.0) == [0, 5]
    still = np.repeat(slide[10:11], 30, axis=0)
    assert choose_sources(still, 10, count=4, min_baseline=0.048, max_turn_deg=30.0) == []


def _looking_down(height_m: float, x_m: float = 0.0) -> np.ndarray:
    """A camera ``height_m`` above z = 0 at x, looking 45 deg down toward +y."""
    return se3.look_at(np.array([x_m, -height_m, height_m]), np.array([x_m, 0.0, 0.0]))


def test_the_support_ends_where_stereo_sees_past_it():
    """The plane backend's support reaches 1 m around the origin; a table ends at y = 0.2, beyond
    it stereo sees a floor 0.7 m lower: the cells past the edge are carved off, those before kept."""
    from rose_usd.scene.stereo import SupportGrid, plane_depth

    xs = np.linspace(-1.0, 1.0, 21)
    grid = SupportGrid(np.array([[x, y] for x in xs for y in xs]), 0.02)
    for x in (-0.05, 0.0, 0.05):
        view = View(np.zeros((H, W), np.float32), K, _looking_down(0.5, x))
        plane, xy = plane_depth(view, (H, W))
        depth = np.where(np.isfinite(plane), plane, 0.0)
        beyond = np.isfinite(plane) & (xy[..., 1] > 0.2)
        depth[beyond] *= 2.0  # the floor far below: much deeper than the table's plane
        grid.add(depth.astype(np.float32), view, 0.05)
    kept = grid.kept(np.zeros((1, 2)))
    seen = grid.on + grid.through >= 5  # cells well seen (the view's far rim has a pixel or two)
    table, carved = grid.centers(seen & kept), grid.centers(seen & ~kept)
    assert len(table) > 100 and len(carved) > 100
    assert carved[:, 1].min() > 0.2 - grid.cell
    # past the edge, but for the far corners of what the views see (closed again, CLOSE_CELLS)
    assert not ((table[:, 1] > 0.2 + grid.cell) & (table[:, 1] < 0.55) & (np.abs(table[:, 0]) < 0.5)).any()


def test_only_clusters_that_rise_stand_on_the_support():
    """A blob of 400 points 5 cm high stands (but for a few on its fringe); five stray points do
    not, nor does a sheet of 400 points 1.5 cm over the support (stereo's noise on a table)."""
    from rose_usd.scene.stereo import standing_clusters

    rng = np.random.default_rng(1)
    blob = rng.normal([0.0, 0.0, 0.05], 0.01, (400, 3))
    strays = rng.uniform(-0.5, 0.5, (5, 3)) + np.array([0.0, 0.0, 1.0])
    sheet = np.column_stack([rng.uniform(0.3, 0.5, (400, 2)), rng.uniform(0.012, 0.018, 400)])
    points = np.concatenate([blob, strays, sheet])
    keep = standing_clusters(points, points[:, 2] - 0.02, 0.02, 30, 0.01)
    assert keep[:400].mean() > 0.95 and not keep[400:].any()


@pytest.mark.parametrize("k, views", [(1, 4), (2, 4), (2, 2), (3, 5)])
def test_mean_of_smallest_is_the_mean_of_the_k_smallest(k, views):
    """The sweep's per-pixel cost over its best views: the mean of the k smallest values along
    the first axis, as sorting them gives (ties and a repeated 4.0, the 'not seen' cost, included)."""
    from rose_usd.geometry.stereo import _mean_of_smallest

    rng = np.random.default_rng(k + views)
    values = rng.uniform(0, 2, (views, 30, 40)).astype(np.float32)
    values[:, :5] = 4.0
    values[0, 10:12] = values[1, 10:12]
    want = np.sort(values, axis=0)[:k].mean(axis=0)
    got = _mean_of_smallest(values, k)
    assert got.dtype == np.float32 and got.shape == (30, 40)
    if k <= 2:
        assert np.array_equal(got, want)  # a sum of two is the same in either order
    else:
        np.testing.assert_allclose(got, want, rtol=1e-6)
