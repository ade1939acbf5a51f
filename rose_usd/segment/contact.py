"""Contact and support read from the masks: whether the interactor touches an object, the first
frame it does, what may hide an object (the other masks), and the height of the surface around
an object. Shared by the scene stage (its support pads), the object stage (the rest it fuses, the
support it stands on) and the tracker (when it registers instead of holding)."""

from __future__ import annotations

import cv2
import numpy as np

from rose_usd.core.pinhole import masked_world_points
from rose_usd.io.images import read_mask
from rose_usd.segment.tracks import INTERACTOR
from rose_usd.stage_api import StageContext

TOUCH_REACH_PX = 5
"""The tracker's touch: the interactor touches an object whose mask it comes this near [px].
Classical masks leave a pixel or two claimed by neither where hand meets object: at 3 px a hand
carrying an object by its top can reach it on fewer pixels than ``touches`` needs, and the
tracker then holds the object in the air while it is set down. The rest that fusion uses ends
at 3 px (``first_contact``)."""


def first_contact(
    masks: list, hand_folder, depth_of, n: int, *, reach_px: int = 3, depth_m: float = 0.02, min_px: int = 20
) -> int:
    """The first frame in which the interactor touches the object: its mask comes within
    ``reach_px`` of the object's with depths within ``depth_m`` over ``min_px`` pixels (n if never).
    Nothing moves an object before that. Closer than the tracker's ``TOUCH_REACH_PX``: here a
    touch seen too early ends the rest and loses views (at 5 px a hand reaching for the upper
    object of a stack can seem to touch the lower one long before it does), where for the
    tracker it only means registering instead of holding."""
    for t in range(n):
        if masks[t] is None or not (hand_folder / f"{t:06d}.png").is_file():
            continue
        if touches(
            read_mask(hand_folder / f"{t:06d}.png"),
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


def occluders(ctx: StageContext, name: str, t: int, shape: tuple[int, int], *, grow_px: int) -> np.ndarray:
    """What may stand in front of object ``name`` or beside it in frame t: the masks of the other
    objects and of the interactor, grown by ``grow_px`` (bool, ``shape``)."""
    out = np.zeros(shape, np.uint8)
    for other in [o.name for o in ctx.case.config.objects if o.name != name] + [INTERACTOR]:
        f = ctx.out_dir / "masks" / other / f"{t:06d}.png"
        if f.is_file():
            out |= read_mask(f).astype(np.uint8)
    return cv2.dilate(out, np.ones((2 * grow_px + 1, 2 * grow_px + 1), np.uint8)).astype(bool)


def ring_height(
    ctx: StageContext, name: str, views: list[tuple[int, float]], masks, depth_of, cameras, *, count: int = 8
) -> float:
    """The height of the surface around object ``name``: the median z of a ring of pixels 3-12 px
    outside its mask (other objects and the interactor left out) in up to ``count`` of ``views``
    ((frame, depth scale): each frame's depth is multiplied by its scale), spread over them; 0
    when the ring has under 50 points. The world's z = 0 is one plane fitted for the whole scene;
    under a given object the table may sit a few mm (or, with MegaSaM depth, centimeters) off it.
    ``masks[t]``: the object's mask in frame t. The object stage stands objects on this height
    and the scene stage flattens its collider under them to it (``scene.tsdf.support_pads``)."""
    zs = []
    for t, scale in [views[i] for i in np.unique(np.linspace(0, len(views) - 1, min(count, len(views))).astype(int))]:
        mask = masks[t].astype(np.uint8)
        ring = cv2.dilate(mask, np.ones((25, 25), np.uint8)).astype(bool) & ~cv2.dilate(
            mask, np.ones((7, 7), np.uint8)
        ).astype(bool)
        ring &= ~occluders(ctx, name, t, mask.shape, grow_px=3)
        pts, _ = masked_world_points(depth_of(t) * np.float32(scale), ring, cameras.K[t], cameras.world_from_cv[t])
        zs.append(pts[:, 2])
    z = np.concatenate(zs) if zs else np.zeros(0)
    return float(np.median(z)) if len(z) >= 50 else 0.0
