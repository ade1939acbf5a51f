"""The classical segment backend: objects from a prompt (or the region the interactor comes to),
followed through the video in 3D by the depth segmenter (``segment.segmenter``), and the
interactor as what stands in front of the static world."""

from __future__ import annotations

import cv2
import numpy as np

from rose_usd.errors import InputError
from rose_usd.geometry.background import StaticBackground
from rose_usd.geometry.hands import Hand, hand_mask
from rose_usd.geometry.support import SupportSurface
from rose_usd.layers.world import metric_depth_reader, read_cameras
from rose_usd.progress import progress
from rose_usd.segment.colors import histogram
from rose_usd.segment.hands import found_hands as find_hands
from rose_usd.segment.hands import skin_histogram
from rose_usd.segment.interactor import arm_mask, following_arm, interactor_mask
from rose_usd.segment.prompts import check_prompts, parse_prompts, prompts_source
from rose_usd.segment.segmenter import MIN_REGION_PX, Segmenter
from rose_usd.segment.tracks import INTERACTOR, MaskTrack, author_and_check
from rose_usd.stage_api import StageContext


def run(ctx: StageContext) -> None:
    case = ctx.case
    n = ctx.time_info.n_frames
    cfg = ctx.config
    cameras = read_cameras(ctx.stage, n)
    depth_of = metric_depth_reader(ctx.stage, case, cache=24)
    where = prompts_source(cfg.prompts, case)
    background = StaticBackground(depth_of, cameras.world_from_cv, cameras.K, case.width, case.height)
    support = SupportSurface(depth_of, cameras.world_from_cv, cameras.K, background.refs)
    seg = Segmenter(case.rgb, depth_of, cameras, cfg, background, support)
    try:
        _segment(ctx, seg, support, where)
    finally:
        seg.close()


def _segment(ctx: StageContext, seg: Segmenter, support: SupportSurface, where) -> None:
    case, n, cfg = ctx.case, ctx.time_info.n_frames, ctx.config
    specs = parse_prompts(cfg.prompts, list(case.config.objects))
    prompted = check_prompts(specs, case.width, case.height, n, where)
    if not specs:  # a static scene (rose.toml: objects = []): only the interactor
        starts, how = [], "static-scene"
    elif prompted:
        starts = seg.start_from_prompts(specs, where)
        how = "prompt"
    else:
        starts, how = [], ""  # found below, once the hands are known
    t0 = min((f for f, _ in starts), default=0)
    seg.foregrounds_ahead([t for _, t in _order(t0, n)])  # made beside the hands' detector
    found_hands = find_hands(ctx, case.rgb) if cfg.classical.hands else None
    if found_hands is not None and cfg.classical.skin_peel_px > 0:
        seg.skin = skin_histogram(case.rgb, found_hands)
    if specs and not prompted:
        # hands found in a tenth of the frames or more are what touches the objects
        by_hand = found_hands is not None and sum(bool(h) for h in found_hands) >= max(3, 0.1 * n)
        toucher = (lambda t: _hand_pixels(seg, t, found_hands)) if by_hand else (lambda t: interactor_mask(seg, t, []))
        starts = [(0, tr) for tr in seg.discover([s.name for s in specs], toucher, n, where)]
        how = "hand-contact" if by_hand else "interactor-contact"
        if not by_hand:
            ctx.warn(
                f"no prompt, and hands found in {sum(bool(h) for h in found_hands or [])} of {n} frames: the"
                " objects are the regions on the support that what moves in front of the static world came"
                " nearest to (a moving camera's depth edges move too, so where no hand moves anything this is"
                " a guess); give each object a prompt box (rose.toml's prompt = { frame = 0, box = [x0, y0,"
                " x1, y1] }, or --prompt NAME=0:x0,y0,x1,y1)"
            )
    t0 = min((f for f, _ in starts), default=0)
    masks = {s.name: [None] * n for s in specs}
    hands = _follow(seg, specs, starts, _order(t0, n), found_hands, masks)
    tracks_out = []
    for spec in specs:
        area = np.array([m.sum() for m in masks[spec.name]], dtype=float)
        typical = float(np.median(area[area > 0])) if np.any(area > 0) else 1.0
        tracks_out.append(MaskTrack(spec.name, iter(masks[spec.name]), np.clip(area / typical, 0.0, 1.0)))
    tracks_out.append(MaskTrack(INTERACTOR, iter(hands)))
    author_and_check(
        ctx,
        tracks_out,
        lambda name: InputError(f"object {name!r} was never found", path=where, hint="check its prompt box"),
        start=how,
        frames_with_hands_found=None if found_hands is None else sum(bool(h) for h in found_hands),
        lift_m=round(seg.lift, 4),
        support_relief_mm=support.relief_mm(),
    )


def _order(t0: int, n: int) -> list[tuple[int, int]]:
    """(direction, frame) in the order the masks are followed: forward from t0, then back from it."""
    return [(+1, t) for t in range(t0, n)] + [(-1, t) for t in range(t0 - 1, -1, -1)]


def _follow(seg: Segmenter, specs, starts, order, found_hands, masks: dict) -> list[np.ndarray | None]:
    """Every frame's object masks (into ``masks``) and interactor mask (returned), in ``order``
    (forward from the first prompted frame, then back from it), the next frame's reading made on a
    worker thread meanwhile (``Segmenter.prefetch``; the foregrounds are already under way:
    ``Segmenter.foregrounds_ahead``)."""
    n = len(order)
    height, width = seg.height, seg.width
    t0 = order[0][1]
    hands: list[np.ndarray | None] = [None] * n
    hand_hist = None
    tracks = []
    for i, (direction, t) in enumerate(progress(order, "segment", total=n)):
        if i + 1 < n:
            seg.prefetch(order[i + 1][1])
        if not tracks or (direction < 0 and t == t0 - 1):  # (re)start from the prompts
            tracks = [tr.copy() for _, tr in starts]
        active = [k for k, (f, _) in enumerate(starts) if direction < 0 or f <= t]
        found = hand_mask(found_hands[t], (height, width)) if found_hands and found_hands[t] else None
        arm = (
            arm_mask(seg, t, found)
            if found is not None
            else following_arm(seg, t, hands[t - direction] if 0 <= t - direction < n else None)
        )
        out = seg.step(t, [tracks[k] for k in active], hand_hist, found, arm, arm_found=found is not None)
        objs = [np.zeros((height, width), bool) for _ in specs]
        for k, m in zip(active, out):
            objs[k] = m
        hand = interactor_mask(seg, t, objs, hand_hist)
        if found is not None:
            hand |= found & ~np.any(objs, axis=0) if objs else found
        # the hand's colors, from its pixels away from the objects (a missed bit of an object
        # must not teach the hand model the object's colors)
        near_obj = (
            cv2.dilate(np.any(objs, axis=0).astype(np.uint8), np.ones((15, 15), np.uint8)).astype(bool)
            if objs
            else np.zeros_like(hand)
        )
        far_hand = hand & ~near_obj
        if far_hand.sum() > MIN_REGION_PX * seg.scale_px:
            hh = histogram(seg.frame(t).cidx[far_hand])
            hand_hist = hh if hand_hist is None else 0.9 * hand_hist + 0.1 * hh
        for spec, m in zip(specs, objs):
            masks[spec.name][t] = m
        hands[t] = hand
    return hands


def _hand_pixels(seg: Segmenter, t: int, found_hands: list[list[Hand]]) -> np.ndarray:
    shape = seg.frame(t).depth.shape
    return hand_mask(found_hands[t], shape) if found_hands[t] else np.zeros(shape, bool)
