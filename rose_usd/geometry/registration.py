"""Depth-to-colour registration checks: for a static camera, the pixel shift that puts what moves
in the depth on what moves in the colour (``find_depth_shift``); for any camera, whether the
depth's silhouettes lie on the colour's edges (``edge_alignment``).

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
from collections.abc import Callable, Iterable
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


EDGE_CAP_PX = 5.0
"""A depth silhouette pixel farther than this from every colour edge counts as this far [px]."""
EDGE_CONTRAST = 0.8
"""Registered: the silhouettes' mean edge distance at no offset is at most this fraction of its
median over all offsets (measured over 8 frames: visp-desk's RealSense depth 0.64, registered;
7-Scenes' Kinect depth, which its colour camera does not share, 0.98; cups-rgbd's depth, 20 px off,
0.87)."""


@dataclass(frozen=True)
class EdgeAlignment:
    dx: int
    """Depth pixel (x, y) lies on the colour's edges at (x + dx, y + dy) (as ``DepthShift``)."""
    dy: int
    at_best_px: float
    """Mean distance from a depth silhouette pixel to the nearest colour edge at (dx, dy) [px]."""
    at_zero_px: float
    """The same at no offset."""
    typical_px: float
    """Its median over every offset tried: what an unrelated offset gives."""
    frames: int
    """Frames with enough depth silhouette to measure."""

    @property
    def registered(self) -> bool:
        """The best offset is within a pixel of none, and the silhouettes lie clearly nearer the
        edges there than at an unrelated offset (a view with few colour edges at its depth
        silhouettes proves nothing)."""
        return (
            self.frames > 0
            and max(abs(self.dx), abs(self.dy)) <= 1
            and self.at_zero_px <= EDGE_CONTRAST * self.typical_px
        )


def edge_alignment(
    rgb_of: Callable[[int], np.ndarray],
    depth_of: Callable[[int], np.ndarray],
    frames: Iterable[int],
    *,
    max_px: int = 16,
    samples: int = 3000,
) -> EdgeAlignment:
    """How well depth silhouettes lie on colour edges, at every integer offset within ``max_px``,
    over ``frames`` (any camera: each frame is compared with itself). A silhouette pixel is the
    near side of a depth jump of 3 cm or 3 %; colour edges are Canny's on the smoothed gray image."""
    span = np.arange(-max_px, max_px + 1)
    total = np.zeros((len(span), len(span)))
    used = 0
    rng = np.random.default_rng(0)
    for t in frames:
        rgb, depth = rgb_of(t), np.asarray(depth_of(t), np.float32)
        ys, xs = _silhouette_pixels(depth, max_px)
        if len(ys) < 50:
            continue
        if len(ys) > samples:
            keep = rng.choice(len(ys), samples, replace=False)
            ys, xs = ys[keep], xs[keep]
        gray = cv2.GaussianBlur(cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY), (5, 5), 0)
        edges = cv2.Canny(gray, 30, 90) > 0
        dist = np.minimum(cv2.distanceTransform((~edges).astype(np.uint8), cv2.DIST_L2, 3), EDGE_CAP_PX)
        # dist at every offset of every pixel: (offsets_y, offsets_x, pixels) gathered at once
        rows = ys[None, :] + span[:, None]
        cols = xs[None, :] + span[:, None]
        total += dist[rows[:, None, :], cols[None, :, :]].mean(axis=-1)
        used += 1
    if not used:
        return EdgeAlignment(0, 0, EDGE_CAP_PX, EDGE_CAP_PX, EDGE_CAP_PX, 0)
    total /= used
    i, j = np.unravel_index(int(np.argmin(total)), total.shape)
    return EdgeAlignment(
        int(span[j]), int(span[i]), float(total[i, j]), float(total[max_px, max_px]), float(np.median(total)), used
    )


def _silhouette_pixels(depth: np.ndarray, margin: int) -> tuple[np.ndarray, np.ndarray]:
    """Rows and columns of the pixels on the near side of a depth jump (a 4-neighbour 3 cm or
    3 % farther), ``margin`` or more pixels from the border."""
    valid = depth > 0
    near = np.zeros_like(valid)
    pad = np.pad(depth, 1)
    h, w = depth.shape
    for dy, dx in ((0, 1), (0, -1), (1, 0), (-1, 0)):
        other = pad[1 + dy : 1 + dy + h, 1 + dx : 1 + dx + w]
        near |= valid & (other > 0) & (other - depth > np.maximum(0.03, 0.03 * depth))
    inner = np.zeros_like(near)
    inner[margin : h - margin, margin : w - margin] = True
    return np.nonzero(near & inner)
