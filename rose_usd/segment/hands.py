"""Hands found by MediaPipe's models (``geometry.hands``) for the segment backends: every frame's
hands, and the colors of their skin."""

from __future__ import annotations

import functools

import cv2
import numpy as np

from rose_usd.errors import EnvironmentProblem
from rose_usd.geometry.hands import Hand, HandDetector, bridge_gaps, hand_mask
from rose_usd.progress import progress
from rose_usd.segment.colors import SHADES, color_index, histogram
from rose_usd.segment.regions import grown, touching
from rose_usd.segment.segmenter import MIN_REGION_PX
from rose_usd.stage_api import StageContext

SKIN_RATIO = 1.0
"""A pixel is an object's rather than a hand's only where the object's color model is this many
times likelier than the hands' skin (``skin_histogram``): inside a found hand's landmark mask
(``segment.flow``), and where a hidden track is looked for again (``segment.refind``: without it,
a pen's gray and a cup's red took the hand holding them, openreal2sim-marker-rgb and sam2-cups)."""


ARM_SKIN = 2.0
"""The forearm (``skin_arm``) is the pixels the hands' skin model claims this many times over the
rest of the frame's colors, in regions that come within 0.3 hand sizes of a found hand."""


def skin_arm(rgb: np.ndarray, hands: list[Hand], skin: np.ndarray) -> np.ndarray:
    """The bare arm of the found ``hands`` in ``rgb`` (bool, the hands' landmark masks left out):
    the regions ``skin`` claims (``ARM_SKIN``; specks and wood-grain stripes opened away, the
    highlights between them closed) that come within 0.3 hand sizes of a hand, so that a watch or a
    sleeve's edge at the wrist does not cut the forearm off. A sleeve is not skin: it is not found."""
    hand = hand_mask(hands, rgb.shape[:2])
    if not hand.any():
        return np.zeros_like(hand)
    idx = color_index(rgb)
    rest = histogram(idx[~hand])
    size = max(_extent(hand_mask([h], hand.shape)) for h in hands)

    def radius(diameter: float) -> int:
        return max(1, int(round(diameter / 2)))

    def disk(diameter: float) -> np.ndarray:
        r = radius(diameter)
        return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))

    claimed = (skin[idx] > ARM_SKIN * rest[idx]).astype(np.uint8)
    claimed = cv2.morphologyEx(claimed, cv2.MORPH_OPEN, disk(0.03 * size))
    claimed = cv2.morphologyEx(claimed, cv2.MORPH_CLOSE, disk(0.1 * size)).astype(bool)
    near = grown(hand, radius(0.6 * size))  # a dilation by disk(0.6 * size), within the hand's box
    return touching(claimed | hand, near, grow_px=1) & ~hand


def _extent(mask: np.ndarray) -> float:
    """The diagonal of ``mask``'s bounding box [px], 0 when it is empty."""
    ys, xs = np.nonzero(mask)
    return float(np.hypot(np.ptp(ys), np.ptp(xs))) if len(ys) else 0.0


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


class BareArms:
    """The bare arm of each frame's found hands (``segment.hands.skin_arm``)."""

    def __init__(self, frame_of, found: list[list[Hand]] | None, skin: np.ndarray | None, shape: tuple[int, int]):
        """``skin``: the found hands' skin (``skin_histogram``); the arm's is that seen at each of
        ``SHADES`` (its underside, turned from the light, is darker than the hand's back)."""
        self.frame_of, self.found, self.shape, self._skin = frame_of, found, shape, skin

    @functools.cached_property
    def skin(self) -> np.ndarray | None:
        """The arm's skin model, made when first asked (a moving camera never asks)."""
        if self._skin is None or not self.found:
            return None
        shaded = [
            skin_histogram(lambda t, f=f: (self.frame_of(t) * f).astype(np.uint8), self.found) for f in SHADES[1:]
        ]
        return np.mean([self._skin] + [h for h in shaded if h is not None], axis=0)

    def __call__(self, t: int) -> np.ndarray | None:
        """Frame t's bare arms, None without a found hand or a skin model."""
        if not self.found or not self.found[t] or self.skin is None:
            return None
        return skin_arm(self.frame_of(t), self.found[t], self.skin)

    def cover(self, t: int) -> np.ndarray | None:
        """What frame t's found hands and their bare arms cover, None without a found hand."""
        if not self.found or not self.found[t]:
            return None
        hand = hand_mask(self.found[t], self.shape)
        bare = self(t)
        return hand if bare is None else hand | bare
