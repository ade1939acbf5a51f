"""Is the camera static? Corners of the first frame that stay put.

A camera on a tripod or a rig films a person moving things: the moving person covers a large
part of the view, and RGB-D tracking, which assumes a mostly static scene, then reports a static
camera drifting by centimetres (cups-rgbd-upside-down: 2-4 cm). Corners of the first frame
tracked by pyramidal Lucas-Kanade tell it directly: on a static camera most of them stay within
a fraction of a pixel of where they were for the whole video (those on the moving person do not),
on a hand-held one almost none do.
"""

from __future__ import annotations

from collections.abc import Callable

import cv2
import numpy as np

STILL_PX = 0.5
"""A corner stayed put when it is this near its first-frame position [px]."""


def still_fraction(rgb_of: Callable[[int], np.ndarray], n_frames: int, *, samples: int = 12) -> float:
    """The median, over frames spread through the video, of the fraction of frame 0's corners
    found within ``STILL_PX`` of their first position (0 when frame 0 has too few corners)."""
    gray0 = cv2.cvtColor(rgb_of(0), cv2.COLOR_RGB2GRAY)
    corners = cv2.goodFeaturesToTrack(gray0, maxCorners=400, qualityLevel=0.01, minDistance=8)
    if corners is None or len(corners) < 20 or n_frames < 2:
        return 0.0
    fractions = []
    for t in np.linspace(1, n_frames - 1, min(samples, n_frames - 1)).round().astype(int):
        gray = cv2.cvtColor(rgb_of(int(t)), cv2.COLOR_RGB2GRAY)
        moved, status, _ = cv2.calcOpticalFlowPyrLK(gray0, gray, corners, None, winSize=(15, 15), maxLevel=2)
        ok = status.ravel() == 1
        dist = np.linalg.norm((moved - corners).reshape(-1, 2), axis=1)
        fractions.append(float(np.mean(ok & (dist < STILL_PX))))
    return float(np.median(fractions))


def is_static(rgb_of: Callable[[int], np.ndarray], n_frames: int, *, min_fraction: float = 0.3) -> bool:
    """True when at least ``min_fraction`` of the first frame's corners stay put (``still_fraction``)."""
    return still_fraction(rgb_of, n_frames) >= min_fraction
