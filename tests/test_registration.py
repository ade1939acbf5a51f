"""Depth-to-colour registration of a static camera's video (geometry.registration)."""

import cv2
import numpy as np
import pytest

from rose_usd.geometry.registration import find_depth_shift, shift_depth


def _video(n=24, h=120, w=160, seed=0):
    """A textured static scene at 1 m with a grey hand-sized block moving over it (0.6 m)."""
    rng = np.random.default_rng(seed)
    background = rng.integers(0, 256, (h, w, 3)).astype(np.uint8)
    frames, depths = [], []
    for t in range(n):
        rgb, depth = background.copy(), np.full((h, w), 1.0, np.float32)
        x = 10 + int(110 * t / (n - 1))
        y = 30 + int(20 * np.sin(t / 3.0))
        rgb[y : y + 40, x : x + 30] = (200, 160, 140)
        depth[y : y + 40, x : x + 30] = 0.6
        frames.append(rgb)
        depths.append(depth)
    return frames, depths


@pytest.mark.parametrize("dx,dy", [(-20, 4), (7, -11)])
def test_a_shifted_depth_is_found(dx, dy):
    rgb, depth = _video()
    moved = [shift_depth(d, dx, dy) for d in depth]
    found = find_depth_shift(lambda t: rgb[t], lambda t: moved[t], len(rgb), max_px=25)
    assert (found.dx, found.dy) == (-dx, -dy) and found.applies
    assert found.overlap > 0.9 and found.overlap_unshifted < 0.5


def test_registered_depth_is_left_alone():
    rgb, depth = _video()
    found = find_depth_shift(lambda t: rgb[t], lambda t: depth[t], len(rgb))
    assert (found.dx, found.dy) == (0, 0) and not found.applies


def test_shift_depth_moves_pixels_and_leaves_no_depth_behind():
    depth = np.arange(1, 13, dtype=np.float32).reshape(3, 4)
    out = shift_depth(depth, 1, -1)
    np.testing.assert_array_equal(out, [[0, 5, 6, 7], [0, 9, 10, 11], [0, 0, 0, 0]])


def test_a_static_camera_is_told_from_a_moving_one():
    """Corners of the first frame stay put on a static camera (a block moving over part of the
    view does not change that) and move on a panning one."""
    from rose_usd.capture.static import still_fraction

    rgb, _ = _video(h=240, w=320)
    smooth = [cv2.GaussianBlur(f, (0, 0), 1.5) for f in rgb]  # corners LK can follow
    panned = [np.roll(smooth[0], 2 * t, axis=1) for t in range(len(smooth))]
    assert still_fraction(lambda t: smooth[t], len(smooth)) > 0.6
    assert still_fraction(lambda t: panned[t], len(panned)) < 0.05
