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


def _blocks(h=240, w=320, seed=1):
    """A cluttered view: textured blocks at 0.5-0.9 m in front of a textured wall at 1.5 m, each
    block's colour its own (its silhouette is a colour edge as well as a depth one)."""
    rng = np.random.default_rng(seed)
    rgb = cv2.GaussianBlur(rng.integers(60, 200, (h, w, 3)).astype(np.uint8), (0, 0), 2.0)
    depth = np.full((h, w), 1.5, np.float32)
    for _ in range(7):
        y, x = int(rng.integers(10, h - 70)), int(rng.integers(10, w - 70))
        bh, bw = int(rng.integers(25, 60)), int(rng.integers(25, 60))
        rgb[y : y + bh, x : x + bw] = rng.integers(0, 256, 3)
        depth[y : y + bh, x : x + bw] = rng.uniform(0.5, 0.9)
    return rgb, depth


def test_depth_registered_to_colour_is_told_by_its_edges():
    """A depth map whose silhouettes lie on the colour's edges is registered; shifted by 6 px
    (a depth camera's calibration error) it is not, and the offset that puts it back is found."""
    from rose_usd.geometry.registration import edge_alignment

    views = [_blocks(seed=s) for s in range(4)]
    rgb_of = lambda t: views[t][0]  # noqa: E731
    aligned = edge_alignment(rgb_of, lambda t: views[t][1], range(4))
    assert aligned.registered and (aligned.dx, aligned.dy) == (0, 0)
    assert aligned.at_zero_px < 0.5 * aligned.typical_px
    off = edge_alignment(rgb_of, lambda t: shift_depth(views[t][1], 6, -2), range(4))
    assert not off.registered and (off.dx, off.dy) == (-6, 2)


def test_without_depth_silhouettes_nothing_is_claimed_registered():
    """A flat wall has no depth edges to check colour against: not registered (so nothing relies on it)."""
    from rose_usd.geometry.registration import edge_alignment

    rgb, _ = _blocks()
    flat = edge_alignment(lambda t: rgb, lambda t: np.full(rgb.shape[:2], 1.0, np.float32), range(3))
    assert not flat.registered and flat.frames == 0


@pytest.mark.parametrize("shift", [True, False])
def test_the_capture_says_it_shifts_depth_and_can_be_told_not_to(tmp_path, shift):
    """A user read "depth is shifted by (-20, 4) px" as a complaint, not as what rose did, and found
    no setting to keep a depth/ they knew was registered: `capture.rgbd.depth_shift = false`."""
    import rose_usd
    from rose_usd.usd.stage import layer_file, read_provenance

    rgb, depth = _video(n=30, h=240, w=320)
    # the background as a table 0.6 m below a camera pitched 45 deg down (a wall has no support)
    v = (np.arange(240, dtype=np.float32)[:, None] - 119.5) / 300.0
    table = np.broadcast_to(0.6 / (np.cos(np.pi / 4) * v + np.sin(np.pi / 4)), (240, 320))
    depth = [np.where(d == 1.0, table, 0.5).astype(np.float32) for d in depth]
    case = tmp_path / "case"
    for name in ("rgb", "depth"):
        (case / name).mkdir(parents=True)
    for t, (image, d) in enumerate(zip(rgb, depth)):
        cv2.imwrite(str(case / "rgb" / f"{t:06d}.png"), image)
        cv2.imwrite(str(case / "depth" / f"{t:06d}.png"), (shift_depth(d, -20, 4) * 1000).astype(np.uint16))
    (case / "cam_K.txt").write_text("300 0 159.5\n0 300 119.5\n0 0 1\n")
    (case / "rose.toml").write_text("objects = []\n")
    settings = {"capture": {"rgbd": {"depth_shift": shift}}}
    rose_usd.reconstruct(case, tmp_path / "out", until="capture", settings=settings)
    from rose_usd.layers.world import depth_shift_px
    from rose_usd.usd.stage import open_stage

    assert depth_shift_px(open_stage(tmp_path / "out" / "rose.usda")) == ((20, -4) if shift else (0, 0))
    prov = read_provenance(layer_file(tmp_path / "out", "world"))
    said = [w for w in prov.get("warnings", []) if "does not line up with rgb/" in w]
    assert bool(said) is shift
    if shift:
        assert "every stage reads the depth shifted by (20, -4) px" in said[0] and "depth_shift=false" in said[0]
