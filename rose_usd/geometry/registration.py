"""Depth-to-colour registration check for a static camera: the pixel shift that puts what moves
in the depth on what moves in the colour.

"Aligned" depth from real sensors is often not: a stream aligned with another profile's
extrinsics, or cropped from another aspect ratio, puts every depth silhouette some pixels off its
object (cups-rgbd-upside-down: about 20 px left and 4 px down, so the segmenter took the table
beside the ball for the ball). Edges do not measure it well: a cluttered colour image has an edge
near every shift. Motion does: with a static camera, the pixels whose colour differs from the
video's median and the pixels that are nearer than the median depth (the hand, the moved
object) are the same pixels once the depth is shifted right. The shift maximizes their overlap
(intersection over union) summed over frames spread through the video, for every integer offset
at once by FFT cross-correlation.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np

COLOUR_CHANGE = 40
"""A pixel's colour changed when a channel differs from the median frame by this much (8-bit)."""
DEPTH_CHANGE_M = 0.03
"""A pixel came nearer when its depth is this much (or 3 %) short of the median depth [m]."""


@dataclass(frozen=True)
class DepthShift:
    dx: int
    """Depth pixel (x, y) shows colour pixel (x + dx, y + dy)."""
    dy: int
    overlap: float
    """Intersection over union of the moving pixels in depth and in colour at the shift."""
    overlap_unshifted: float
    frames: int
    """Frames with enough motion to measure."""

    @property
    def applies(self) -> bool:
        """Used when it is at least 2 px and the overlap at it is at least 1.25x that of no
        shift (a registered sensor's best offset is 0 or 1 px and gains nothing)."""
        return (
            max(abs(self.dx), abs(self.dy)) >= 2
            and self.overlap >= 1.25 * self.overlap_unshifted
            and self.overlap >= 0.1
        )


def find_depth_shift(
    rgb_of: Callable[[int], np.ndarray],
    depth_of: Callable[[int], np.ndarray],
    n_frames: int,
    *,
    samples: int = 40,
    max_px: int = 30,
) -> DepthShift:
    """The integer shift within ``max_px`` that best overlays the depth's moving pixels on the
    colour's, over ``samples`` frames of a static camera's video."""
    frames = sorted(set(np.linspace(0, n_frames - 1, min(samples, n_frames)).round().astype(int).tolist()))
    rgbs = np.stack([rgb_of(t) for t in frames]).astype(np.int16)
    depths = np.stack([depth_of(t) for t in frames]).astype(np.float32)
    depths[~(depths > 0)] = np.nan
    median_rgb = np.median(rgbs, axis=0)
    with warnings.catch_warnings():  # pixels never with depth: an all-NaN median is NaN
        warnings.simplefilter("ignore", RuntimeWarning)
        median_depth = np.nanmedian(depths, axis=0)
    h, w = depths.shape[1:]
    size = (h + 2 * max_px, w + 2 * max_px)
    rows = np.arange(-max_px, max_px + 1) % size[0]
    cols = np.arange(-max_px, max_px + 1) % size[1]
    inter = np.zeros((len(rows), len(cols)))
    total, used = 0.0, 0
    kernel = np.ones((3, 3), np.uint8)
    for rgb, depth in zip(rgbs, depths):
        colour = _opened(np.abs(rgb - median_rgb).max(axis=-1) > COLOUR_CHANGE, kernel)
        with np.errstate(invalid="ignore"):
            nearer = np.nan_to_num(median_depth - depth) > np.maximum(
                DEPTH_CHANGE_M, 0.03 * np.nan_to_num(median_depth)
            )
        nearer = _opened(nearer, kernel)
        if nearer.sum() < 200 or colour.sum() < 200:
            continue
        # inter[dy, dx] = sum over x of nearer(x) * colour(x + d), for every d at once
        corr = np.fft.irfft2(np.fft.rfft2(colour, s=size) * np.conj(np.fft.rfft2(nearer, s=size)), s=size)
        inter += corr[np.ix_(rows, cols)]
        total += float(colour.sum() + nearer.sum())
        used += 1
    if not used:
        return DepthShift(0, 0, 0.0, 0.0, 0)
    iou = inter / np.maximum(total - inter, 1.0)
    i, j = np.unravel_index(int(np.argmax(iou)), iou.shape)
    return DepthShift(int(j - max_px), int(i - max_px), float(iou[i, j]), float(iou[max_px, max_px]), used)


def _opened(mask: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    return cv2.morphologyEx(mask.astype(np.uint8), cv2.MORPH_OPEN, kernel).astype(np.float32)


def shift_depth(depth: np.ndarray, dx: int, dy: int) -> np.ndarray:
    """Depth moved onto the colour pixels: output (x + dx, y + dy) = input (x, y); uncovered
    pixels have no depth (0)."""
    if dx == 0 and dy == 0:
        return depth
    h, w = depth.shape
    out = np.zeros_like(depth)
    src_y, dst_y = slice(max(-dy, 0), h - max(dy, 0)), slice(max(dy, 0), h - max(-dy, 0))
    src_x, dst_x = slice(max(-dx, 0), w - max(dx, 0)), slice(max(dx, 0), w - max(-dx, 0))
    out[dst_y, dst_x] = depth[src_y, src_x]
    return out
