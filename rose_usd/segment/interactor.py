"""The interactor's mask (the hand and arm): what stands in front of the static world and is no
object, connected to a hand found by its landmarks or followed from the frame before."""

from __future__ import annotations

from typing import TYPE_CHECKING

import cv2
import numpy as np

from rose_usd.segment.colors import histogram
from rose_usd.segment.regions import components, touching
from rose_usd.segment.segmenter import MIN_REGION_PX

if TYPE_CHECKING:
    from rose_usd.segment.segmenter import Segmenter


def arm_mask(seg: Segmenter, t: int, hand: np.ndarray) -> np.ndarray:
    """What stands in front of the static world (geometry.background) in frame t and connects to
    ``hand`` (pixels of a hand found by its landmarks): the arm, and whatever the hand holds."""
    return touching(seg.foreground(t)[0] | hand, hand, grow_px=2) & ~hand


def following_arm(seg: Segmenter, t: int, last: np.ndarray | None) -> np.ndarray | None:
    """Without a found hand: what stands in front of the static world (geometry.background) in
    frame t, in regions that overlap ``last`` (the interactor's mask in the frame before): the
    interactor followed from frame to frame, with what it now holds (``arm_mask``'s role). Sensor
    holes on a dark sleeve break the region into specks: they are bridged first (``bridge_holes``)."""
    if last is None or not last.any():
        return None
    return touching(seg.bridged(t), last, grow_px=2) & seg.foreground(t)[0]


def interactor_mask(
    seg: Segmenter, t: int, objects: list[np.ndarray], hand_hist: np.ndarray | None = None
) -> np.ndarray:
    """The other moving region: nearer than the static world, not an object. With a color model
    of the hand, it grows through hand-colored pixels connected to it whose depth is missing or
    disagrees with the static world (too near for the sensor, or misregistered at the rim)."""
    rgb, depth, pts, edges, cidx, _ = seg.frame(t)
    fg, static = seg.foreground(t)
    taken = np.zeros_like(fg)
    for m in objects:
        taken |= m
    taken = cv2.dilate(taken.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    fg = seg.bridged(t) & ~taken
    fg = cv2.morphologyEx(fg.astype(np.uint8), cv2.MORPH_OPEN, np.ones((3, 3), np.uint8)).astype(bool)
    n, labels, areas = components(fg)
    big = np.zeros(n, bool)
    big[1:] = areas[1:] >= MIN_REGION_PX * seg.scale_px
    hand = big[labels]
    if hand_hist is not None and hand.any() and static.any():
        bg_hist = histogram(cidx[static][:: max(1, int(static.sum()) // 20000)])
        maybe = (hand_hist[cidx] > 2.0 * bg_hist[cidx]) & ~static & ~taken
        hand = touching(hand | maybe, hand)
    return hand
