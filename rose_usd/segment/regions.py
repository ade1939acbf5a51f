"""Pixel regions of masks: connected parts and holes, and what an object's mask takes that is not
the object: the fingers on it, peeled off by their color, and blobs apart from it."""

from __future__ import annotations

import cv2
import numpy as np


def components(mask: np.ndarray) -> tuple[int, np.ndarray, np.ndarray]:
    """4-connected components: count, labels (H, W) and the area of each label."""
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=4)
    return n, labels, stats[:, cv2.CC_STAT_AREA]


def fill_holes(mask: np.ndarray, max_hole_px: int) -> np.ndarray:
    """``mask`` with its holes of at most ``max_hole_px`` pixels filled (not those at the border)."""
    inv = ~mask
    n, labels, areas = components(inv)
    border = np.unique(np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]]))
    small = np.zeros(n, bool)
    small[1:] = areas[1:] <= max_hole_px
    small[border] = False
    return mask | small[labels]


def peel_skin(
    mask: np.ndarray,
    cidx: np.ndarray,
    color: np.ndarray,
    skin: np.ndarray,
    front: np.ndarray,
    sigma_px: float,
    *,
    min_px: int = 15,
) -> np.ndarray:
    """``mask`` without the fingers on it: its parts whose colours, averaged by a Gaussian of
    ``sigma_px`` over the mask, are likelier under the ``skin`` color histogram than under the
    object's ``color``, where they touch ``front`` outside the mask (a found hand, or what stands in
    front of the static world: the arm of a hand the detector missed). A finger is skin through
    and through; an object's skin-like print is mixed with its other colours at this scale, and
    where it meets the table rather than a hand it stays."""
    if not mask.any():
        return mask
    pad = int(3 * sigma_px) + 3
    ys, xs = np.nonzero(mask)
    y0, y1 = max(int(ys.min()) - pad, 0), min(int(ys.max()) + pad + 1, mask.shape[0])
    x0, x1 = max(int(xs.min()) - pad, 0), min(int(xs.max()) + pad + 1, mask.shape[1])
    m, c = mask[y0:y1, x0:x1], cidx[y0:y1, x0:x1]
    ratio = (np.log(color[c]) - np.log(skin[c])).astype(np.float32)
    weight = m.astype(np.float32)
    mean = cv2.GaussianBlur(ratio * weight, (0, 0), sigma_px) / np.maximum(
        cv2.GaussianBlur(weight, (0, 0), sigma_px), 1e-3
    )
    skin = m & (mean < 0)
    if not skin.any():
        return mask
    touching = cv2.dilate((front[y0:y1, x0:x1] & ~m).astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    n, labels, areas = components(skin)
    drop = np.zeros(n, bool)
    drop[np.unique(labels[skin & touching])] = True
    drop[0] = False
    drop &= areas >= min_px
    out = mask.copy()
    out[y0:y1, x0:x1] &= ~drop[labels]
    return out


def main_part(
    mask: np.ndarray,
    area_px: float,
    depth: np.ndarray | None = None,
    *,
    reach: float = 0.15,
    share: float = 0.25,
    front_m: float = 0.005,
) -> np.ndarray:
    """``mask`` without small blobs apart from the object (a bit of a spoon of its colours, a
    sleeve, once taken along): when its largest 4-connected part holds at least ``share`` of
    ``area_px`` (the object's visible pixels at the start), the parts kept are that one, those
    within ``reach`` times the square root of ``area_px`` of it, those of at least ``share`` of its
    area, and, with ``depth`` [m], those cut off it by something in front of both (the object seen
    past a finger: the gap between them is nearer the camera by ``front_m``). A mask in pieces (the
    object between the fingers of a hand that holds it) is kept whole."""
    n, labels, areas = components(mask)
    if n <= 2:
        return mask
    largest = 1 + int(np.argmax(areas[1:]))
    if areas[largest] < share * area_px:
        return mask
    r = max(2, int(round(reach * np.sqrt(area_px))))
    main = labels == largest
    near = cv2.dilate(main.astype(np.uint8), np.ones((2 * r + 1, 2 * r + 1), np.uint8)).astype(bool)
    keep = areas >= share * areas[largest]
    keep[np.unique(labels[near & mask])] = True
    keep[0] = False
    if depth is not None and np.any(~keep[1:]):
        d = np.where(depth > 0, depth, np.nan)
        to_main = cv2.distanceTransform((~main).astype(np.uint8), cv2.DIST_L2, 5)
        main_d = float(np.nanmedian(d[main])) if np.isfinite(d[main]).any() else np.nan
        for k in np.flatnonzero(~keep[1:]) + 1:
            part = labels == k
            to_part = cv2.distanceTransform((~part).astype(np.uint8), cv2.DIST_L2, 5)
            # the pixels between the two: on short paths from one to the other
            between = (to_part + to_main <= float(to_main[part].min()) + 2.0) & ~mask & np.isfinite(d)
            if not between.any() or not np.isfinite(d[part]).any() or not np.isfinite(main_d):
                continue
            nearest_side = min(float(np.nanmedian(d[part])), main_d)
            keep[k] = float(np.median(d[between])) < nearest_side - front_m
    return keep[labels]


def depth_edges(depth: np.ndarray, *, rel: float = 0.02, abs_m: float = 0.008) -> np.ndarray:
    """Pixels at a depth discontinuity (a jump to a neighbor beyond ``abs_m + rel * depth``)."""
    d = depth.astype(np.float32)
    tol = abs_m + rel * d
    edge = np.zeros(d.shape, bool)
    dx = np.abs(np.diff(d, axis=1)) > tol[:, :-1]
    dy = np.abs(np.diff(d, axis=0)) > tol[:-1, :]
    edge[:, :-1] |= dx
    edge[:, 1:] |= dx
    edge[:-1, :] |= dy
    edge[1:, :] |= dy
    return edge | (d <= 0)
