"""The depth segmenter (the classical backend's, whose interactor the sam2 backend also uses):
object masks from a prompt (or from what the hand touches) propagated through the video in 3D,
and the interactor as the other moving region. No learned model.

The capture stage gives metric depth, cameras and a gravity-aligned world whose z = 0 is the
support plane, so every pixel has a world point; its height is taken over the support surface
under it (``geometry.support``: the table as the video sees it, which may bend away from z = 0).

1. **Start.** On the prompt frame, the object is the depth-connected region of pixels standing on
   the support (height > ``lift``: ``min_height_m``, raised to the support's measured depth noise
   around the prompt) inside the prompt box (or containing the prompt point). Without a prompt
   it is the region standing on the support at the first frame that the interactor comes nearest
   to over the video ("what the hand moves"). A depth edge may cut one object into pieces (a
   cup's rim); pieces that touch in 3D, or that leave their place in the same frames, are
   joined. With several objects named, that region is first
   split into the part that later leaves its place (seen past in a later frame) and the part that
   stays, for objects stacked on each other. Names of rose.toml go to regions in that order
   (unprompted, nothing else tells which object is which). Prompt regions of one frame that
   overlap (a stack's boxes) are separated: a shared pixel goes to the object whose colors make
   it likelier, else to the nearest pixel only one region claims.
2. **Propagate** (forward from the prompt frame, then backward). In each frame, a pixel belongs to
   the object when it stands on the support (above ``lift``), its world point lies within
   ``shell_m`` (plus half the last motion) of the object's previous points moved by its last
   rigid motion (within ``max(diameter, 3 cm)``, growing, while it is hidden), its color is more
   likely under the object's color model than under the model of its surroundings and the hand,
   and it is depth-connected to a core of pixels within ``core_m`` of the moved points. Pixels
   connected to a found hand (its fingers, its arm, what it holds) are the object's only within
   ``core_m`` of the moved points, inside the silhouette they show and not in front of their
   surface by more than ``occluder_m`` (fingers wrapped around it); an object hidden in the
   frame before, only within ``core_m`` of its stale points. With no hand found, the
   interactor's region of the frame before, followed into this one (``interactor.following_arm``), is
   taken as the arm, by the same rule save the silhouette (a part the points never covered may
   join: a lying can's end cap beside the thumb). A pixel belongs to one
   object at most. Color models are updated as the object turns. The motion
   between frames is rigid: translation-only ICP of the seen points first (not the shift of
   their mean, which occlusion moves), then a turn where it fits clearly better (a cup turned in
   the hand). Points that something now stands in front of are kept, moved along, while they lie
   within the object's size of where it was carried (a finger taken once is not kept behind the
   hand). When the object is hidden (the hand covers it), its last points are kept and the
   search widens until it reappears.
3. **Interactor.** Pixels nearer than the static world (geometry.background) by more than
   ``foreground_m`` (with the sensor's holes between them bridged: a dark sleeve), minus the
   objects, in regions of at least ``min_region_px`` pixels.
"""

from __future__ import annotations

import functools
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from typing import NamedTuple

import cv2
import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from rose_usd.core.pinhole import pixels_of, sample_at, world_points
from rose_usd.errors import InputError
from rose_usd.geometry.background import StaticBackground
from rose_usd.geometry.support import SupportSurface
from rose_usd.segment.colors import color_index, histogram, object_colored
from rose_usd.segment.config import SegmentConfig
from rose_usd.segment.motion import diameter, rigid_motion, rotation_matrix, subsample
from rose_usd.segment.regions import (
    bridge_holes,
    components,
    depth_edges,
    fill_holes,
    grow_across_edges,
    main_part,
    off_surface,
    peel_skin,
    separate,
)

LED_JOIN_PX = 8
"""A mug's outer wall lies this near its inner wall in the image at 640x480 [px] (past the rim
and the depth edge: 4.8 px on the default suite's push-mug-s203)."""


@dataclass
class ObjectTrack:
    name: str
    points: np.ndarray
    """World points of the object's last visible pixels (subsampled), (M, 3)."""
    color: np.ndarray
    """Color histogram of the object."""
    diameter: float
    area: float
    """Visible pixels at the start."""
    velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))
    """The last motion's translation of the points' centre [m per frame] (damped)."""
    spin: np.ndarray = field(default_factory=lambda: np.zeros(3))
    """The last motion's turn about the points' centre, a rotation vector [rad per frame] (damped)."""
    hidden: int = 0
    first_color: np.ndarray | None = None
    """The color model of the start: half of the model always, so a face lost once is not forgotten."""

    def __post_init__(self):
        if self.first_color is None:
            self.first_color = self.color.copy()

    def predicted(self) -> np.ndarray:
        """The points moved by the last motion (turned about their centre, then shifted)."""
        centre = np.median(self.points, axis=0)
        return (self.points - centre) @ rotation_matrix(self.spin).T + centre + self.velocity

    def motion_m(self) -> float:
        """How far the last motion moved the farthest point [m]."""
        radius = 0.5 * self.diameter
        return float(np.linalg.norm(self.velocity) + np.linalg.norm(self.spin) * radius)

    def copy(self) -> "ObjectTrack":
        """An independent copy (propagation updates tracks in place)."""
        return replace(
            self,
            points=self.points.copy(),
            color=self.color.copy(),
            velocity=self.velocity.copy(),
            spin=self.spin.copy(),
            first_color=self.first_color.copy(),
        )


# ----------------------------------------------------------------------------- the segmenter
MIN_REGION_PX = 150
"""The smallest region taken for an object or the interactor, at 640x480 (scaled with the image area)."""


class Frame(NamedTuple):
    rgb: np.ndarray
    depth: np.ndarray
    pts: np.ndarray
    """World point of every pixel (H, W, 3), NaN without depth."""
    edges: np.ndarray
    cidx: np.ndarray
    """Color bin of every pixel."""
    height: np.ndarray
    """Height of every pixel's point over the support surface under it [m] (NaN without depth)."""


class Segmenter:
    def __init__(
        self,
        rgb_of,
        depth_of,
        cameras,
        config: SegmentConfig,
        background: StaticBackground,
        support: SupportSurface | None = None,
    ):
        self.rgb_of, self.depth_of, self.cam, self.config, self.bg = rgb_of, depth_of, cameras, config, background
        self.support = support
        """The support's height per place (None: the world's z = 0 plane is the support)."""
        self.width, self.height = cameras.width, cameras.height
        self.scale_px = self.width * self.height / (640 * 480)
        self.frame = functools.lru_cache(maxsize=5)(self._frame_or_ahead)
        """The ``Frame`` t (the last few are cached)."""
        self._frames_ahead: dict[int, Future] = {}
        """Frames ``prefetch`` was asked for, being made on a worker thread."""
        self._foregrounds_ahead: dict[int, Future] = {}
        """Foregrounds ``foregrounds_ahead`` was asked for (packed bits), being made on another."""
        self._workers: dict[str, ThreadPoolExecutor] = {}
        self.foreground = functools.lru_cache(maxsize=2)(self._foreground)
        """(foreground, static) of frame t (``StaticBackground.foreground`` at ``foreground_m``;
        read-only: the peel, the arm and the interactor of a frame share it)."""
        self.bridged = functools.lru_cache(maxsize=2)(self._bridged)
        """Frame t's foreground with a dark sleeve's sensor holes bridged (``bridge_holes``; read-only)."""
        self.lift = config.min_height_m
        """A pixel stands on the support when its point is this high above the support under it [m]
        (``measure_lift``: at least ``min_height_m``, more where the depth is noisy)."""
        self.skin: np.ndarray | None = None
        """Color histogram of the hands' skin, learnt by the caller from the hands found so far, or
        None: fingers on an object are peeled off its mask (``peel_skin``) only with it."""

    def foregrounds_ahead(self, frames: list[int]) -> None:
        """Start making the foreground of ``frames``, in that order, on a worker thread (the static
        world's depth warped from the reference frames: NumPy and OpenCV, which leave the GIL, so it
        runs beside the hand detector and the tracking). ``foreground`` takes each one made, makes
        those not started itself, and gives the same result either way."""
        pool = self._worker("foregrounds")
        for t in frames:
            if t not in self._foregrounds_ahead:
                self._foregrounds_ahead[t] = pool.submit(self._packed_foreground, t)

    def prefetch(self, t: int) -> None:
        """Start reading frame t (its ``Frame``) on a worker thread, for ``frame`` to take."""
        if t in self._frames_ahead or not 0 <= t < len(self.cam.world_from_cv):
            return
        while len(self._frames_ahead) >= 3:
            del self._frames_ahead[next(iter(self._frames_ahead))]
        self._frames_ahead[t] = self._worker("frames").submit(self._frame, t)

    def close(self) -> None:
        """Stop the worker threads (what they have not started is dropped)."""
        for pool in self._workers.values():
            pool.shutdown(wait=True, cancel_futures=True)
        self._workers.clear()
        self._frames_ahead.clear()
        self._foregrounds_ahead.clear()

    def _worker(self, kind: str) -> ThreadPoolExecutor:
        """The single-thread executor of one kind of work ahead (one each, so neither waits on the other)."""
        if kind not in self._workers:
            self._workers[kind] = ThreadPoolExecutor(max_workers=1, thread_name_prefix=f"segment-{kind}")
        return self._workers[kind]

    def _packed_foreground(self, t: int) -> tuple[np.ndarray, np.ndarray]:
        return tuple(np.packbits(m) for m in self._make_foreground(t))

    def _frame_or_ahead(self, t: int) -> Frame:
        ahead = self._frames_ahead.pop(t, None)
        if ahead is not None and not ahead.cancel():
            return ahead.result()
        return self._frame(t)

    def _frame(self, t: int) -> Frame:
        rgb, depth = self.rgb_of(t), self.depth_of(t)
        pts = world_points(depth, self.cam.K[t], self.cam.world_from_cv[t])
        height = pts[..., 2] if self.support is None else self.support.height_above(pts).astype(np.float32)
        return Frame(rgb, depth, pts, depth_edges(depth), color_index(rgb), height)

    def _foreground(self, t: int) -> tuple[np.ndarray, np.ndarray]:
        ahead = self._foregrounds_ahead.pop(t, None)
        if ahead is not None and not ahead.cancel():
            shape, size = (self.height, self.width), self.height * self.width
            fg, static = (np.unpackbits(m, count=size).view(bool).reshape(shape) for m in ahead.result())
            return fg, static
        return self._make_foreground(t)

    def _make_foreground(self, t: int) -> tuple[np.ndarray, np.ndarray]:
        return self.bg.foreground(t, self.depth_of(t), tau_m=self.config.foreground_m)

    def _bridged(self, t: int) -> np.ndarray:
        return bridge_holes(self.foreground(t)[0], self.frame(t).depth)

    def measure_lift(self, t: int, box: tuple[int, int, int, int] | None = None) -> float:
        """Set and return ``lift`` from frame t: the support pixels' (within 3 cm of the plane,
        around ``box`` = (x0, y0, x1, y1) when given, else everywhere) median height plus four
        robust sigmas, at least ``min_height_m`` and at most 2 cm. A real depth sensor's support
        is rippled and offset by millimetres (a RealSense at 0.8 m: median 2.8 mm, sigma 2 mm),
        and pixels of the support taken for the object carry the track onto the table."""
        depth, height = self.frame(t).depth, self.frame(t).height
        near = (depth > 0) & (np.abs(np.nan_to_num(height, nan=1.0)) < 0.03)
        if box is not None:
            x0, y0, x1, y1 = (int(round(c)) for c in box)
            pad = max(x1 - x0, y1 - y0, 20)
            ring = np.zeros_like(near)
            ring[max(y0 - pad, 0) : y1 + pad + 1, max(x0 - pad, 0) : x1 + pad + 1] = True
            ring[max(y0, 0) : y1 + 1, max(x0, 0) : x1 + 1] = False
            near &= ring
        h = height[near]
        if h.size >= 200:
            med = float(np.median(h))
            sigma = 1.4826 * float(np.median(np.abs(h - med)))
            self.lift = max(self.lift, float(np.clip(med + 4.0 * sigma, self.config.min_height_m, 0.02)))
        return self.lift

    # ----------------------------------------------------------------- start
    def start_from_prompts(self, specs, where) -> list[tuple[int, ObjectTrack]]:
        """(prompt frame, track) of every prompted object; objects prompted on the same frame get
        regions that share no pixel (``separate``)."""
        for s in specs:
            self.measure_lift(s.prompt.frame, s.prompt.box)
        regions = {s.name: self.prompt_region(s.name, s.prompt, where) for s in specs}
        for frame in sorted({s.prompt.frame for s in specs}):
            names = [s.name for s in specs if s.prompt.frame == frame]
            f = self.frame(frame)
            split = separate([regions[m] for m in names], f.cidx, height=f.height)
            for name, region in zip(names, split):
                regions[name] = region
        return [(s.prompt.frame, self._new_track(s.name, s.prompt.frame, regions[s.name])) for s in specs]

    def prompt_region(self, name: str, prompt, where) -> np.ndarray:
        """The object's pixels on its prompt frame: the depth-connected region standing on the
        support inside the prompt box (or the one nearest the prompt point)."""
        t = prompt.frame
        rgb, depth, pts, edges, cidx, height = self.frame(t)
        standing = (depth > 0) & (height > self.lift) & ~edges
        inside = np.zeros_like(standing)
        if prompt.box is not None:
            x0, y0, x1, y1 = (int(round(c)) for c in prompt.box)
            inside[max(y0, 0) : y1 + 1, max(x0, 0) : x1 + 1] = True
        else:
            x, y = (int(round(c)) for c in prompt.point)
            r = max(4, int(0.03 * self.width))
            inside[max(y - r, 0) : y + r + 1, max(x - r, 0) : x + r + 1] = True
        n, labels, areas = components(standing & inside)
        areas[0] = 0
        if n <= 1 or areas.max() < max(0.1 * inside.sum(), MIN_REGION_PX * self.scale_px / 4):
            raise InputError(
                f"nothing stands on the support inside the prompt of {name!r} on frame {t}",
                path=where,
                hint="draw the box around the object on a frame where it is visible",
            )
        if prompt.box is not None:
            label = 1 + int(np.argmax(areas[1:]))
        else:
            x, y = (int(round(c)) for c in prompt.point)
            ys, xs = np.nonzero(labels > 0)
            nearest = int(np.argmin((xs - x) ** 2 + (ys - y) ** 2))
            label = int(labels[ys[nearest], xs[nearest]])
        # pieces of the same object that a depth edge (a rim) cut off it, inside the prompt
        region = grow_across_edges(labels, labels == label, pts)
        others = [int(v) for v in np.unique(labels[inside]) if v > 0 and areas[v] >= MIN_REGION_PX * self.scale_px / 4]
        rim = inside & ~cv2.erode(inside.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
        within = set(others) - set(np.unique(labels[rim]).tolist())
        return self.join_moving_with(labels, region, others, t, within=within)

    def _new_track(self, name: str, t: int, mask: np.ndarray) -> ObjectTrack:
        rgb, depth, pts, edges, cidx, _ = self.frame(t)
        obj_pts = pts[mask & (depth > 0)]
        return ObjectTrack(
            name, subsample(obj_pts), histogram(cidx[mask]), max(diameter(obj_pts), 0.02), float(mask.sum())
        )

    def discover(
        self, names: list[str], interactor_of, n_frames: int, where, *, touch_m: float = 0.02
    ) -> list[ObjectTrack]:
        """Objects with no prompt: regions standing on the support at frame 0, ranked by the
        number of frames in which the interactor comes within ``touch_m`` of them, then by how
        near it comes."""
        self.measure_lift(0)
        rgb, depth, pts, edges, cidx, height = self.frame(0)
        standing = (depth > 0) & (height > self.lift) & (height < 0.6) & ~edges
        n, labels, areas = components(standing)
        border = np.unique(np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]]))
        regions = []
        for label in range(1, n):
            if label in border or areas[label] < MIN_REGION_PX * self.scale_px:
                continue
            p = pts[labels == label]
            if diameter(p) > 0.4:
                continue
            regions.append((label, cKDTree(subsample(p, 2000))))
        if not regions:
            raise InputError(
                "no object stands on the support in the first frame",
                path=where,
                hint="give a prompt box in rose.toml ([[objects]] prompt = { frame = F, box = [x0, y0, x1, y1] })",
            )
        nearest = np.full(len(regions), np.inf)
        touching = np.zeros(len(regions))  # sampled frames in which the interactor touches it
        for t in range(0, n_frames, max(1, n_frames // 40)):
            hand = interactor_of(t)
            if hand.sum() < MIN_REGION_PX * self.scale_px:
                continue
            hand &= self.frame(t).depth > 0
            if not hand.any():
                continue
            hp = subsample(self.frame(t).pts[hand], 3000)
            for i, (_, tree) in enumerate(regions):
                d, _ = tree.query(hp, k=1)
                nearest[i] = min(nearest[i], float(d.min()))
                touching[i] += float(d.min()) < touch_m
        # the region touched in the most frames first, then the one approached nearest
        order = list(np.lexsort((nearest, -touching)))
        if len(names) > 1:
            # objects standing on each other (a stack) form one region: split the most
            # approached region into what later leaves its place and what stays
            i = order[0]
            parts = self._split_by_motion(labels == regions[i][0], n_frames)
            if parts is not None:
                moved, stayed = parts
                labels = labels.copy()
                new_label = labels.max() + 1
                labels[stayed] = new_label
                regions.append((new_label, cKDTree(subsample(pts[stayed], 2000))))
                nearest = np.append(nearest, nearest[i])
                order = [i, len(regions) - 1] + order[1:]
        if len(regions) < len(names) or not np.isfinite(nearest[order[len(names) - 1]]):
            raise InputError(
                f"found {int(np.isfinite(nearest).sum())} region(s) the interactor approaches, "
                f"rose.toml names {len(names)} object(s)",
                path=where,
                hint="give each object a prompt box in rose.toml",
            )
        # the touched region may be one piece of its object (a cup's inner wall, cut off by its rim)
        chosen = [regions[order[i]][0] for i in range(len(names))]
        grown = []
        for c in chosen:
            own = np.where(np.isin(labels, chosen) & (labels != c), 0, labels)
            region = grow_across_edges(own, labels == c, pts)
            grown.append(self.join_moving_with(own, region, self._neighbours(own, region, pts), 0, led=True))
        return [self._new_track(name, 0, grown[i]) for i, name in enumerate(names)]

    def _neighbours(
        self, labels: np.ndarray, region: np.ndarray, pts: np.ndarray, *, within_m: float = 0.03
    ) -> list[int]:
        """Labels of the components with a point within ``within_m`` of ``region``'s points."""
        tree = cKDTree(subsample(pts[region & np.isfinite(pts[..., 2])], 2000))
        out = []
        for label in np.unique(labels[(labels > 0) & ~region]):
            part = subsample(pts[(labels == label) & np.isfinite(pts[..., 2])], 500)
            if len(part) and float(tree.query(part, k=1)[0].min()) < within_m:
                out.append(int(label))
        return out

    def moved_when(self, region: np.ndarray, t0: int, *, leave_m: float = 0.02, samples: int = 40) -> np.ndarray:
        """For frames sampled through the video (``samples`` of them), whether most of ``region``'s
        points (pixels of frame ``t0``) have left their place: the frame sees past them by more
        than ``leave_m`` (a hand in front of them hides them, it does not move them)."""
        n_frames = len(self.cam.world_from_cv)
        pts = self.frame(t0).pts
        v, u = np.nonzero(region & np.isfinite(pts[..., 2]))
        world = subsample(pts[v, u], 1500)
        out = []
        for t in range(0, n_frames, max(1, n_frames // samples)):
            uu, vv, z = pixels_of(world, self.cam.world_from_cv[t], self.cam.K[t], self.width, self.height)
            d = sample_at(self.depth_of(t), uu, vv)
            seen = (uu >= 0) & (d > 0)
            out.append(seen.sum() >= 0.3 * len(world) and np.count_nonzero(seen & (d > z + leave_m)) > 0.5 * seen.sum())
        return np.array(out, bool)

    def join_moving_with(
        self,
        labels: np.ndarray,
        region: np.ndarray,
        candidates: list[int],
        t0: int,
        *,
        within: set[int] = frozenset(),
        max_diameter_m: float = 0.3,
        led: bool = False,
    ) -> np.ndarray:
        """``region`` joined with the components among ``candidates`` (labels of frame ``t0``'s
        components) that leave their place in the same frames as it: one object moves as one.
        A depth edge cuts a cup lying on its side into its outer wall and, seen through its rim,
        its inner wall 2-4 cm deeper; the hand touches one, and both go when it lifts the cup.
        They must have started to move within two sampled frames of each other (a ball put into
        a cup and carried with it later is another object), moved together in at least two
        sampled frames and in 60 % of the frames the one that moved less often moved in (a cup's
        inner wall lies a few mm over the table, and seen past by less than ``leave_m`` it seems
        to move only while the cup is high); a component that moved in over half the frames (a
        person) is not joined, nor one that makes the union wider than ``max_diameter_m``.
        A component ``within`` the prompt box (touching none of its sides) may start to move later,
        if it never moves while the region stays: a standing mug's inner wall, seen over its rim,
        seems to leave its place only once a push has moved the mug by more than ``leave_m``.
        With ``led`` (no prompt: the region is what the interactor came to, maybe that inner wall),
        a component across a depth edge from it (within ``LED_JOIN_PX`` at 640x480: not a ball beside a cup)
        may start to move earlier, if the region never moves without it."""
        mine = self.moved_when(region, t0)
        if mine.sum() < 2:
            return region
        pts = self.frame(t0).pts
        near = None
        if led:
            reach = max(3, round(LED_JOIN_PX * self.scale_px**0.5))  # the rim between the walls, in pixels
            near = cv2.dilate(region.astype(np.uint8), np.ones((2 * reach + 1,) * 2, np.uint8)).astype(bool)
        for label in candidates:
            part = labels == label
            if (part & region).any():
                continue
            theirs = self.moved_when(part, t0)
            both = np.count_nonzero(mine & theirs)
            if both < 2 or both < 0.6 * min(mine.sum(), theirs.sum()) or theirs.sum() > 0.5 * len(theirs):
                continue
            later = label in within and np.count_nonzero(theirs & ~mine) <= 1
            earlier = led and np.count_nonzero(mine & ~theirs) <= 1 and (near & part).any()
            if abs(int(np.argmax(mine)) - int(np.argmax(theirs))) > 2 and not (later or earlier):
                continue  # they did not start to move together: two objects, carried together later
            union = region | part
            if diameter(pts[union & np.isfinite(pts[..., 2])]) <= max_diameter_m:
                region = union
        return region

    def _split_by_motion(
        self, region: np.ndarray, n_frames: int, *, leave_m: float = 0.02
    ) -> tuple[np.ndarray, np.ndarray] | None:
        """Split a frame-0 region into the pixels whose point later leaves its place (a later
        frame sees past it, by more than ``leave_m``) and the rest; None unless both parts are
        sizable regions."""
        pts = self.frame(0).pts
        v, u = np.nonzero(region)
        world = pts[v, u]
        left = np.zeros(len(v), bool)
        for t in range(n_frames // 2, n_frames, max(1, n_frames // 20)):
            uu, vv, z = pixels_of(world, self.cam.world_from_cv[t], self.cam.K[t], self.width, self.height)
            left |= (uu >= 0) & (sample_at(self.frame(t).depth, uu, vv) > z + leave_m)
        moved = np.zeros_like(region)
        moved[v[left], u[left]] = True
        moved = cv2.morphologyEx(moved.astype(np.uint8), cv2.MORPH_OPEN, np.ones((5, 5), np.uint8)).astype(bool)
        stayed = region & ~cv2.dilate(moved.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
        least = MIN_REGION_PX * self.scale_px
        if moved.sum() < least or stayed.sum() < least:
            return None
        n, labels, areas = components(moved)
        moved = labels == 1 + int(np.argmax(areas[1:]))
        n, labels, areas = components(stayed)
        stayed = labels == 1 + int(np.argmax(areas[1:]))
        return moved, stayed

    # ----------------------------------------------------------------- propagate
    def step(
        self,
        t: int,
        tracks: list[ObjectTrack],
        hand_hist: np.ndarray | None,
        exclude: np.ndarray | None = None,
        arm: np.ndarray | None = None,
        *,
        arm_found: bool = True,
    ) -> list[np.ndarray]:
        """Masks of every track in frame t (updating the tracks). Pixels of ``arm`` (what stands in
        front of the static world connected to a found hand: the arm, and the object the hand
        holds) belong to an object only when they are within ``core_m`` of its predicted points,
        not in front of the surface those show and, with ``arm_found``, inside their silhouette.
        Without ``arm_found`` (an arm followed from the interactor's last mask, no hand found) a
        part the points never covered stays (a lying can's end cap beside the thumb), and a track
        hidden in the frame before is not held to its stale points at all; with it, such a track
        is held to ``core_m`` of them alone.
        Pixels of ``exclude`` (a hand found by its landmarks) belong to no object without a skin
        model; with one (``skin``), they are taken as the arm's are, and the fingers on the object
        are peeled off its mask by their color (``peel_skin``)."""
        rgb, depth, pts, edges, cidx, height = self.frame(t)
        p = self.config
        valid = (depth > 0) & (height > self.lift)
        peel = self.skin is not None and p.classical.skin_peel_px > 0
        if exclude is not None and not peel:
            valid &= ~exclude
        if exclude is not None and peel:
            # a found hand's mask covers what it holds in front of its palm (a ball in the fist):
            # it is taken near the object's points, as the arm is, and fingers are peeled by color
            arm = exclude if arm is None else arm | exclude
        best = np.full(depth.shape, np.inf, np.float32)
        owner = np.full(depth.shape, -1, np.int32)
        cores = []
        for k, track in enumerate(tracks):
            core = np.zeros(depth.shape, bool)
            cores.append(core)
            pred = track.predicted()
            found = self._candidates(t, track, pred, valid, hand_hist)
            if found is None:
                continue
            ys, xs, d = found
            core_m = p.core_m + 0.5 * track.motion_m()
            ok = self._arm_allows(t, track, pred, found, core_m, arm, arm_found)
            better = ok & (d < best[ys, xs])
            best[ys[better], xs[better]] = d[better]
            owner[ys[better], xs[better]] = k
            sel = ok & (d < core_m) & (height[ys, xs] > self.lift)
            core[ys[sel], xs[sel]] = True
        masks = []
        max_hole = int(200 * self.scale_px)
        front = None
        if peel:
            front = self.foreground(t)[0]
            if exclude is not None:
                front = front | exclude
        for k, track in enumerate(tracks):
            mask = self._mask_of(t, k, track, owner, cores[k], hand_hist, max_hole, front)
            masks.append(mask if exclude is None or peel else mask & ~exclude)
        # closing, color borders and filled holes may reach into another object's pixels: each
        # pixel stays with the track that owns it (the nearest), or the first that claims it
        claims = np.sum(masks, axis=0) if masks else None
        for k, (track, mask) in enumerate(zip(tracks, masks)):
            shared = mask & (claims > 1)
            if shared.any():
                others_own = (owner != k) & (owner >= 0)
                earlier = np.any(masks[:k], axis=0) if k else np.zeros_like(mask)
                mask &= ~(shared & (others_own | ((owner < 0) & earlier)))
            self._update(track, t, mask)
        return masks

    def _arm_allows(self, t, track, pred, found, core_m: float, arm, arm_found: bool) -> np.ndarray:
        """Which candidate pixels ``found`` (rows, cols, distances) of ``track`` the arm leaves it
        (``step``): all when there is no arm, or when a followed arm's track was hidden (its region
        holds what it hid: an object coming out from under the hand, whose last points are stale,
        is searched as widely as it was hidden); else those off the arm, and those on it near the
        track's points and on the surface they show: within its predicted silhouette (with
        ``arm_found``), not in front of it (fingers wrapped around it are within core_m of its
        points); for a track hidden in the frame before, near its stale points alone."""
        ys, xs, d = found
        if arm is None or (track.hidden and not arm_found):
            return np.ones(len(d), bool)
        if track.hidden:  # it comes back where the hand brings it, beside its stale points' silhouette
            return ~arm[ys, xs] | (d < core_m)
        off = off_surface(
            pred,
            self.cam.world_from_cv[t],
            self.cam.K[t],
            self.frame(t).depth,
            ys,
            xs,
            self.config.occluder_m + 0.25 * track.motion_m(),
            outside=arm_found,
        )
        return ~arm[ys, xs] | ((d < core_m) & ~off)

    def _candidates(
        self, t: int, track: ObjectTrack, pred: np.ndarray, valid: np.ndarray, hand_hist: np.ndarray | None
    ):
        """Pixels of frame t that may be the track's: ``valid`` (standing), within the shell around
        its predicted points ``pred`` (``track.predicted()``) and of its colors where color breaks a
        tie; (rows, cols, distance to the nearest predicted point), or None."""
        pts, cidx = self.frame(t).pts, self.frame(t).cidx
        reach = max(track.diameter, 0.03) * (1.0 + 0.5 * min(track.hidden, 10))
        # a track seen in the last frame moves rigidly: its pixels lie near its moved points
        shell = reach if track.hidden else self.config.shell_m + 0.5 * track.motion_m()
        box = self._image_box(t, pred, reach)
        if box is None:
            return None
        y0, y1, x0, x1 = box
        sub = pts[y0:y1, x0:x1]
        lo, hi = pred.min(axis=0) - reach, pred.max(axis=0) + reach
        ys, xs = np.nonzero(valid[y0:y1, x0:x1] & np.all((sub >= lo) & (sub <= hi), axis=-1))
        if not len(ys):
            return None
        ys, xs = ys + y0, xs + x0
        d, _ = cKDTree(pred).query(pts[ys, xs], k=1, distance_upper_bound=reach)
        # color breaks ties only, between what stands near the object (farther than the shell
        # from its points: a hand, another object) and the hand
        c = cidx[ys, xs]
        others = int(np.count_nonzero(d >= shell))
        colored = object_colored(track.color, c, c, hand_hist, others=others, min_px=MIN_REGION_PX * self.scale_px / 4)
        keep = np.flatnonzero((d < shell) & colored)
        return ys[keep], xs[keep], d[keep]

    def _mask_of(self, t, k, track, owner, core, hand_hist, max_hole, front) -> np.ndarray:
        """Track k's mask in frame t from the pixels it owns: the depth-connected parts holding a
        core pixel, closed, grown by its colors, holes filled, within its size, fingers peeled off
        (with ``front``) and blobs apart dropped."""
        depth, edges, cidx = self.frame(t).depth, self.frame(t).edges, self.frame(t).cidx
        grow = (owner == k) & ~edges
        n, labels, _ = components(grow)
        keep = np.unique(labels[core & grow])
        keep = keep[keep > 0]
        mask = np.isin(labels, keep) if len(keep) else np.zeros_like(grow)
        mask = cv2.morphologyEx(mask.astype(np.uint8), cv2.MORPH_CLOSE, np.ones((3, 3), np.uint8)).astype(bool)
        mask = fill_holes(self._color_border(mask, cidx, track, hand_hist, owner, k), max_hole)
        mask &= self._within_size(t, track, mask)
        if front is not None:
            sigma = self.config.classical.skin_peel_px
            mask = peel_skin(mask, cidx, track.color, self.skin, front, sigma, min_px=max(4, int(15 * self.scale_px)))
        return main_part(mask, track.area, depth)

    def _within_size(self, t: int, track: ObjectTrack, mask: np.ndarray, *, slack_m: float = 0.015) -> np.ndarray:
        """The object is rigid: pixels whose point lies farther than its diameter (measured at the
        start) plus ``slack_m`` from its predicted centre are not its (an arm of the same colour
        that touches it would otherwise be taken, and the track would climb it frame by frame).
        Not half the diameter: the predicted centre (the median of the tracked points, moved by the
        last velocity) lags a placed or turned mug, and the small suite's mask IoU fell by up to
        0.29 at half. Pixels without depth stay."""
        pts = self.frame(t).pts
        centre = np.median(track.predicted(), axis=0)
        far = np.linalg.norm(np.nan_to_num(pts - centre, nan=0.0), axis=-1) > track.diameter + slack_m
        return ~(far & mask)

    def _color_border(self, mask, cidx, track, hand_hist, owner, k, *, ring_px: int = 5) -> np.ndarray:
        """Grow the mask by object-colored pixels within ``ring_px``: at silhouettes, depth is
        missing or (registered only approximately to color) belongs to what is behind."""
        if not mask.any():
            return mask
        kernel = np.ones((3, 3), np.uint8)
        outer = cv2.dilate(mask.astype(np.uint8), np.ones((2 * ring_px + 1,) * 2, np.uint8)).astype(bool) & ~mask
        around_px = (
            cv2.dilate(mask.astype(np.uint8), np.ones((6 * ring_px + 1,) * 2, np.uint8)).astype(bool) & ~mask & ~outer
        )
        if not around_px.any():
            return mask
        around = histogram(cidx[around_px])
        other = around if hand_hist is None else np.maximum(around, hand_hist)
        colored = outer & (track.color[cidx] > 2.0 * other[cidx]) & ((owner == k) | (owner < 0))
        grown = mask.copy()
        for _ in range(ring_px):  # grow only through colored pixels connected to the mask
            grown |= cv2.dilate(grown.astype(np.uint8), kernel).astype(bool) & colored
        return grown

    def _image_box(self, t: int, points: np.ndarray, reach: float):
        """Pixel rows/cols (y0, y1, x0, x1) that points within ``reach`` of ``points`` can
        project to in frame t; None when none is in front of the camera."""
        pose, k = self.cam.world_from_cv[t], self.cam.K[t]
        cam = (points - pose[:3, 3]) @ pose[:3, :3]
        cam = cam[cam[:, 2] > 0.05]
        if not len(cam):
            return None
        u = k[0, 0] * cam[:, 0] / cam[:, 2] + k[0, 2]
        v = k[1, 1] * cam[:, 1] / cam[:, 2] + k[1, 2]
        margin = k[0, 0] * reach / max(float(cam[:, 2].min()) - reach, 0.05)
        x0, x1 = int(max(u.min() - margin, 0)), int(min(u.max() + margin + 1, self.width))
        y0, y1 = int(max(v.min() - margin, 0)), int(min(v.max() + margin + 1, self.height))
        return None if x0 >= x1 or y0 >= y1 else (y0, y1, x0, x1)

    def _update(self, track: ObjectTrack, t: int, mask: np.ndarray) -> None:
        rgb, depth, pts, edges, cidx, _ = self.frame(t)
        area = float(mask.sum())
        if area < 0.25 * track.area:
            track.hidden += 1
            track.velocity *= 0.5
            track.spin *= 0.5
            return
        new = subsample(pts[mask & (depth > 0)], 4000, seed=t)
        if len(new) < 20:
            track.hidden += 1
            return
        turn, shift = rigid_motion(track.points, new, track.spin if track.hidden == 0 else np.zeros(3))
        if track.hidden == 0:
            track.velocity = 0.5 * track.velocity + 0.5 * shift
            track.spin = 0.5 * track.spin + 0.5 * Rotation.from_matrix(turn).as_rotvec()
        else:
            track.velocity, track.spin = np.zeros(3), np.zeros(3)
        # the part hidden now (something in front of it: a hand) is still there, moved with the
        # part seen; keeping only the seen part loses a box whose seen face the hand then covers
        centre = np.median(track.points, axis=0)
        moved = (track.points - centre) @ turn.T + centre + shift
        u, v, z = pixels_of(moved, self.cam.world_from_cv[t], self.cam.K[t], self.width, self.height)
        d = sample_at(depth, u, v)
        behind = (u >= 0) & (d > 0) & (d < z - 0.01)
        points = np.concatenate([new, moved[behind]])
        # the object is rigid and no wider than it was: points farther from the centre of where
        # it was carried (a finger, a ball held beside a cup, taken once) are not kept, or they
        # would stay behind what hides them and draw the mask to them frame after frame
        centre = np.median(moved, axis=0)
        near = np.linalg.norm(points - centre, axis=1) <= 0.65 * track.diameter + 0.015
        track.points = subsample(points[near] if near.sum() >= 20 else points, 4000, seed=t)
        track.hidden = 0
        track.color = 0.5 * track.first_color + 0.5 * (
            0.8 * (2.0 * track.color - track.first_color) + 0.2 * histogram(cidx[mask])
        )
