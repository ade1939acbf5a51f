"""The depth segmenter's start regions: pieces of one object that a depth edge cut apart are
joined when they leave their place together; a neighbour that stays is not."""

from __future__ import annotations

import numpy as np

from rose_usd.core import se3
from rose_usd.segment.config import SegmentConfig
from rose_usd.segment.segmenter import Segmenter, components
from rose_usd.usd.camera import CameraTrack

W, H, N = 160, 120, 40
K = np.array([[150.0, 0.0, 80.0], [0.0, 150.0, 60.0], [0.0, 0.0, 1.0]])


def _clip():
    """A static camera 0.6 m above a table (depth 0.6) looking straight down. A cup lying on its
    side shows as two pieces, its outer wall (depth 0.53) and, past a depth edge, its inner wall
    (0.59, 1 cm over the table); a spoon beside it (0.58) never moves. The cup is lifted away in
    frames 20-27."""
    pieces = {"outer": (slice(40, 55), slice(60, 90), 0.53), "inner": (slice(55, 65), slice(62, 88), 0.575)}
    spoon = (slice(40, 60), slice(100, 106), 0.58)

    def depth_of(t):
        d = np.full((H, W), 0.6, np.float32)
        if not 20 <= t < 28:
            for rows, cols, z in pieces.values():
                d[rows, cols] = z
        d[spoon[0], spoon[1]] = spoon[2]
        return d

    cams = CameraTrack(
        np.repeat(se3.look_at((0.0, 0.0, 0.6), (0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0))[None], N, 0),
        np.repeat(K[None], N, 0),
        W,
        H,
    )
    return depth_of, cams, pieces, spoon


def test_pieces_of_one_object_that_leave_together_are_joined():
    depth_of, cams, pieces, spoon = _clip()
    seg = Segmenter(lambda t: np.zeros((H, W, 3), np.uint8), depth_of, cams, SegmentConfig(), background=None)
    d = depth_of(0)
    standing = (d < 0.595) & ~seg.frame(0).edges
    _, labels, _ = components(standing)
    label = {name: int(labels[rows, cols][2, 2]) for name, (rows, cols, _) in pieces.items()}
    spoon_label = int(labels[spoon[0], spoon[1]][5, 2])
    inner = labels == label["inner"]
    moved = seg.moved_when(inner, 0)
    assert moved.sum() >= 2 and not moved[0]
    joined = seg.join_moving_with(labels, inner, [label["outer"], spoon_label], 0)
    assert np.array_equal(joined, inner | (labels == label["outer"]))
    assert (
        seg.join_moving_with(labels, labels == spoon_label, [label["outer"]], 0).sum() == (labels == spoon_label).sum()
    )


def test_an_object_carried_with_another_later_is_not_joined():
    """A ball beside the cup is taken away at frame 8 and put back at 28; the cup leaves at 20:
    they were away together in frames 20-27 but did not start to move together."""
    depth_of, cams, pieces, _ = _clip()
    ball = (slice(70, 85), slice(20, 35), 0.55)

    def with_ball(t):
        d = depth_of(t)
        if not 8 <= t < 28:
            d[ball[0], ball[1]] = ball[2]
        return d

    seg = Segmenter(lambda t: np.zeros((H, W, 3), np.uint8), with_ball, cams, SegmentConfig(), background=None)
    standing = (with_ball(0) < 0.595) & ~seg.frame(0).edges
    _, labels, _ = components(standing)
    ball_label = int(labels[ball[0], ball[1]][5, 5])
    outer = int(labels[pieces["outer"][0], pieces["outer"][1]][2, 2])
    moved = seg.moved_when(labels == ball_label, 0)
    assert moved[[8, 20, 27]].all() and not moved[[0, 7, 28]].any()
    assert np.array_equal(seg.join_moving_with(labels, labels == ball_label, [outer], 0), labels == ball_label)


def test_unprompted_a_piece_that_moves_first_joins_what_the_hand_came_to():
    """No prompt: the hand comes to a standing mug's inner wall (seen over its rim, past a depth
    edge from the outer wall), which seems to leave its place only once a push has moved the mug
    far enough (frame 20), while the outer wall leaves at 12 (both back at 28). Led by that
    region, the outer wall joins it; without ``led`` (the two did not start together) it does
    not. A ball 8 cm away, away over frames 8-27, is not joined either way."""
    walls = {"outer": (slice(40, 55), slice(60, 90), 0.53), "inner": (slice(55, 65), slice(62, 88), 0.575)}
    ball = (slice(40, 55), slice(110, 125), 0.55)

    def depth_of(t):
        d = np.full((H, W), 0.6, np.float32)
        for name, (rows, cols, z) in walls.items():
            if not (12 if name == "outer" else 20) <= t < 28:
                d[rows, cols] = z
        if not 8 <= t < 28:
            d[ball[0], ball[1]] = ball[2]
        return d

    _, cams, _, _ = _clip()
    seg = Segmenter(lambda t: np.zeros((H, W, 3), np.uint8), depth_of, cams, SegmentConfig(), background=None)
    _, labels, _ = components((depth_of(0) < 0.595) & ~seg.frame(0).edges)
    outer, inner = (int(labels[rows, cols][2, 2]) for rows, cols, _ in walls.values())
    ball_label = int(labels[ball[0], ball[1]][5, 5])
    region = labels == inner
    assert np.array_equal(seg.join_moving_with(labels, region, [outer, ball_label], 0), region)
    joined = seg.join_moving_with(labels, region, [outer, ball_label], 0, led=True)
    assert np.array_equal(joined, region | (labels == outer))


def test_frames_and_foregrounds_made_ahead_are_the_ones_made_in_place():
    """``foregrounds_ahead`` and ``prefetch`` make on worker threads what ``foreground`` and
    ``frame`` would make themselves: the same arrays, whether a frame was made ahead, is still
    being made, or was never started (``close`` drops it)."""
    from rose_usd.geometry.background import StaticBackground

    depth_of, cams, _, _ = _clip()
    rgb_of = lambda t: np.full((H, W, 3), 3 * t, np.uint8)  # noqa: E731
    bg = StaticBackground(depth_of, cams.world_from_cv, cams.K, W, H)
    plain = Segmenter(rgb_of, depth_of, cams, SegmentConfig(), background=bg)
    ahead = Segmenter(rgb_of, depth_of, cams, SegmentConfig(), background=bg)
    try:
        ahead.foregrounds_ahead(list(range(N)))
        for t in range(N):
            ahead.prefetch(t + 1)
            for a, b in zip(ahead.foreground(t), plain.foreground(t)):
                assert a.dtype == bool and np.array_equal(a, b)
            for a, b in zip(ahead.frame(t), plain.frame(t)):
                assert np.array_equal(a, b, equal_nan=True)
    finally:
        ahead.close()
    assert np.array_equal(ahead.foreground(N - 1)[0], plain.foreground(N - 1)[0])


def test_nearest_points_are_scipys():
    from scipy.spatial import cKDTree

    from rose_usd.segment.motion import Nearest

    rng = np.random.default_rng(3)
    old, new = rng.normal(size=(3000, 3)) * 0.05, rng.normal(size=(2500, 3)) * 0.05
    d, i = Nearest(old).query(new)
    d_ref, i_ref = cKDTree(old).query(new)
    assert np.array_equal(i, i_ref) and np.allclose(d, d_ref, rtol=0, atol=1e-12)
