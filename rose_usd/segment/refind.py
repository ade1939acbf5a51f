"""Finding a hidden 2D track again (the ``flow`` backend, ``segment.flow``).

The flow over a hidden track is its occluder's: an arm that swept in front of realistic
push-box-static-s303's box dragged its shape off it, and the box, seen whole again beside the hand
two frames later, was not found for 39 frames (mask IoU 0.36 over the clip; 0.99 found again). A
track under half seen in the last frame is looked for where its shape covers the most pixels its
color model clearly claims, near where the flow put it.
"""

from __future__ import annotations

import cv2
import numpy as np

from rose_usd.segment.colors import histogram
from rose_usd.segment.hands import SKIN_RATIO

REACH = 2.0
"""A mostly hidden track is looked for within this many times its size (sqrt of its area) of its
moved shape."""

FILL = 0.5
"""Its shape goes where the pixels its color model clearly claims fill at least this share of it,
and ``GAIN`` times the share they fill where the flow put it..."""

GAIN = 1.5

LOOK = 0.3
"""...and where the colors under it hold this much of its color model (histogram intersection):
push-box-static-s303's box seen again beside the hand 0.58, the red arm that covered
unstack-can-s300's purple base 0.09."""

ALIKE = 0.5
"""A track is not looked for by its color while another track's color model overlaps its own by
this much (histogram intersection): sam2-cups' red cup and its two look-alikes 0.83-0.94 (a hidden
cup went to another cup), realistic unstack-can-s300's base and can 0.14."""


def find_hidden(
    tracks, moved: list[np.ndarray], idx: np.ndarray, bg: np.ndarray, skin: np.ndarray | None, blocked
) -> dict[int, np.ndarray]:
    """{track index: offset (dx, dy) [px] from its moved shape} for the ``tracks`` (``flow.Track2D``)
    under half seen in the last frame and unlike the others (``ALIKE``) whose colors are clearly
    seen again near ``moved`` (their shapes where the flow put them in this frame): off the other
    tracks' shapes and off ``blocked`` (the found hands and their arms, or None). ``idx``: the
    frame's color indices; ``bg``: the background's color model; ``skin``: the hands' (or None)."""
    found = {}
    for k, tr in enumerate(tracks):
        if tr.last_visible.sum() >= 0.5 * tr.typical_px or not moved[k].any():
            continue
        if any(np.minimum(o.fg, tr.fg).sum() >= ALIKE for o in tracks if o is not tr):
            continue  # another track looks the same: its color cannot tell them apart
        others = np.zeros_like(moved[k]) if blocked is None else blocked.copy()
        for j, m in enumerate(moved):
            if j != k:
                others |= m
        claim = tr.fg[idx] > 2.0 * bg[idx]
        if skin is not None:
            claim &= tr.fg[idx] > SKIN_RATIO * skin[idx]
        claim &= ~others
        offset = _best_offset(claim, moved[k], tr.typical_px)
        if offset is not None and _look(tr.fg, idx, moved[k], offset) >= LOOK:
            found[k] = offset
    return found


def _best_offset(claim: np.ndarray, shape: np.ndarray, typical_px: float) -> np.ndarray | None:
    """The offset within ``REACH`` that puts ``shape`` over the most ``claim`` pixels, when they
    fill ``FILL`` of it there and ``GAIN`` times what they fill at no offset (plus a tenth of it)."""
    h, w = shape.shape
    ys, xs = np.nonzero(shape)
    y0, y1, x0, x1 = ys.min(), ys.max() + 1, xs.min(), xs.max() + 1
    reach = int(max(REACH * np.sqrt(typical_px), 10))
    wy0, wx0 = max(y0 - reach, 0), max(x0 - reach, 0)
    window = claim[wy0 : min(y1 + reach, h), wx0 : min(x1 + reach, w)].astype(np.float32)
    template = shape[y0:y1, x0:x1].astype(np.float32)
    if window.shape[0] < template.shape[0] or window.shape[1] < template.shape[1]:
        return None
    _, best, _, (bx, by) = cv2.minMaxLoc(cv2.matchTemplate(window, template, cv2.TM_CCORR))
    area, here = float(template.sum()), float(claim[shape].sum())
    if best < FILL * area or best < GAIN * here + 0.1 * area:
        return None
    return np.array([wx0 + bx - x0, wy0 + by - y0], float)


def _look(fg: np.ndarray, idx: np.ndarray, shape: np.ndarray, offset: np.ndarray) -> float:
    """Histogram intersection of the colors under ``shape`` moved by ``offset`` with ``fg``."""
    h, w = shape.shape
    warp = np.float32([[1, 0, offset[0]], [0, 1, offset[1]]])
    there = cv2.warpAffine(shape.astype(np.uint8), warp, (w, h), flags=cv2.INTER_NEAREST).astype(bool)
    return float(np.minimum(histogram(idx[there]), fg).sum())
