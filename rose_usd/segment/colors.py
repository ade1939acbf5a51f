"""Color models of the segmenter: pixels' colors as indices into a 16x16x16 RGB grid, smoothed
normalized histograms over it, and the tie-break between an object's colors and its neighbours'."""

from __future__ import annotations

import numpy as np
from scipy.ndimage import gaussian_filter

BINS = 16


def color_index(rgb: np.ndarray) -> np.ndarray:
    q = (rgb // (256 // BINS)).astype(np.int32)
    return (q[..., 0] * BINS + q[..., 1]) * BINS + q[..., 2]


def histogram(idx: np.ndarray) -> np.ndarray:
    hist = np.bincount(idx.ravel(), minlength=BINS**3).astype(np.float64).reshape(BINS, BINS, BINS)
    hist = gaussian_filter(hist, sigma=1.0, mode="constant").reshape(-1)  # shading shifts colors by a bin or two
    return (hist + 1e-3) / (hist.sum() + 1e-3 * hist.size)


SHADES = (1.0, 0.8, 0.6)
"""Brightness factors a surface's own colors are seen at: a mesh's texture is lit evenly, the
object's faces turned from the light are darker in the video."""


def surface_histogram(colors8: np.ndarray) -> np.ndarray:
    """The color model of a surface from its own colors (sRGB8, (N, 3): a mesh's texture sampled
    over its area), as seen at each of ``SHADES``."""
    shaded = np.concatenate([np.clip(colors8.astype(np.float64) * s, 0, 255) for s in SHADES])
    return histogram(color_index(shaded.astype(np.uint8)))


def object_colored(
    color: np.ndarray,
    idx: np.ndarray,
    near: np.ndarray,
    hand_hist: np.ndarray | None = None,
    *,
    others: int = 0,
    min_px: float = 0,
) -> np.ndarray:
    """Per color index of ``idx``: likelier under the object's ``color`` histogram than under
    that of what stands ``near`` it (color indices: the object and anything else standing in its
    reach), mixed half and half with the hand's when there is one. Color only breaks ties: when
    ``others`` (the near pixels that are not the object's: a hand, another object) are fewer than
    ``min_px`` and no hand has been seen, nothing competes and every pixel passes; otherwise the
    object's rarer colors (a can's pale lid) would lose to its commoner ones."""
    if hand_hist is None and others < max(min_px, 1):
        return np.ones(len(idx), bool)
    ring = histogram(near)
    denominator = ring if hand_hist is None else 0.5 * (ring + hand_hist)
    return color[idx] > denominator[idx]
