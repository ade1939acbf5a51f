"""The ``flow`` segment backend: object masks in 2D, for videos without depth (RGB only).

No learned model and no capture stage: it needs a prompt box (or point) per object (a static
scene, ``objects = []``, gets the hands MediaPipe finds as its interactor alone), and works at
a working resolution whose long side is at most ``segment.flow.max_side_px``.

1. **Start.** GrabCut inside the prompt box gives the object (prompts of one frame share no pixel:
   a patch two of them take goes to the object whose box it helps fill, ``core.grabcut.split_shared``;
   a box's prompt holds the lower half of the can standing on it); its color model is learned
   against the ring of pixels around the box, half and half with the colors of its whole surface where its
   mesh (rose.toml's ``mesh``, ``perception/``) has a texture or vertex colors (the faces a hand
   turns up later are not in the prompt frame; the share fades as the track learns, see
   ``LOOK_WEIGHT``). Regions elsewhere in the prompt frame that the object's
   color model also claims (other red cups in a shell game) become *look-alikes*: they are
   tracked with the objects, so that when they touch, every pixel goes to the track it came from.
2. **Propagate** (forward from the prompt frame, then backward). Dense optical flow (OpenCV's DIS)
   moves each track's mask from the previous frame; pixels the color model claims are given to
   the nearest moved shape within reach of it; GrabCut in the track's neighborhood refines the
   boundary, with the other tracks' pixels as sure background. Each track keeps its whole shape
   from its last clear view and moves it rigidly by the median flow of what is seen of it, so a
   track hidden by the hand or passing behind another keeps its shape and is not absorbed by its
   neighbor; where shapes overlap, the one standing lower in the image is in front. A track at
   rest stays with the static background (the camera's homography of the flow) unless its pixels
   match the next frame clearly better moved by the flow (an arm sweeping over it drags the flow
   of what it covers), and a hidden one that was at rest stays there; one mostly hidden in the
   last frame moves to where its colors are clearly seen again near it, off the hands and the
   other tracks (``segment.refind``: the flow over it was its occluder's). A track that moved
   since the last frame takes no pixel of the static background (a still camera's temporal
   median): what is carried is not what it leaves behind. A track resting while its color model
   is broad (a mesh's texture) takes no pixel that moved relative to it (backward flow): the mug
   carried past the resting cube. Confidence is the visible fraction of the shape.
3. **Hands** (``segment.flow.hands``): MediaPipe's hand landmarks (``segment.hands``), found in
   every frame before propagating, are no track's pixels but where a track's color model claims
   them over the hands' skin (fingers guessed behind the object); the arm (the motion foreground
   joined to a hand and, with a still camera, the bare arm the skin's colors find off the static
   background and the tracks' colors, ``segment.hands.skin_arm``) is no track's beyond its reach.
4. **Interactor** (a 2D motion cue, no depth). What differs from the static background:
   the per-pixel temporal median of the video when the camera stands still (of the frames where
   no found hand or bare arm covers the pixel; chroma weighted over lightness, so shadows count
   less), else the pixels whose flow departs from the camera's (a
   RANSAC homography of the flow); minus the tracks and what the objects' color models claim
   within a track's reach; plus the found hands' and bare arms' pixels that no track took.
"""

from __future__ import annotations

import functools
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass

import cv2
import numpy as np

from rose_usd.core.grabcut import SEEDS, box_grabcut, split_shared
from rose_usd.errors import InputError
from rose_usd.geometry.hands import Hand, hand_mask
from rose_usd.io.meshfile import read_mesh_file, surface_colors
from rose_usd.progress import progress
from rose_usd.segment.colors import color_index, histogram, surface_histogram
from rose_usd.segment.hands import SKIN_RATIO, BareArms, skin_histogram
from rose_usd.segment.hands import found_hands as find_hands
from rose_usd.segment.moving import MotionForeground, camera_shift
from rose_usd.segment.prompts import check_prompts, parse_prompts, prompts_source
from rose_usd.segment.refind import find_hidden
from rose_usd.segment.regions import components, fill_holes, grown, touching
from rose_usd.segment.tracks import INTERACTOR, MaskTrack, author_and_check
from rose_usd.stage_api import StageContext

MOVING_PX = 2.0
"""A track whose shape moved by more than this between frames [px] is carried: the static
background's pixels are not its (the tangram box under DeepAC's cat became part of the cat's
shape while the cat was lifted off it, and held the track there when the cat left)."""

LOOK_WEIGHT = 0.5
"""Share of a given mesh's texture in an object's color model at the prompt frame (the rest: what
that frame shows of it), which shows one side; a hand turns up the others. Each clear, whole view
then mixes 5 % of what it sees into the model, so the texture's share fades (2 % after 60 such
frames). Keeping it at this share for the whole video was worse on visp-cube-hand-rgb (the cube's
silhouette vs masks IoU 0.80 -> 0.53, the gate failed): the texture's colors then claim the hand
and the desk whenever they are near."""

STILL_GRAY = 8.0
"""A pixel tells whether a track stayed or moved where one way matches it by this many gray levels better."""

VOTE_BAND_PX = 6
"""Pixels of a track this near its hidden part do not vote (``FlowTracker._votes``) [px]: dense
flow bleeds from an occluder's moving edge over them."""

VOTE_MARGIN = 2.0
"""A resting track starts to move with the flow (a carried one stops) only where this many times
more of its pixels say so than say not (``FlowTracker._votes``): a plain red block half hidden by
an arm sweeping over it matched 74 of its pixels better at rest, 76 moved with the arm's flow; a
plain block that moves matches better moved at its trailing edge, and nowhere better at rest."""

MOVER_PX = 3.0
"""A pixel that moved this much more than a resting track since the last frame is not the track's,
where the track's color model is broad (``Track2D.broad``). Not for every track: in sam2-cups the
shape of a cup pushed by a hand lags it, the cup's own pixels then look like movers (its visible
fraction fell from 0.82 to 0.68)."""

POINT_BOXES = (0.1, 0.2, 0.4)
"""The widths of the boxes a point prompt's GrabCut tries in turn, as shares of the image's long side."""

FLOW_AHEAD = 3
"""Flows made ahead of the propagation on a second thread (``FlowTracker.plan``)."""

_REACH = 0.35
"""A pixel can join a track within this fraction of the track's size (sqrt of its area) of its moved mask."""


def claims(fg: np.ndarray, bg: np.ndarray) -> np.ndarray:
    """Per color bin: whether a track whose color model is ``fg`` claims it against the background
    model ``bg``: likelier under ``fg``, and seen by one of them. A color neither saw lies on both
    histograms' floors (``colors.histogram``), and the floor of a model made from fewer pixels
    lies higher: the track's won every such color (default push-box-s103, rgb: the box's 8 531
    prompt pixels against its ring's 71 588 claimed the pushing hand's peach 9 to 1, a whole view
    then taught the box the hand's colors; mask IoU 0.45)."""
    seen = (fg > 2.0 * fg.min()) | (bg > 2.0 * bg.min())
    return (fg > bg) & seen


def _reach_px(tr: "Track2D") -> float:
    """How far from a track's shape a pixel can still join it [px]."""
    return _REACH * np.sqrt(tr.typical_px) + 3.0


@dataclass
class Track2D:
    name: str
    mask: np.ndarray
    """The whole shape (working resolution) from the last clear view, moved with the object."""
    fg: np.ndarray
    """Color model (histogram over color_index bins)."""
    typical_px: float
    """The track's area when fully visible."""
    is_object: bool = True
    broad: bool = False
    """Its color model holds colors the prompt frame did not show (a mesh's texture): it claims
    other things' colors too (the browns and blues of a mug carried past a textured cube)."""
    last_visible: np.ndarray | None = None
    """What was seen of it in the last frame (empty when hidden)."""
    carried: bool = False
    """Whether it moved against the static background when half of it or more was last seen (``MOVING_PX``)."""

    def __post_init__(self):
        if self.last_visible is None:
            self.last_visible = self.mask.copy()


def _work_size(width: int, height: int, max_side: int) -> tuple[int, int, float]:
    s = min(1.0, max_side / max(width, height))
    return int(round(width * s)), int(round(height * s)), s


@dataclass(frozen=True)
class HandPixels:
    """The found hands of one frame (working resolution): their landmark masks (``hand``) and
    the arm (what the motion foreground joins to them, and the bare arm ``_bare_arm`` finds: ``arm``)."""

    hand: np.ndarray
    arm: np.ndarray
    skin: np.ndarray | None
    """Color histogram of the hands' skin (``segment.hands.skin_histogram``), or None."""

    def not_of(self, tr: Track2D, idx: np.ndarray, moved: np.ndarray) -> np.ndarray:
        """The pixels track ``tr`` may not take: the hands' landmark masks, but for pixels its
        color model claims over the skin's (a finger guessed behind the object covers it there),
        and the arm beyond the track's reach of its moved shape ``moved`` (the arm that reaches
        past it; nearer, the object it holds is joined to it)."""
        near = grown(moved, _reach_px(tr))
        hand = self.hand if self.skin is None else self.hand & ~(tr.fg[idx] > SKIN_RATIO * self.skin[idx])
        return hand | (self.arm & ~near)


class FlowTracker:
    """Masks of prompted objects (and their look-alikes) through a video, in 2D."""

    def __init__(self, frame_of, size: tuple[int, int], skin: np.ndarray | None = None):
        self.frame_of = frame_of
        """t -> RGB frame (H, W, 3) uint8 at the working resolution."""
        self.w, self.h = size
        self.skin = skin
        """Color histogram of the hands' skin, or None."""
        self.dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)
        self._pool: ThreadPoolExecutor | None = None
        self._ahead: dict[tuple[int, int], Future] = {}
        self._plan: list[tuple[int, int]] = []
        self._next = 0

    # ----------------------------------------------------------------- start
    def cut(self, name: str, t: int, box, point) -> tuple[np.ndarray, tuple[int, int, int, int]]:
        """GrabCut of a prompt: the mask and the box (x0, y0, x1, y1) clipped to the image. A point
        prompt cuts a box around it a tenth of the image wide, then a fifth, then two fifths, until
        the cut stays off the box's sides (``POINT_BOXES``): a box inside the object leaves GrabCut
        no background to tell it from (a white mug filling a sixth of the frame)."""
        rgb = self.frame_of(t)
        if box is not None:
            clipped = self._clip(box)
            mask = box_grabcut(rgb, clipped, seeds=SEEDS, connectivity=4)
            if not mask.any():
                raise InputError(
                    f"GrabCut found nothing inside the prompt of {name!r} on frame {t}",
                    hint="draw the box tightly around the object",
                )
            return mask, clipped
        found = None
        for share in POINT_BOXES:
            r = int(round(share * max(self.w, self.h) / 2))
            clipped = self._clip((point[0] - r, point[1] - r, point[0] + r, point[1] + r))
            mask = box_grabcut(rgb, clipped, seeds=1, connectivity=4)
            if mask.any():
                found = (mask, clipped)
                if not _reaches_sides(mask, clipped, (self.w, self.h)):
                    break
        if found is None:
            raise InputError(
                f"GrabCut found no object around the point prompt of {name!r} on frame {t}",
                hint=f"give a box around the object instead: --prompt {name}={t}:x0,y0,x1,y1 in pixels",
            )
        return found

    def _clip(self, box) -> tuple[int, int, int, int]:
        return tuple(int(np.clip(v, 0, lim)) for v, lim in zip(box, (self.w, self.h, self.w, self.h)))

    def start(
        self, name: str, t: int, mask: np.ndarray, box: tuple[int, int, int, int], look: np.ndarray | None = None
    ) -> tuple[Track2D, np.ndarray]:
        """A track of the object ``mask`` shows in frame t (its prompt's cut, ``box``); returns it
        and the background color model of the prompt's surroundings. ``look``: the color model of
        the object's whole surface (its mesh's texture, ``surface_histogram``), mixed into the
        track's by ``LOOK_WEIGHT``."""
        rgb = self.frame_of(t)
        x0, y0, x1, y1 = box
        bw, bh = x1 - x0, y1 - y0
        ring = np.zeros_like(mask)
        ring[max(0, y0 - bh) : y1 + bh, max(0, x0 - bw) : x1 + bw] = True
        ring &= ~cv2.dilate(mask.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
        idx = color_index(rgb)
        fg = histogram(idx[mask])
        if look is not None:
            fg = (1.0 - LOOK_WEIGHT) * fg + LOOK_WEIGHT * look
        return Track2D(name, mask, fg, float(mask.sum()), broad=look is not None), histogram(idx[ring])

    def look_alikes(self, t: int, tracks: list[Track2D], bg: np.ndarray) -> list[Track2D]:
        """Regions of frame t outside the tracks that their color models claim, as large as them."""
        idx = color_index(self.frame_of(t))
        taken = np.any([tr.mask for tr in tracks], axis=0)
        claimed = np.zeros_like(taken)
        for tr in tracks:
            claimed |= tr.fg[idx] > 2.0 * bg[idx]
        claimed = cv2.morphologyEx(
            (claimed & ~taken).astype(np.uint8), cv2.MORPH_OPEN, np.ones((3, 3), np.uint8)
        ).astype(bool)
        n, labels, areas = components(claimed)
        smallest = min(tr.typical_px for tr in tracks)
        out = []
        for label in range(1, n):
            if areas[label] >= 0.3 * smallest:
                m = labels == label
                out.append(
                    Track2D(f"look-alike {len(out) + 1}", m, histogram(idx[m]), float(areas[label]), is_object=False)
                )
        return out

    # ----------------------------------------------------------------- propagate
    def flow(self, a: int, b: int) -> np.ndarray:
        """Dense flow (H, W, 2) from frame a to frame b [px] (made ahead where ``plan`` has it)."""
        made = self._ahead.pop((a, b), None)
        out = made.result() if made is not None else self._calc(self.dis, a, b)
        if self._pool is not None and (a, b) in self._plan[self._next : self._next + FLOW_AHEAD]:
            self._advance(self._plan.index((a, b), self._next) + 1)
        return out

    def _calc(self, dis, a: int, b: int) -> np.ndarray:
        ga = cv2.cvtColor(self.frame_of(a), cv2.COLOR_RGB2GRAY)
        gb = cv2.cvtColor(self.frame_of(b), cv2.COLOR_RGB2GRAY)
        return dis.calc(ga, gb, None)

    def plan(self, pairs: list[tuple[int, int]]) -> None:
        """The flows (a, b) the propagation will ask for, in that order: each is made on a worker
        thread ``FLOW_AHEAD`` asks ahead, beside the propagation (OpenCV's DIS leaves the GIL;
        the worker has its own instance, and the flows are the same)."""
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="segment-flow")
        self._calc_ahead = functools.partial(self._calc, cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM))
        self._plan, self._next = list(pairs), 0
        self._advance(0)

    def _advance(self, to: int) -> None:
        """The plan moves to its entry ``to``: drop what was made for entries before it and not
        asked for (a flow back to the frame before, where no track rested), make the next ones."""
        for pair in self._plan[self._next : to]:
            made = self._ahead.pop(pair, None)
            if made is not None:
                made.cancel()
        self._next = to
        for pair in self._plan[to : to + FLOW_AHEAD]:
            if pair not in self._ahead:
                self._ahead[pair] = self._pool.submit(self._calc_ahead, *pair)

    def close(self) -> None:
        """Stop the worker thread of ``plan``."""
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool, self._ahead, self._plan = None, {}, []

    def _shift(
        self, tr: Track2D, flow: np.ndarray, camera: np.ndarray | None, prev: int, t: int
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """How the track's shape moves (dx, dy) [px] from frame ``prev`` to ``t``, and how the
        static background moves there (None without ``camera``): the median
        flow of what was seen of it (a hand over part of an object does not drag its shape along),
        or the static background's (``camera``: the camera's homography from ``prev``, the
        identity for a still camera; None where unknown: the flow alone), whichever its pixels
        favour (``_votes``, each pixel by its own flow, away from its hidden part; a resting
        track needs ``VOTE_MARGIN`` times more pixels to start to move, a carried one to stop). A
        hidden track that rested when last seen stays with the background: the flow over it is its
        occluder's (default unstack-can-s100, rgb: an arm sweeping over the base can dragged its
        shape 40 px off, and the can, seen again, was not found for 45 frames); a hidden track
        that was carried goes with what covers it (the hand that holds it)."""
        part = tr.last_visible if tr.last_visible is not None and tr.last_visible.sum() >= 20 else None
        still = camera_shift(camera, tr.mask) if camera is not None else None
        if part is None and still is not None and not tr.carried:
            return still, still
        if part is None:
            return (np.median(flow[tr.mask], axis=0) if tr.mask.any() else np.zeros(2)), still
        shift = np.median(flow[part], axis=0)
        if still is None or np.hypot(*(shift - still)) <= MOVING_PX:
            return shift, still
        # pixels beside the part of the shape not seen are left out: what hides it moves there
        hidden = grown(tr.mask & ~part, VOTE_BAND_PX)
        for_still, for_moved = self._votes(part & ~hidden, flow, still, prev, t)
        # a track keeps resting, or keeps being carried, unless clearly more pixels say otherwise
        if tr.carried:
            return (still if for_still > VOTE_MARGIN * for_moved else shift), still
        return (shift if for_moved > VOTE_MARGIN * for_still else still), still

    def _votes(self, seen: np.ndarray, flow: np.ndarray, still, prev: int, t: int) -> tuple[int, int]:
        """How many pixels ``seen`` of frame ``prev`` match frame t better (gray levels, by more
        than ``STILL_GRAY``) moved by ``still`` (with the background) than each by its own
        ``flow``, and the other way round. An arm sweeping over a resting object: the flow of the
        pixels it covers is the arm's, and their median goes with it; the pixels still seen match
        where they were (sam2-cups: the middle cup rests while another is carried in front of it,
        frames 96-104; its mask went with the passing cup). An object turned in the hand matches
        its flow pixel by pixel where no one shift does (visp-cube-hand-rgb's masks are the same
        as when the median flow alone moved the shape; with the median as the moved way, they
        left the turned cube); a plain one carried matches both ways where it overlaps itself,
        and only the flow's way at its trailing edge."""
        a = cv2.cvtColor(self.frame_of(prev), cv2.COLOR_RGB2GRAY).astype(np.float32)
        b = cv2.cvtColor(self.frame_of(t), cv2.COLOR_RGB2GRAY).astype(np.float32)
        ys, xs = np.nonzero(seen)

        def error(d) -> np.ndarray:
            u = np.clip(np.round(xs + d[..., 0]).astype(int), 0, self.w - 1)
            v = np.clip(np.round(ys + d[..., 1]).astype(int), 0, self.h - 1)
            return np.abs(b[v, u] - a[ys, xs])

        e_still, e_moved = error(np.asarray(still)), error(flow[ys, xs])
        return int(np.count_nonzero(e_still + STILL_GRAY < e_moved)), int(
            np.count_nonzero(e_moved + STILL_GRAY < e_still)
        )

    def _moved(self, tr: Track2D, shift: np.ndarray) -> np.ndarray:
        """The track's whole shape moved rigidly by ``shift`` (dx, dy) [px]."""
        if not np.any(shift):
            return tr.mask
        warp = np.float32([[1, 0, shift[0]], [0, 1, shift[1]]])
        return cv2.warpAffine(tr.mask.astype(np.uint8), warp, (self.w, self.h), flags=cv2.INTER_NEAREST).astype(bool)

    def step(
        self,
        prev: int,
        t: int,
        tracks: list[Track2D],
        bg: np.ndarray,
        flow: np.ndarray,
        static=None,
        hand: HandPixels | None = None,
        camera: np.ndarray | None = None,
    ) -> list[float]:
        """Move every track from frame ``prev`` to frame ``t`` along ``flow`` (``self.flow(prev,
        t)``); returns each track's visible fraction. ``static``: (t, prev) -> bool image of the
        pixels of frame t that show the static background (``MotionForeground.background``), or
        None: a track that moved by more than ``MOVING_PX`` takes none of them (what it carries is
        not the background behind it). ``hand``: the found hands of frame t; their pixels are no
        track's (``HandPixels.not_of``). ``camera``: the camera's homography from frame ``prev``
        (the identity for a still camera), None where unknown (``_shift``)."""
        rgb = self.frame_of(t)
        idx = color_index(rgb)
        shifts = []
        for tr in tracks:
            d, still = self._shift(tr, flow, camera, prev, t)
            shifts.append(d)
            # judged on half a view or more: the flow of a sliver beside its occluder is the occluder's
            if still is not None and tr.last_visible is not None and tr.last_visible.sum() >= 0.5 * tr.typical_px:
                tr.carried = bool(np.hypot(*(d - still)) > MOVING_PX)
        moved = self._all_moved(tracks, shifts, idx, bg, hand)
        carried = [static is not None and np.hypot(*d) > MOVING_PX for d in shifts]
        resting = [tr.broad and np.hypot(*d) <= MOVING_PX for tr, d in zip(tracks, shifts)]
        # how each pixel of frame t moved since frame prev: for a resting track with a broad color
        # model, what moved by more than MOVER_PX relative to it (a mug carried past a cube at
        # rest, the hand reaching for it) is something else
        motion = -self.flow(t, prev) if any(resting) else None
        still = static(t, prev) if any(carried) else None
        # ownership: every claimed pixel goes to the nearest moved shape within its reach
        dist = np.full((len(tracks), self.h, self.w), np.inf, np.float32)
        for k, (tr, m) in enumerate(zip(tracks, moved)):
            if m.any():
                d = cv2.distanceTransform((~m).astype(np.uint8), cv2.DIST_L2, 3)
                dist[k] = np.where(d <= _reach_px(tr), d, np.inf)
        owner = np.argmin(dist, axis=0)
        reachable = np.isfinite(np.min(dist, axis=0))
        # where moved shapes overlap, one object passes in front of another: on a tabletop seen
        # from above and in front, the one whose bottom is lower in the image is nearer
        inside = dist == 0
        contested = inside.sum(axis=0) > 1
        if contested.any():
            bottom = np.array([np.nonzero(m.any(axis=1))[0].max() if m.any() else -1 for m in moved])
            front = np.argmax(np.where(inside, bottom[:, None, None], -2), axis=0)
            owner[contested] = front[contested]
        touching = [bool(np.any(contested & inside[k])) for k in range(len(tracks))]
        bgr = cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)
        visible = []
        for k, tr in enumerate(tracks):
            mine = reachable & (owner == k)
            claimed = mine & claims(tr.fg, bg)[idx]
            if carried[k] and still is not None:  # None: the camera moves
                claimed &= ~still
            others = [moved[j] for j in range(len(tracks)) if j != k]
            if hand is not None:
                off = hand.not_of(tr, idx, moved[k])
                claimed &= ~off
                others.append(off)
            if resting[k]:  # resting and broad
                movers = np.linalg.norm(motion - shifts[k], axis=2) > MOVER_PX
                claimed &= ~movers
                others.append(movers)
            m = self._refine(bgr, claimed, mine, moved[k], others)
            frac = float(m.sum()) / tr.typical_px
            visible.append(min(frac, 1.0))
            if 0.85 < frac < 1.3 and not touching[k]:
                # a clear, whole view: it becomes the shape, and teaches the look as it turns
                tr.mask = m
                tr.fg = 0.95 * tr.fg + 0.05 * histogram(idx[m])
                tr.typical_px = 0.95 * tr.typical_px + 0.05 * float(m.sum())
            else:  # partly hidden or touching another: its last whole shape, moved
                tr.mask = moved[k]
            tr.last_visible = m if frac >= 0.05 else np.zeros_like(m)
        return visible

    def _all_moved(self, tracks, shifts, idx, bg, hand: HandPixels | None) -> list[np.ndarray]:
        """Each track's shape moved by its shift, or where ``segment.refind`` finds a hidden one
        again (its entry of ``shifts`` updated in place)."""
        moved = [self._moved(tr, d) for tr, d in zip(tracks, shifts)]
        blocked = hand.hand | hand.arm if hand is not None else None
        for k, offset in find_hidden(tracks, moved, idx, bg, self.skin, blocked).items():
            shifts[k] = shifts[k] + offset
            moved[k] = self._moved(tracks[k], shifts[k])
        return moved

    def _refine(
        self, bgr: np.ndarray, claimed: np.ndarray, mine: np.ndarray, moved: np.ndarray, others: list[np.ndarray]
    ) -> np.ndarray:
        """GrabCut around a track: claimed pixels are probable object, its moved mask's core sure
        object where claimed, other tracks sure background."""
        if claimed.sum() < 20:
            return np.zeros_like(claimed)
        ys, xs = np.nonzero(claimed | moved)
        pad = 12
        y0, y1 = max(0, ys.min() - pad), min(self.h, ys.max() + pad + 1)
        x0, x1 = max(0, xs.min() - pad), min(self.w, xs.max() + pad + 1)
        gc = np.full((y1 - y0, x1 - x0), cv2.GC_PR_BGD, np.uint8)
        c = claimed[y0:y1, x0:x1]
        gc[c] = cv2.GC_PR_FGD
        core = cv2.erode((claimed & moved).astype(np.uint8), np.ones((7, 7), np.uint8)).astype(bool)[y0:y1, x0:x1]
        gc[core] = cv2.GC_FGD
        for o in others:
            gc[o[y0:y1, x0:x1] & ~c] = cv2.GC_BGD
        gc[~mine[y0:y1, x0:x1] & ~c] = cv2.GC_BGD
        if not np.any(gc == cv2.GC_FGD) and not np.any(gc == cv2.GC_PR_FGD):
            return np.zeros_like(claimed)
        if np.any((gc == cv2.GC_BGD) | (gc == cv2.GC_PR_BGD)):
            bgd, fgd = np.zeros((1, 65)), np.zeros((1, 65))
            try:
                cv2.grabCut(np.ascontiguousarray(bgr[y0:y1, x0:x1]), gc, None, bgd, fgd, 2, cv2.GC_INIT_WITH_MASK)
            except cv2.error:  # too few samples of one side for its color model: keep the claim
                pass
        out = np.zeros_like(claimed)
        out[y0:y1, x0:x1] = (gc == cv2.GC_FGD) | (gc == cv2.GC_PR_FGD)
        out &= mine
        # keep the parts that overlap where the track was carried
        return fill_holes(touching(out, moved, grow_px=4), max_hole_px=int(0.05 * out.sum()) + 1)


def segment_video(
    frame_of,
    n: int,
    size: tuple[int, int],
    prompts: list[tuple[str, int, tuple | None, tuple | None]],
    *,
    interactor: bool = True,
    looks: dict[str, np.ndarray] | None = None,
    found: list[list[Hand]] | None = None,
    skin: np.ndarray | None = None,
):
    """Masks of each prompted object and of the interactor over ``n`` frames (working resolution).

    ``prompts``: (name, frame, box, point) with box/point in working-resolution pixels. Returns
    ({name: [mask per frame]}, [interactor mask per frame], {name: visible fraction per frame}).
    ``looks``: {name: color model of the object's surface} for objects whose mesh has colors.
    ``found``: the hands of every frame (``segment.hands.found_hands``, working-resolution
    pixels), whose pixels are the interactor's; ``skin``: their skin's color histogram.

    GrabCut's color models start from OpenCV's random generator (per thread, shared with anything
    else that ran before): it is reset here, so the masks depend on the video alone."""
    cv2.setRNGSeed(0)  # the generator's initial state (0 selects OpenCV's default seed)
    tracker = FlowTracker(frame_of, size, skin)
    starts = _starts(tracker, frame_of, prompts, looks)
    t0 = min(t for t, _, _ in starts)
    bg = np.mean([b for _, _, b in starts], axis=0)
    names = [tr.name for _, tr, _ in starts]
    masks = {k: [None] * n for k in names}
    visible = {k: np.zeros(n) for k in names}
    arms = BareArms(frame_of, found, skin, (tracker.h, tracker.w))
    motion = MotionForeground(tracker, n, cover=arms.cover) if interactor else None
    hands: list[np.ndarray | None] = [None] * n

    def fresh():
        tracks = [Track2D(tr.name, tr.mask.copy(), tr.fg.copy(), tr.typical_px, broad=tr.broad) for _, tr, _ in starts]
        return tracks + tracker.look_alikes(t0, tracks, bg)

    order = [(+1, t) for t in range(t0, n)] + [(-1, t) for t in range(t0 - 1, -1, -1)]
    # each step's flow from the frame before (t - 1 forward, t + 1 backward), and back to it where
    # a broad track may rest (``FlowTracker.step``), made ahead on a second thread
    back = any(tr.broad for _, tr, _ in starts)
    steps = [(t - 1 if t > t0 else t + 1, t) for _, t in order[1:]]
    tracker.plan([pair for p, t in steps for pair in ([(p, t), (t, p)] if back else [(p, t)])])
    tracks, prev = fresh(), None
    try:
        for direction, t in progress(order, "segment (flow)", total=n):
            flow = None
            if direction < 0 and t == t0 - 1:
                tracks, prev = fresh(), t0
            if prev is not None:
                flow = tracker.flow(prev, t)
            camera = motion.camera(flow) if motion is not None else None
            moving = motion(t, flow, camera) if motion is not None else None
            hand = bare = None
            if found and found[t]:
                bare = _bare_arm(arms, motion, t, tracks, skin)
                hand = _hand_pixels(found[t], moving, bare, skin, (tracker.h, tracker.w))
            if prev is None:  # the prompt frame itself
                fracs = [1.0] * len(tracks)
            else:
                static = motion.background if motion is not None else None
                fracs = tracker.step(prev, t, tracks, bg, flow, static, hand, camera)
            prev = t
            everything = np.zeros((tracker.h, tracker.w), bool)
            for tr, frac in zip(tracks, fracs):
                everything |= tr.last_visible
                if tr.is_object:
                    masks[tr.name][t] = tr.last_visible.copy()
                    visible[tr.name][t] = frac
            hands[t] = _interactor(tracker.frame_of(t), tracks, bg, everything, moving, hand, bare)
    finally:
        tracker.close()
    return masks, hands, visible


def _bare_arm(arms: BareArms, motion: MotionForeground | None, t: int, tracks, skin) -> np.ndarray | None:
    """Frame t's bare arm (``segment.hands.skin_arm``) with a still camera, off its known background
    and off what a track's color model claims over the skin's within its reach (a cube's peach face
    joined to the hand turning it); None where the camera moves or no hand is found."""
    if motion is None or not motion.static_camera:
        return None
    bare = arms(t)
    if bare is None:
        return None
    idx = color_index(arms.frame_of(t))
    claimed = np.any([tr.fg[idx] > SKIN_RATIO * skin[idx] for tr in tracks if tr.is_object], axis=0)
    return bare & ~motion.shows_background(t) & ~(claimed & _within_reach(tracks))


def _interactor(rgb, tracks, bg, everything, moving, hand: HandPixels | None, bare) -> np.ndarray | None:
    """A frame's interactor: what moves (``moving``, None without the motion cue) but the tracks'
    pixels (``everything``) and what their color models claim within their reach (a look-alike
    the tracks lost is still not the hand; a dark sleeve far from a mug with dark speckles is);
    with the found hands' and their bare arms' pixels (``hand``, ``bare``) that no track took."""
    out = None
    if moving is not None:
        idx = color_index(rgb)
        claimed = np.any([tr.fg[idx] > 2.0 * bg[idx] for tr in tracks if tr.is_object], axis=0)
        out = moving & ~cv2.dilate(
            (everything | (claimed & _within_reach(tracks))).astype(np.uint8), np.ones((5, 5), np.uint8)
        ).astype(bool)
    if hand is not None:
        untaken = (hand.hand if bare is None else hand.hand | bare) & ~everything
        out = untaken if out is None else out | untaken
    return out


def _starts(tracker: FlowTracker, frame_of, prompts, looks) -> list[tuple[int, Track2D, np.ndarray]]:
    """Each prompt's track and background color model, (frame, track, background), from its cut;
    the cuts of one frame share no pixel (``core.grabcut.split_shared``)."""
    cuts = {name: tracker.cut(name, t, box, point) for name, t, box, point in prompts}
    for t in {t for _, t, _, _ in prompts}:  # prompts of one frame share no pixel
        names = [name for name, frame, _, _ in prompts if frame == t]
        boxed = {name for name, _, box, _ in prompts if box is not None}
        split = split_shared(
            {name: cuts[name][0] for name in names}, {name: cuts[name][1] if name in boxed else None for name in names}
        )
        cuts.update({name: (split[name], cuts[name][1]) for name in names})
    starts = []
    for name, t, _, _ in prompts:
        mask, box = cuts[name]
        if not mask.any():
            raise InputError(
                f"the prompt of {name!r} on frame {t} holds nothing that another prompt does not claim",
                hint="draw each object's box around that object",
            )
        track, bg = tracker.start(name, t, mask, box, (looks or {}).get(name))
        starts.append((t, track, bg))
    return starts


def _reaches_sides(mask: np.ndarray, box: tuple[int, int, int, int], size: tuple[int, int]) -> bool:
    """Whether ``mask`` comes within 2 px of a side of ``box`` that is not the image's edge."""
    x0, y0, x1, y1 = box
    ys, xs = np.nonzero(mask)
    w, h = size
    return bool(
        (x0 > 0 and xs.min() <= x0 + 1)
        or (y0 > 0 and ys.min() <= y0 + 1)
        or (x1 < w and xs.max() >= x1 - 2)
        or (y1 < h and ys.max() >= y1 - 2)
    )


def _hand_pixels(found: list[Hand], moving: np.ndarray | None, bare: np.ndarray | None, skin, shape) -> HandPixels:
    """Frame t's found hands as pixels: their landmark masks, and the arm (the motion foreground
    ``moving`` that touches them, and the ``bare`` arm their skin's colors find)."""
    hand = hand_mask(found, shape)
    arm = touching(moving | hand, hand, grow_px=2) & ~hand if moving is not None else np.zeros_like(hand)
    return HandPixels(hand, arm | bare if bare is not None else arm, skin)


def _within_reach(tracks: list[Track2D]) -> np.ndarray:
    """The pixels within ``_REACH`` of any track's shape (where a pixel could join it)."""
    near = np.zeros_like(tracks[0].mask)
    for tr in tracks:
        near |= grown(tr.mask, _reach_px(tr))
    return near


def _looks(case, specs) -> dict[str, np.ndarray]:
    """The color model of every object whose mesh (rose.toml's ``mesh``, ``perception/``) has a
    texture or vertex colors."""
    looks = {}
    for spec in specs:
        path = case.mesh_file(spec)
        colors = surface_colors(read_mesh_file(path)) if path is not None else None
        if colors is not None:
            looks[spec.name] = surface_histogram(colors)
    return looks


def run(ctx: StageContext) -> None:
    case = ctx.case
    n = ctx.time_info.n_frames
    cfg = ctx.config
    where = prompts_source(cfg.prompts, case)
    specs = parse_prompts(cfg.prompts, list(case.config.objects))
    check_prompts(specs, case.width, case.height, n, where)
    if any(s.prompt is None for s in specs):
        raise InputError(
            "the flow backend needs a prompt (box or point) for every object",
            path=where,
            hint="add prompt = { frame = 0, box = [x0, y0, x1, y1] } to each [[objects]] of rose.toml, "
            "or pass --prompt NAME=FRAME:x0,y0,x1,y1",
        )
    w, h, s = _work_size(case.width, case.height, cfg.flow.max_side_px)

    @functools.lru_cache(maxsize=64)
    def frame_of(t: int) -> np.ndarray:
        rgb = case.rgb(t)
        return rgb if s == 1.0 else cv2.resize(rgb, (w, h), interpolation=cv2.INTER_AREA)

    prompts = []
    for spec in specs:
        p = spec.prompt
        box = tuple(v * s for v in p.box) if p.box is not None else None
        point = tuple(v * s for v in p.point) if p.point is not None else None
        prompts.append((spec.name, p.frame, box, point))
    found = find_hands(ctx, frame_of) if cfg.flow.hands else None
    if specs:
        skin = skin_histogram(frame_of, found) if found else None
        try:
            masks, hands, visible = segment_video(
                frame_of, n, (w, h), prompts, looks=_looks(case, specs), found=found, skin=skin
            )
        except InputError as e:  # a prompt's cut found nothing: it names the prompts' source
            raise InputError(e.message, path=e.path or where, hint=e.hint) from None
    else:  # a static scene (objects = []): nothing to track, the interactor is the hands found
        masks, visible = {}, {}
        hands = [hand_mask(f, (h, w)) if f else np.zeros((h, w), bool) for f in (found or [[]] * n)]

    def full(frames):
        for m in frames:
            yield (
                m
                if s == 1.0
                else cv2.resize(m.astype(np.uint8), (case.width, case.height), interpolation=cv2.INTER_NEAREST).astype(
                    bool
                )
            )

    tracks = [MaskTrack(spec.name, full(masks[spec.name]), visible[spec.name]) for spec in specs]
    tracks.append(MaskTrack(INTERACTOR, full(hands)))
    author_and_check(
        ctx,
        tracks,
        lambda name: InputError(f"object {name!r} was never found", path=where, hint="check its prompt box"),
        start="prompt",
        working_size=[w, h],
        frames_with_hands_found=None if found is None else sum(bool(f) for f in found),
    )
