"""An object's mask from a box prompt: GrabCut in the box, robust to its random start.

GrabCut starts its colour models by k-means from OpenCV's global random generator, and on an
object of two looks (a pen's clear body and black cap on a wooden desk) different draws settle on
different parts of it. A box prompt says where the object's extremes are, so several seeded runs
are made and the one whose largest part fills the box clearly best is kept: the result no longer
depends on what drew from the generator before.
"""

from __future__ import annotations

import cv2
import numpy as np

SEEDS = 4
"""GrabCut runs, seeded 0..SEEDS-1."""
FILL_MARGIN = 0.05
"""A later run replaces the one kept only where its box IoU is higher by this much: runs that differ
by a few pixels of outline (a flat-coloured object's) keep seed 0's."""


def box_grabcut(
    rgb: np.ndarray, box: tuple[int, int, int, int], *, iterations: int = 5, seeds: int = SEEDS, connectivity: int = 8
):
    """The largest ``connectivity``-connected part of GrabCut's foreground in ``box`` (x0, y0, x1,
    y1 [px], inside the image) over ``seeds`` seeded runs: the one whose bounding box has the
    highest IoU with ``box``, by ``FILL_MARGIN`` over an earlier run's; bool (h, w), empty when
    every run found nothing. Leaves OpenCV's random generator seeded."""
    x0, y0, x1, y1 = box
    bgr = cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)
    best, best_fit = np.zeros(rgb.shape[:2], bool), -1.0
    for seed in range(seeds):
        cv2.setRNGSeed(seed)
        gc = np.zeros(rgb.shape[:2], np.uint8)
        bgd, fgd = np.zeros((1, 65), np.float64), np.zeros((1, 65), np.float64)
        cv2.grabCut(bgr, gc, (x0, y0, x1 - x0, y1 - y0), bgd, fgd, iterations, cv2.GC_INIT_WITH_RECT)
        part = largest_part((gc == cv2.GC_FGD) | (gc == cv2.GC_PR_FGD), connectivity)
        if not part.any():
            continue
        fit = _box_iou(_bounds(part), box)
        if fit > best_fit + (FILL_MARGIN if best.any() else 0.0):
            best, best_fit = part, fit
    return best


def largest_part(mask: np.ndarray, connectivity: int = 8) -> np.ndarray:
    """The largest ``connectivity``-connected part of a bool mask (all False when it is empty)."""
    count, labels, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=connectivity)
    if count < 2:
        return np.zeros(mask.shape, bool)
    return labels == 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))


def _bounds(mask: np.ndarray) -> tuple[int, int, int, int]:
    ys, xs = np.nonzero(mask)
    return int(xs.min()), int(ys.min()), int(xs.max()) + 1, int(ys.max()) + 1


def _box_iou(a, b) -> float:
    w = min(a[2], b[2]) - max(a[0], b[0])
    h = min(a[3], b[3]) - max(a[1], b[1])
    inter = max(w, 0) * max(h, 0)
    union = (a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter
    return inter / max(union, 1)


def split_shared(
    masks: dict[str, np.ndarray], boxes: dict[str, tuple[float, float, float, float] | None]
) -> dict[str, np.ndarray]:
    """The masks of several objects prompted on one frame, each pixel in one at most.

    A prompt box drawn around an object holds whatever stands in front of it or on it, and its
    GrabCut takes part of that (a can standing on a box: the box's prompt holds the can's lower
    half, and takes it). Each connected patch of pixels that two masks claim goes to the object
    that the box prompts then fit best: the sum over the objects of the IoU of each mask's bounding
    box with its prompt box (``boxes``; None for a point prompt, which says nothing of the
    extent, and counts for nothing). The can without its lower half no longer reaches the bottom
    of its box; the box without the can's half still fills its own. What an object loses may
    leave it in parts, of which it keeps the largest."""
    names = list(masks)
    out = {n: np.asarray(masks[n], bool).copy() for n in names}
    if len(names) < 2:
        return out
    shared = np.sum([out[n] for n in names], axis=0) > 1
    if not shared.any():
        return out
    count, labels = cv2.connectedComponents(shared.astype(np.uint8), connectivity=8)
    for patch_label in range(1, count):
        patch = labels == patch_label
        claimants = [n for n in names if (out[n] & patch).any()]
        fits = []
        for winner in claimants:
            total = 0.0
            for n in claimants:
                if boxes.get(n) is None:
                    continue
                mask = out[n] | patch if n == winner else out[n] & ~patch
                total += _box_iou(_bounds(mask), boxes[n]) if mask.any() else 0.0
            fits.append(total)
        winner = claimants[int(np.argmax(fits))]
        for n in claimants:
            if n != winner:
                out[n] &= ~patch
    return {n: largest_part(m) if m.any() else m for n, m in out.items()}
