"""The box prompt's GrabCut: the same mask whatever drew from OpenCV's random generator before."""

from pathlib import Path

import cv2
import numpy as np
import pytest
from conftest import can_on_box

from rose_usd.capture.scale import prompt_silhouette
from rose_usd.core.grabcut import _bounds, _box_iou, box_grabcut, split_shared

MARKER = Path(__file__).resolve().parents[2] / "shared" / "data" / "real" / "openreal2sim-marker-rgb" / "rgb"
MARKER_BOX = (700, 232, 990, 602)
"""The rightmost pen of the clip's first frame (1280x720)."""


def _first_frame(video: Path) -> np.ndarray:
    capture = cv2.VideoCapture(str(video))
    ok, bgr = capture.read()
    capture.release()
    assert ok
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


@pytest.mark.skipif(not MARKER.is_dir(), reason="../shared/data/real/openreal2sim-marker-rgb is not present")
def test_pen_mask_does_not_depend_on_the_random_state():
    """A pen of a clear body and a black cap on a wooden desk: one GrabCut run takes the whole pen
    or only its body by the k-means draw (2 of the first 4 global seeds took the body: 5496 of
    13180 px); the seeded runs kept by how they fill the box take the whole pen every time."""
    rgb = _first_frame(MARKER / "demo_video.mp4")
    masks = []
    for seed in range(6):
        cv2.setRNGSeed(seed)
        masks.append(prompt_silhouette(rgb, MARKER_BOX))
    for mask in masks[1:]:
        assert np.array_equal(mask, masks[0])
    assert _box_iou(_bounds(masks[0]), MARKER_BOX) > 0.9
    assert masks[0].sum() > 12000


def test_box_grabcut_takes_the_object_in_the_box():
    """A two-tone bar on a noisy background, its box drawn tightly: the mask is the bar's."""
    rng = np.random.default_rng(3)
    rgb = rng.integers(150, 200, (240, 320, 3)).astype(np.uint8)
    rgb[100:140, 60:160] = (30, 30, 30)
    rgb[100:140, 160:260] = (200, 40, 40)
    mask = box_grabcut(rgb, (55, 95, 265, 145))
    truth = np.zeros(mask.shape, bool)
    truth[100:140, 60:260] = True
    assert (mask & truth).sum() / (mask | truth).sum() > 0.95
    assert not box_grabcut(np.zeros((40, 40, 3), np.uint8), (5, 5, 35, 35)).any()


def test_overlapping_prompts_share_no_pixel():
    """GrabCut in the box's prompt takes the can's lower half too; split among the prompts of the
    frame, the shared patch goes to the can, whose box it fills: both masks near the truth."""
    rgb, prompts, truth = can_on_box()
    alone = {name: box_grabcut(rgb, b) for name, b in prompts.items()}
    assert (alone["Box"] & truth["Can"]).sum() > 0.3 * truth["Can"][140:160].sum()  # the case this is for
    split = split_shared(alone, prompts)
    assert not (split["Box"] & split["Can"]).any()
    for name, mask in split.items():
        assert (mask & truth[name]).sum() / (mask | truth[name]).sum() > 0.95, name
