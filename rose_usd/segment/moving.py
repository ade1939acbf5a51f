"""What moves in an RGB video, for the flow segment backend's interactor and its tracks: against
a still camera's static background (the per-pixel temporal median of the frames no found hand or
its bare arm covers there, chroma weighted over lightness),
else the pixels whose flow departs from the camera's (a RANSAC homography of the flow)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import cv2
import numpy as np

from rose_usd.segment.regions import components

if TYPE_CHECKING:
    from rose_usd.segment.flow import FlowTracker

FOREGROUND_LAB = 20.0
"""A still camera's pixel is foreground this far from the temporal median (weighted Lab)."""

UNCOVERED = 0.25
"""A still camera's background at a pixel is the median of the sampled frames where no found hand
or its bare arm covers it (``segment.hands.skin_arm``), where at least this share of them leave it
uncovered; elsewhere of all of them. Of all of them, the forearm resting on the left of
r2r2r-mug-rgb in 36 of its 65 frames was the background: the interactor had only the hand, and
the scene's texture a ghost of the arm."""


class MotionForeground:
    """What is not the static background: a temporal median when the camera stands still, else
    flow that departs from the camera's homography."""

    def __init__(self, tracker: FlowTracker, n: int, *, cover=None, samples: int = 40):
        """``cover``: t -> the pixels of frame t a found hand or its arm covers, or None (no hand)."""
        self.tracker = tracker
        picks = np.linspace(0, n - 1, min(n, samples)).round().astype(int)
        shifts = []
        for a, b in zip(picks[:-1], picks[1:]):
            f = tracker.flow(int(a), int(b))
            shifts.append(float(np.median(np.linalg.norm(f, axis=2))))
        self.static_camera = bool(np.median(shifts) < 1.0) if shifts else True
        self.median = None
        self.known = None
        """Pixels whose background was seen uncovered in ``UNCOVERED`` of the samples (still camera)."""
        self._labs: dict[int, np.ndarray] = {}
        self._near: tuple[int, np.ndarray] | None = None
        if self.static_camera:
            stack = np.stack([cv2.cvtColor(tracker.frame_of(int(t)), cv2.COLOR_RGB2LAB) for t in picks])
            covers = [cover(int(t)) if cover is not None else None for t in picks]
            self.median, self.known = _uncovered_median(stack, covers)

    def _lab(self, t: int) -> np.ndarray:
        """Frame t in Lab (float32); the last two asked are kept (a frame is asked as the current
        one, for the interactor, and as the previous one of the next)."""
        if t not in self._labs:
            self._labs = {k: v for k, v in self._labs.items() if k in (t - 1, t + 1)}
            self._labs[t] = cv2.cvtColor(self.tracker.frame_of(t), cv2.COLOR_RGB2LAB).astype(np.float32)
        return self._labs[t]

    @staticmethod
    def _apart(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Per-pixel distance of two Lab images, lightness weighted by a quarter (shadows of the
        hands change it more than chroma), their mean difference (exposure and white balance
        drift) removed."""
        d = a - b
        d -= np.median(d.reshape(-1, 3), axis=0)
        d[..., 0] *= 0.25
        return np.linalg.norm(d, axis=2)

    def background(self, t: int, prev: int) -> np.ndarray | None:
        """Pixels of frame t that surely show the static background: within half the foreground's
        threshold of the temporal median and of frame ``prev`` (unchanged since the last frame:
        an object being set down where it will rest, and so where the median shows it, still
        changes); None when the camera moves."""
        if not self.static_camera:
            return None
        return self._near_median(t) & (self._apart(self._lab(t), self._lab(prev)) < 0.5 * FOREGROUND_LAB)

    def _near_median(self, t: int) -> np.ndarray:
        """Pixels of frame t within half the foreground's threshold of the temporal median (the
        last frame's kept: ``background`` and ``shows_background`` ask for the same frame)."""
        if self._near is None or self._near[0] != t:
            self._near = (t, self._apart(self._lab(t), self.median) < 0.5 * FOREGROUND_LAB)
        return self._near[1]

    def shows_background(self, t: int) -> np.ndarray | None:
        """Pixels of frame t within half the foreground's threshold of a background that was seen
        uncovered (``known``); None when the camera moves."""
        if not self.static_camera:
            return None
        return self.known & self._near_median(t)

    def camera(self, flow: np.ndarray | None) -> np.ndarray | None:
        """The camera's homography along ``flow``: the identity for a still camera, None without a flow."""
        if self.static_camera:
            return np.eye(3)
        return None if flow is None else camera_homography(flow)

    def __call__(self, t: int, flow: np.ndarray | None, camera: np.ndarray | None) -> np.ndarray:
        """The moving pixels of frame t (``flow``: from the last frame; ``camera``: the camera's
        homography along it, ``self.camera(flow)``)."""
        if self.static_camera:
            fg = self._apart(self._lab(t), self.median) > FOREGROUND_LAB
        elif flow is not None:
            h, w = flow.shape[:2]
            yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
            pts = np.stack([xx, yy, np.ones_like(xx)], axis=-1) @ camera.T
            cam = pts[..., :2] / pts[..., 2:3] - np.stack([xx, yy], axis=-1)
            fg = np.linalg.norm(flow - cam, axis=2) > 1.5
        else:
            return np.zeros((self.tracker.h, self.tracker.w), bool)
        fg = cv2.morphologyEx(fg.astype(np.uint8), cv2.MORPH_OPEN, np.ones((5, 5), np.uint8))
        fg = cv2.morphologyEx(fg, cv2.MORPH_CLOSE, np.ones((9, 9), np.uint8)).astype(bool)
        n, labels, areas = components(fg)
        keep = np.zeros(n, bool)
        keep[1:] = areas[1:] >= 0.002 * fg.size
        return keep[labels]


MEDIAN_CHUNK_PX = 1 << 17
"""Pixels whose medians are taken at once: the samples' values of 131k pixels are 63 MB as float32
(a still 1920x1080 view's 40 samples at once: 3.3 GB peak)."""


def _uncovered_median(stack: np.ndarray, covers: list[np.ndarray | None]) -> tuple[np.ndarray, np.ndarray]:
    """The per-pixel median (float32) of ``stack`` (samples, h, w, 3) over the samples whose
    ``covers`` (each sample's hands and arms, or None) leave the pixel uncovered, where
    ``UNCOVERED`` of them do, else over all; and where they do (bool (h, w))."""
    shape = stack.shape[1:3]
    rows = max(1, MEDIAN_CHUNK_PX // shape[1])
    median = np.concatenate(
        [np.median(stack[:, y : y + rows], axis=0).astype(np.float32) for y in range(0, shape[0], rows)]
    )
    if all(c is None or not c.any() for c in covers):
        return median, np.ones(shape, bool)
    grow = np.ones((9, 9), np.uint8)
    free = ~np.stack(
        [np.zeros(shape, bool) if c is None else cv2.dilate(c.astype(np.uint8), grow).astype(bool) for c in covers]
    )
    known = free.sum(axis=0) >= max(3, UNCOVERED * len(covers))
    ys, xs = np.nonzero(known & ~free.all(axis=0))
    for i in range(0, len(ys), MEDIAN_CHUNK_PX):
        y, x = ys[i : i + MEDIAN_CHUNK_PX], xs[i : i + MEDIAN_CHUNK_PX]
        median[y, x] = _median_where(stack[:, y, x], free[:, y, x])
    return median, known


def _median_where(values: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """The median over axis 0 of ``values`` (samples, p, 3) where ``keep`` (samples, p) holds (at
    least one sample each), as float32: the mean of the two middle values for an even count."""
    v = np.where(keep[..., None], values.astype(np.float32), np.float32(np.inf))
    v.sort(axis=0)
    k = np.broadcast_to(keep.sum(axis=0)[:, None], v.shape[1:])
    lo = np.take_along_axis(v, ((k - 1) // 2)[None], axis=0)[0]
    hi = np.take_along_axis(v, (k // 2)[None], axis=0)[0]
    return (lo + hi) / np.float32(2.0)


def camera_homography(flow: np.ndarray) -> np.ndarray:
    """The homography (3, 3) that moves the static background along ``flow`` (RANSAC over every
    8th pixel's flow: the background is most of a tabletop view); the identity where none fits."""
    h, w = flow.shape[:2]
    ys, xs = np.mgrid[0:h:8, 0:w:8]
    src = np.stack([xs.ravel(), ys.ravel()], axis=1).astype(np.float32)
    dst = src + flow[ys.ravel(), xs.ravel()]
    H, _ = cv2.findHomography(src, dst, cv2.RANSAC, 1.0)
    return H if H is not None else np.eye(3)


def camera_shift(camera: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """The shift (dx, dy) [px] that the camera's homography gives the centroid of ``mask``."""
    ys, xs = np.nonzero(mask)
    if not len(xs):
        return np.zeros(2)
    c = np.array([xs.mean(), ys.mean(), 1.0])
    moved = camera @ c
    return moved[:2] / moved[2] - c[:2]
