"""The frames' median colour at surface points (the scene texture's Warp kernel), on a camera
looking straight down at the plane z = 0 from 1 m, where every answer is known."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from rose_usd.geometry.frame_median import FrameMedian, FrameStack

W, H = 64, 48
K = np.array([[100.0, 0.0, 32.0], [0.0, 100.0, 24.0], [0.0, 0.0, 1.0]])
# OpenCV camera axes in the world: x right, y down (world -y), z forward (world -z), at 1 m height
DOWN = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 0.0], [0.0, 0.0, -1.0, 1.0], [0.0, 0.0, 0.0, 1.0]])
UP = np.array([0.0, 0.0, 1.0])


def _stack(values, *, static=None, depth=None, gradient=False) -> FrameStack:
    """One frame per value: a constant colour (or, with ``gradient``, red = u / W and green = v / H
    plus the value in blue), depth 1 m everywhere unless given, every pixel static unless given."""
    n = len(values)
    rgb = np.zeros((n, H, W, 3), np.float32)
    v, u = np.mgrid[0:H, 0:W]
    for k, value in enumerate(values):
        rgb[k] = value
        if gradient:
            rgb[k, ..., 0], rgb[k, ..., 1] = u / W, v / H
    return FrameStack(
        world_from_cv=np.repeat(DOWN[None], n, axis=0),
        K=np.repeat(K[None], n, axis=0),
        depth=np.ones((n, H, W), np.float32) if depth is None else np.asarray(depth, np.float32),
        static=np.ones((n, H, W), bool) if static is None else np.asarray(static, bool),
        rgb=rgb,
    )


def _median(stack: FrameStack, points, normals, **kw):
    limits = {"tol_m": 0.01, "rel_tol": 0.02, "min_cos": 0.15, "min_z": 0.05} | kw
    return FrameMedian(stack, **limits, device="cpu")(np.asarray(points, float), np.asarray(normals, float))


def test_the_median_over_the_frames_that_see_a_point_odd_and_even_counts():
    colors, seen = _median(_stack([0.1, 0.5, 0.3]), [[0.0, 0.0, 0.0]], [UP])
    assert seen.tolist() == [True] and np.allclose(colors, 0.3)
    colors, seen = _median(_stack([0.1, 0.5, 0.3, 0.7]), [[0.0, 0.0, 0.0]], [UP])
    assert np.allclose(colors, (0.3 + 0.5) / 2)  # the two middle values averaged, as np.nanmedian


def test_a_frame_whose_pixel_moves_or_whose_depth_is_nearer_is_left_out():
    static = np.ones((5, H, W), bool)
    static[3, 24, 32] = False  # a hand over the point in frame 3
    depth = np.ones((5, H, W))
    depth[4, 24, 32] = 0.5  # something 50 cm nearer than the point in frame 4
    colors, seen = _median(_stack([0.1, 0.5, 0.3, 0.9, 0.0], static=static, depth=depth), [[0.0, 0.0, 0.0]], [UP])
    assert seen.tolist() == [True] and np.allclose(colors, 0.3)
    # within tol_m + 2 % of the depth the frame still sees it: 1.025 m against 1 m is 2.5 cm < 3 cm
    depth[4, 24, 32] = 1.025
    colors, _ = _median(_stack([0.1, 0.5, 0.3, 0.9, 0.0], static=static, depth=depth), [[0.0, 0.0, 0.0]], [UP])
    assert np.allclose(colors, (0.1 + 0.3) / 2)


def test_points_no_frame_sees_are_unseen():
    stack = _stack([0.2, 0.4])
    points = [[0.0, 0.0, 0.0], [0.0, 0.0, 2.0], [5.0, 0.0, 0.0], [0.0, 0.0, 0.97]]
    normals = [-UP, UP, UP, UP]  # facing away; behind the camera; outside the image; nearer than min_z
    colors, seen = _median(stack, points, normals)
    assert seen.tolist() == [False, False, False, False] and not colors.any()


def test_the_colour_is_sampled_bilinearly_where_the_point_projects():
    # 2.5 mm right of the axis at 1 m with f = 100 px: u = 32.25, v = 24 (the nearest pixel 32, 24)
    colors, seen = _median(_stack([0.5], gradient=True), [[0.0025, 0.0, 0.0]], [UP])
    assert seen.all() and np.allclose(colors[0], [32.25 / W, 24 / H, 0.5], atol=1e-6)


@pytest.mark.parametrize("chunk", [1, 7, 1000])
def test_the_split_into_chunks_and_threads_does_not_change_a_bit(chunk):
    rng = np.random.default_rng(0)
    points = np.column_stack([rng.uniform(-0.3, 0.3, (200, 2)), np.zeros(200)])
    stack = _stack(rng.uniform(0, 1, 9), gradient=True)
    limits = {"tol_m": 0.01, "rel_tol": 0.02, "min_cos": 0.15, "min_z": 0.05}
    whole = FrameMedian(stack, **limits, chunk=10_000, device="cpu")(points, np.tile(UP, (200, 1)))
    split = FrameMedian(stack, **limits, chunk=chunk, device="cpu")(points, np.tile(UP, (200, 1)))
    assert whole[1].sum() > 100 and np.array_equal(whole[0], split[0]) and np.array_equal(whole[1], split[1])


def test_the_median_of_taken_samples_is_numpys_nanmedian_bit_for_bit():
    from rose_usd.geometry.frame_median import median_over_frames

    rng = np.random.default_rng(1)
    for frames in (1, 2, 5, 48):
        samples = rng.integers(0, 256, (frames, 3000, 3), dtype=np.uint8)
        seen = rng.uniform(size=(frames, 3000)) < 0.6
        median, count = median_over_frames(samples, seen, chunk=700, device="cpu")
        assert np.array_equal(count, seen.sum(axis=0))
        some = count > 0
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN columns: the unseen texels
            ref = np.nanmedian(np.where(seen[..., None], samples.astype(np.float32), np.nan), axis=0)
        assert np.array_equal(median[some], ref[some]) and not median[~some].any()
