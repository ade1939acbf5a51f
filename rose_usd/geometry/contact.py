"""Contact and support from masks and depth: whether the interactor touches an object, the first
frame it does, and the height of the surface around an object. Shared by the scene stage (its
support pads), the object stage (the rest it fuses, the support it stands on) and the tracker
(when it registers instead of holding); the masks come from ``rose_usd.layers.masks``."""

from __future__ import annotations

from collections.abc import Callable

import cv2
import numpy as np

from rose_usd.core.pinhole import masked_world_points

TOUCH_REACH_PX = 5
"""The tracker's touch: the interactor touches an object whose mask it comes this near [px].
Classical masks leave a pixel or two claimed by neither where hand meets object: at 3 px a hand
carrying an object by its top can reach it on fewer pixels than ``touches`` needs, and the
tracker then holds the object in the air while it is set down. The rest that fusion uses ends
at 3 px (``first_contact``)."""


def first_contact(
    masks: list, hand_of: Callable, depth_of, n: int, *, reach_px: int = 3, depth_m: float = 0.02, min_px: int = 20
) -> int:
    """The first frame in which the interactor touches the object: its mask comes within
    ``reach_px`` of the object's with depths within ``depth_m`` over ``min_px`` pixels (n if never).
    Nothing moves an object before that. Closer than the tracker's ``TOUCH_REACH_PX``: here a
    touch seen too early ends the rest and loses views (at 5 px a hand reaching for the upper
    object of a stack can seem to touch the lower one long before it does), where for the
    tracker it only means registering instead of holding.
    ``hand_of(t)``: the interactor's mask in frame t, None where it has none. An interactor
    mask smaller than a fifth of the object's is no hand: it is a sliver of the object's own rim
    left out of its mask (a depth camera a few pixels off the colour one), seen on a static
    camera before any hand is in view."""
    for t in range(n):
        hand = hand_of(t) if masks[t] is not None else None
        if hand is None or hand.sum() < 0.2 * masks[t].sum():
            continue
        if touches(
            hand,
            masks[t],
            depth_of(t),
            reach_px=reach_px,
            depth_m=depth_m,
            min_px=min_px,
        ):
            return t
    return n


def touches(
    hand: np.ndarray,
    mask: np.ndarray,
    depth: np.ndarray,
    *,
    reach_px: int = TOUCH_REACH_PX,
    depth_m: float = 0.02,
    min_px: int = 20,
) -> bool:
    """Whether the interactor's mask ``hand`` comes within ``reach_px`` of the object's ``mask``
    with depths within ``depth_m`` (plus half the object's extent) over ``min_px`` pixels."""
    kernel = np.ones((2 * reach_px + 1, 2 * reach_px + 1), np.uint8)
    near = cv2.dilate(mask.astype(np.uint8), kernel).astype(bool) & hand
    if near.sum() < min_px:
        return False
    obj_depth = np.median(depth[mask & (depth > 0)]) if np.any(mask & (depth > 0)) else 0.0
    return bool(
        np.count_nonzero(near & (depth > 0) & (np.abs(depth - obj_depth) < depth_m + 0.5 * _extent_m(mask, depth)))
        >= min_px
    )


def _extent_m(mask: np.ndarray, depth: np.ndarray) -> float:
    """The object's depth extent along the view (its far and near sides differ by this) [m]."""
    d = depth[mask & (depth > 0)]
    return float(np.percentile(d, 95) - np.percentile(d, 5)) if len(d) else 0.0


def ring_height(
    occluders: Callable, views: list[tuple[int, float]], masks, depth_of, cameras, *, count: int = 8
) -> float:
    """The height of the surface around an object: the median z of a ring of pixels 3-12 px
    outside its mask (other objects and the interactor left out) in up to ``count`` of ``views``
    ((frame, depth scale): each frame's depth is multiplied by its scale), spread over them; 0
    when the ring has under 50 points. The world's z = 0 is one plane fitted for the whole scene;
    under a given object the table may sit a few mm (or, with MegaSaM depth, centimeters) off it.
    ``masks[t]``: the object's mask in frame t; ``occluders(t, shape)``: what may hide it there
    (``Masks.occluders``). The object stage stands objects on this height
    and the scene stage flattens its collider under them to it (``scene.tsdf.support_pads``)."""
    zs = []
    for t, scale in [views[i] for i in np.unique(np.linspace(0, len(views) - 1, min(count, len(views))).astype(int))]:
        mask = masks[t].astype(np.uint8)
        ring = cv2.dilate(mask, np.ones((25, 25), np.uint8)).astype(bool) & ~cv2.dilate(
            mask, np.ones((7, 7), np.uint8)
        ).astype(bool)
        ring &= ~occluders(t, mask.shape)
        pts, _ = masked_world_points(depth_of(t) * np.float32(scale), ring, cameras.K[t], cameras.world_from_cv[t])
        zs.append(pts[:, 2])
    z = np.concatenate(zs) if zs else np.zeros(0)
    return float(np.median(z)) if len(z) >= 50 else 0.0
