"""Hands found by MediaPipe's models (``geometry.hands``) for the segment backends: every frame's
hands, and the colors of their skin."""

from __future__ import annotations

import cv2
import numpy as np

from rose_usd.errors import EnvironmentProblem
from rose_usd.geometry.hands import Hand, HandDetector, bridge_gaps, hand_mask
from rose_usd.progress import progress
from rose_usd.segment.colors import color_index, histogram
from rose_usd.segment.segmenter import MIN_REGION_PX
from rose_usd.stage_api import StageContext

SKIN_RATIO = 1.0
"""A pixel is an object's rather than a hand's only where the object's color model is this many
times likelier than the hands' skin (``skin_histogram``): inside a found hand's landmark mask
(``segment.flow``), and where a hidden track is looked for again (``segment.refind``: without it,
a pen's gray and a cup's red took the hand holding them, openreal2sim-marker-rgb and sam2-cups)."""


def found_hands(ctx: StageContext, rgb_of) -> list[list[Hand]] | None:
    """The hands in every frame ``rgb_of(t)`` shows (a forward pass: the detector tracks them from
    frame to frame; short losses bridged; landmarks in that image's pixels), None with a warning
    when the hand models are not installed."""
    try:
        detector = HandDetector(ctx.case.fps)
    except EnvironmentProblem as exc:
        ctx.warn(f"hands are not detected ({exc.message}); the interactor is what differs from the static world")
        return None
    with detector:
        n = ctx.time_info.n_frames
        found = [detector.detect(rgb_of(t), t) for t in progress(range(n), "segment: hands", total=n)]
    return bridge_gaps(found)


def skin_histogram(rgb_of, found: list[list[Hand]], *, frames: int = 40) -> np.ndarray | None:
    """The color histogram of the found hands' skin: their landmark masks drawn thin and eroded
    (so little of what they hold or lie on is taken), over up to ``frames`` frames with hands."""
    with_hands = [t for t, hands in enumerate(found) if hands]
    if not with_hands:
        return None
    picked = with_hands[:: max(1, len(with_hands) // frames)]
    kernel = np.ones((3, 3), np.uint8)
    parts = []
    for t in picked:
        rgb = rgb_of(t)
        thin = hand_mask(found[t], rgb.shape[:2], finger_width=0.15).astype(np.uint8)
        parts.append(color_index(rgb)[cv2.erode(thin, kernel) > 0])
    idx = np.concatenate(parts)
    return histogram(idx) if len(idx) >= MIN_REGION_PX else None
