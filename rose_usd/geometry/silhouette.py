"""Shapes fitted to masks by render and compare: the silhouette IoU of a mesh against an object's
masks, and the searches that make it large. What an RGB-only video has instead of depth.

A view is one frame's mask, the pixels to leave out (the interactor and other objects, which may
hide the object) and its camera, cropped around the mask and downscaled (``crop_view``), so a
silhouette costs about a millisecond whatever the video's size. The cost of a shape is 1 - IoU
summed over the views (intersection and union added up before dividing). It is minimized by
Nelder-Mead from a good start: IoU is flat between pixel steps, but over an object of a hundred
pixels a simplex of a few pixels' moves finds its way.

- ``fit_standing``: a shape standing on the support plane (z = ``support_z``) at (x, y) turned by
  yaw, its dimensions (a primitive's) or its scale (a mesh's) free or fixed: what a resting
  object's silhouettes determine.
- ``search_free`` and ``fit_free``: a metric mesh anywhere (6-DoF), for an object held in the air:
  orientations spread over the sphere, each placed where its silhouette's centroid and area match
  the mask's, the best refined.
- ``fit_edges``: a fit's pose refined with its outline asked onto the frame's image edges of its
  own direction (a view made with the frame's gray image has their distance maps,
  ``edge_distance``): where a mask is a pixel or two off the object, its edges are not.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass
from types import SimpleNamespace

import cv2
import numpy as np
from scipy.optimize import minimize

from rose_usd.core import se3
from rose_usd.core.pinhole import project, resized_K, silhouette
from rose_usd.core.raster import convex_spans, fill_convex, row_sums, running_sums
from rose_usd.geometry.primitives import PrimitiveKind, largest_dimension, yaw_starts


@dataclass
class View:
    """One frame's mask in a crop around it (working resolution)."""

    mask: np.ndarray
    """Bool (h, w): the object's pixels."""
    ignore: np.ndarray
    """Bool (h, w): pixels counted neither way (what may hide the object)."""
    K: np.ndarray
    """Intrinsics of the crop (3, 3) [px]."""
    world_from_cv: np.ndarray
    frame: int = -1
    scale: float = 1.0
    """Crop pixels per video pixel."""
    offset: tuple[int, int] = (0, 0)
    """(x0, y0) of the crop in video pixels."""
    soft: np.ndarray | None = None
    """Float (h, w) in [0, 1]: how likely each pixel is the object's (a color posterior blended
    with the mask); when given, the IoU is the soft one against it."""
    edges: np.ndarray | None = None
    """Float (EDGE_BINS, h, w) in [0, 1]: per direction, each pixel's distance to the frame's
    nearest image edge of about that direction (outside what is ignored) over ``EDGE_REACH_PX``,
    capped at 1 (``edge_distance``); where given, a fit can ask its outline to lie on edges
    (``edge_cost``)."""

    @functools.cached_property
    def counted(self) -> SimpleNamespace:
        """What an IoU counts against, made once: the pixels not ignored (``keep``), the mask there
        (``target``: soft where given, else the bool mask) and its total."""
        keep = ~self.ignore
        target = np.where(keep, self.soft, 0.0) if self.soft is not None else self.mask & keep
        return SimpleNamespace(keep=keep, target=target, total=float(target.sum()))

    def render(
        self, vertices_world: np.ndarray, faces: np.ndarray, *, closed: bool = True, convex: bool = False
    ) -> np.ndarray:
        """The mesh's silhouette in the crop; a ``convex`` mesh's is its projected vertices' hull."""
        h, w = self.mask.shape
        hull = self._hull(vertices_world) if convex else None
        if hull is not None:
            return fill_convex(hull, w, h)
        return silhouette(vertices_world, faces, self.world_from_cv, self.K, w, h, closed=closed)

    def outline(self, vertices_world: np.ndarray, faces: np.ndarray, *, convex: bool = False):
        """Points along the mesh's silhouette outline in the crop (M, 2) [px], about a pixel apart,
        and the direction of the outline's normal at each (M,) [rad, mod pi]; None when it has none
        (behind the camera)."""
        hull = self._hull(vertices_world) if convex else None
        if hull is not None:
            ends = np.roll(hull, -1, axis=0)
            steps = np.maximum(np.ceil(np.linalg.norm(ends - hull, axis=1)).astype(int), 1)
            at = np.repeat(np.arange(len(hull)), steps)
            frac = np.concatenate([np.arange(k) / k for k in steps])
            tangent = (ends - hull)[at]
            return hull[at] + frac[:, None] * tangent, np.arctan2(tangent[:, 0], -tangent[:, 1])
        drawn = self.render(vertices_world, faces, convex=convex).astype(np.uint8)
        contours, _ = cv2.findContours(drawn, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        contours = [c.reshape(-1, 2).astype(float) for c in contours if len(c) >= 3]
        if not contours:
            return None
        pts = np.concatenate(contours)
        # the tangent over two pixels each way: a pixel chain's own steps are 45 deg apart
        tangent = np.concatenate([np.roll(c, -2, axis=0) - np.roll(c, 2, axis=0) for c in contours])
        return pts, np.arctan2(tangent[:, 0], -tangent[:, 1])

    def edge_cost(self, vertices_world: np.ndarray, faces: np.ndarray, *, convex: bool = False) -> float:
        """How far the mesh's outline lies from the frame's image edges of its own direction, in
        [0, 1]: the mean along it of ``edges`` in the bin of the outline's normal (bilinear), an
        outline point off the crop counting 1 and one where the object may be hidden
        ``EDGE_HIDDEN``; 0 without an edge map."""
        if self.edges is None:
            return 0.0
        got = self.outline(vertices_world, faces, convex=convex)
        if got is None or not len(got[0]):
            return 1.0
        pts, normal = got
        _, h, w = self.edges.shape
        x, y = pts[:, 0], pts[:, 1]
        inside = (x >= 0) & (y >= 0) & (x <= w - 1) & (y <= h - 1)
        cost = np.ones(len(pts))
        xi, yi = x[inside], y[inside]
        b = np.rint(np.mod(normal[inside], np.pi) / (np.pi / EDGE_BINS)).astype(int) % EDGE_BINS
        x0, y0 = np.minimum(xi.astype(int), w - 2), np.minimum(yi.astype(int), h - 2)
        fx, fy = xi - x0, yi - y0
        e = self.edges
        cost[inside] = (
            e[b, y0, x0] * (1 - fx) * (1 - fy)
            + e[b, y0, x0 + 1] * fx * (1 - fy)
            + e[b, y0 + 1, x0] * (1 - fx) * fy
            + e[b, y0 + 1, x0 + 1] * fx * fy
        )
        hidden = np.zeros(len(pts), bool)
        hidden[inside] = self.ignore[np.rint(yi).astype(int), np.rint(xi).astype(int)]
        cost[hidden] = EDGE_HIDDEN
        return float(cost.mean())

    def _hull(self, vertices_world: np.ndarray) -> np.ndarray | None:
        """The projected vertices' convex hull (M, 2) [px]; None when one is not in front of the camera."""
        cam = se3.transform_points(self._cv_from_world, vertices_world)
        if not np.all(cam[:, 2] > 1e-3):
            return None
        return cv2.convexHull(np.column_stack(project(cam, self.K)).astype(np.float32)).reshape(-1, 2)

    @functools.cached_property
    def _cv_from_world(self) -> np.ndarray:
        return se3.invert(self.world_from_cv)

    @functools.cached_property
    def _sums(self) -> tuple[np.ndarray, np.ndarray, float]:
        """``counted``'s keep and target as running row sums, and the target's total: a convex
        silhouette's IoU from its row spans alone."""
        c = self.counted
        return running_sums(c.keep), running_sums(c.target), c.total

    def convex_overlap(self, vertices_world: np.ndarray) -> tuple[float, float] | None:
        """(intersection, union) of a convex mesh's silhouette with the mask (soft where given),
        outside what is ignored, as ``iou`` counts them; None when a vertex is behind the camera."""
        hull = self._hull(vertices_world)
        if hull is None:
            return None
        spans = convex_spans(hull, self.mask.shape[1], self.mask.shape[0])
        keep, target, total = self._sums
        drawn, inside = row_sums((keep, target), spans)
        return inside, drawn + total - inside


EDGE_REACH_PX = 4.0
"""An outline point this far (working pixels) or farther from an image edge costs the most (1)."""
EDGE_BINS = 8
"""Edge directions are told apart in this many bins over 180 deg (``edge_distance``)."""
EDGE_BAND_PX = 6
"""Only image edges within this many working px of the mask's outline count (``edge_distance``)."""
EDGE_HIDDEN = 0.5
"""What an outline point costs where the object may be hidden (under the hand): neither on an edge
nor off one."""


def edge_distance(gray: np.ndarray, ignore: np.ndarray | None, mask: np.ndarray | None = None) -> np.ndarray:
    """Per direction bin, each pixel's distance to the nearest Canny edge of ``gray`` (uint8, a
    view's crop) whose gradient lies in that bin or the next ones (``EDGE_BINS`` over 180 deg, so
    within about 34 deg), over ``EDGE_REACH_PX`` and capped at 1: (EDGE_BINS, h, w) float32.
    Edges within 2 px of ``ignore`` are left out, and so, given ``mask``, are those farther than
    ``EDGE_BAND_PX`` from its outline (a printed object's own edges are no outline). Canny's
    thresholds follow the crop's gradients (the 90th percentile of the Sobel magnitude, and 0.4
    of it), so a low-contrast outline still has its edges; the directions keep a checked cloth's
    crossing lines off an outline's side."""
    g = cv2.GaussianBlur(gray, (0, 0), 1.0)
    gx, gy = cv2.Sobel(g, cv2.CV_32F, 1, 0), cv2.Sobel(g, cv2.CV_32F, 0, 1)
    high = max(float(np.percentile(cv2.magnitude(gx, gy), 90)), 8.0)
    edges = cv2.Canny(g, 0.4 * high, high, L2gradient=True) > 0
    if ignore is not None and ignore.any():
        edges &= cv2.dilate(ignore.astype(np.uint8), np.ones((5, 5), np.uint8)) == 0
    if mask is not None and mask.any():
        # only edges near the mask's outline: an object's own print (a textured cube's) is no outline
        disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * EDGE_BAND_PX + 1, 2 * EDGE_BAND_PX + 1))
        m8 = mask.astype(np.uint8)
        edges &= (cv2.dilate(m8, disc) > 0) & (cv2.erode(m8, disc) == 0)
    bins = np.rint(np.mod(np.arctan2(gy, gx), np.pi) / (np.pi / EDGE_BINS)).astype(int) % EDGE_BINS
    out = np.ones((EDGE_BINS, *gray.shape), np.float32)
    for k in range(EDGE_BINS):
        near = edges & ((bins == k) | (bins == (k + 1) % EDGE_BINS) | (bins == (k - 1) % EDGE_BINS))
        if near.any():
            dist = cv2.distanceTransform((~near).astype(np.uint8), cv2.DIST_L2, 3)
            out[k] = np.minimum(dist / EDGE_REACH_PX, 1.0)
    return out


def crop_view(
    mask: np.ndarray,
    ignore: np.ndarray | None,
    K: np.ndarray,
    world_from_cv: np.ndarray,
    *,
    frame: int = -1,
    grow: float = 0.75,
    max_side: int = 320,
    box: tuple[float, float, float, float] | None = None,
    soft: np.ndarray | None = None,
    gray: np.ndarray | None = None,
) -> View:
    """The view of ``mask`` (bool, video size) cropped to its bounding box (or ``box``) grown by
    ``grow`` of its size on every side and downscaled so its long side is at most ``max_side``;
    ``soft`` (float, video size) is cropped with it, and ``gray`` (the frame, uint8) gives it its
    edge map (``edge_distance``)."""
    h, w = mask.shape
    if box is None:
        ys, xs = np.nonzero(mask)
        box = (xs.min(), ys.min(), xs.max() + 1, ys.max() + 1) if len(xs) else (0, 0, w, h)
    x0, y0, x1, y1 = box
    bw, bh = x1 - x0, y1 - y0
    x0, x1 = int(max(0, np.floor(x0 - grow * bw))), int(min(w, np.ceil(x1 + grow * bw)))
    y0, y1 = int(max(0, np.floor(y0 - grow * bh))), int(min(h, np.ceil(y1 + grow * bh)))
    s = min(1.0, max_side / max(x1 - x0, y1 - y0, 1))
    cw, ch = max(1, int(round((x1 - x0) * s))), max(1, int(round((y1 - y0) * s)))

    def cut(image):
        part = image[y0:y1, x0:x1].astype(np.uint8)
        return cv2.resize(part, (cw, ch), interpolation=cv2.INTER_AREA) >= 128 if s < 1 else part.astype(bool)

    kc = resized_K(K, s, (x0, y0))
    mask8 = mask.astype(np.uint8) * 255
    ignore8 = (np.zeros_like(mask) if ignore is None else ignore).astype(np.uint8) * 255
    soft_crop = None
    if soft is not None:
        part = np.ascontiguousarray(soft[y0:y1, x0:x1], dtype=np.float32)
        soft_crop = cv2.resize(part, (cw, ch), interpolation=cv2.INTER_AREA) if s < 1 else part
    ignore_crop = cut(ignore8)
    edges = None
    if gray is not None:
        part = np.ascontiguousarray(gray[y0:y1, x0:x1], dtype=np.uint8)
        small = cv2.resize(part, (cw, ch), interpolation=cv2.INTER_AREA) if s < 1 else part
        edges = edge_distance(small, ignore_crop, cut(mask8))
    return View(cut(mask8), ignore_crop, kc, np.asarray(world_from_cv, float), frame, s, (x0, y0), soft_crop, edges)


def is_convex(vertices: np.ndarray, faces: np.ndarray, tolerance: float = 0.01) -> bool:
    """Whether a closed mesh's volume is within ``tolerance`` of its convex hull's (its silhouette is
    then the hull of its projected vertices, a hundred times faster to draw)."""
    import trimesh

    tm = trimesh.Trimesh(vertices, faces, process=False)
    return bool(tm.is_watertight and tm.volume >= (1.0 - tolerance) * tm.convex_hull.volume)


def iou(
    views: list[View], vertices_world: np.ndarray, faces: np.ndarray, *, closed: bool = True, convex: bool = False
) -> float:
    """Silhouette IoU of the mesh (world coordinates) with the views' masks, outside what they ignore."""
    inter = union = 0.0
    for view in views:
        overlap = view.convex_overlap(vertices_world) if convex else None
        if overlap is not None:
            inter, union = inter + overlap[0], union + overlap[1]
            continue
        r = view.render(vertices_world, faces, closed=closed, convex=convex)
        counted = view.counted
        if view.soft is not None:  # soft IoU: sum(r S) / sum(r + S - r S)
            rk = r & counted.keep
            inside = float(counted.target[rk].sum())
            inter += inside
            union += float(np.count_nonzero(rk)) + counted.total - inside
            continue
        both = int(np.count_nonzero(r & counted.target))
        inter += both
        union += int(np.count_nonzero(r & counted.keep)) + int(counted.total) - both
    return inter / max(union, 1e-9)


def nelder_mead(cost: Callable[[np.ndarray], float], x0: np.ndarray, steps: np.ndarray, *, maxfev: int = 200):
    """Minimize ``cost`` from ``x0`` with a first simplex ``steps`` wide: (x, cost)."""
    x0 = np.asarray(x0, float)
    simplex = np.vstack([x0] + [x0 + np.eye(len(x0))[i] * steps[i] for i in range(len(x0))])
    res = minimize(
        cost,
        x0,
        method="Nelder-Mead",
        options={"initial_simplex": simplex, "maxfev": maxfev, "xatol": 1e-4, "fatol": 1e-4},
    )
    return np.asarray(res.x, float), float(res.fun)


def rot_z(yaw: float) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def standing_pose(x: float, y: float, yaw: float, support_z: float = 0.0) -> np.ndarray:
    """world_from_object of a shape whose frame's origin is the center of its bottom."""
    return se3.make_pose(rot_z(yaw), np.array([x, y, support_z]))


@dataclass
class StandingFit:
    x: float
    y: float
    yaw: float
    size: np.ndarray
    """A primitive's dimensions, or (rho,) for a mesh's scale."""
    iou: float
    cost: float
    """What the fit minimized: 1 - IoU plus the size prior's cost."""

    def pose(self, support_z: float = 0.0) -> np.ndarray:
        return standing_pose(self.x, self.y, self.yaw, support_z)


PRIOR_WEIGHT = 0.005
"""Cost of a one-sigma size deviation in a standing fit with a size prior, in IoU."""


def log_normal_sizes(expected: np.ndarray, sigma: float) -> Callable[[np.ndarray], float]:
    """A size prior for ``fit_standing``: ``PRIOR_WEIGHT`` * z**2 per size parameter, z its log
    ratio to ``expected`` over the relative one-sigma ``sigma`` (a 1-sigma size costs as much as
    0.005 IoU, 3 sigma 0.045), so the silhouettes decide within that spread and a size they leave
    open (an end outside the crop, a side an occluder hides) stays near the expected one."""
    log_expected = np.log(np.asarray(expected, float))

    def cost(size: np.ndarray) -> float:
        z = (np.log(np.asarray(size, float)) - log_expected) / max(sigma, 1e-6)
        return PRIOR_WEIGHT * float(np.sum(z * z))

    return cost


def log_normal_given_size(
    kind: PrimitiveKind, typical_dims: np.ndarray, size_m: float, sigma_size: float, sigma_shape: float
) -> Callable[[np.ndarray], float]:
    """A size prior for ``fit_standing`` where the object's largest dimension is given:
    ``PRIOR_WEIGHT`` * z**2 for that dimension's log ratio to ``size_m`` over ``sigma_size``, and for
    each proportion (a size parameter over the largest dimension; a box's sides sorted, since its
    yaw may swap them) its log ratio to the typical one over ``sigma_shape``. A given size says how
    large the object is, not its shape: a cube of category box is no carton."""

    def shape(size: np.ndarray) -> np.ndarray:
        d = np.asarray(size, float)
        d = np.sort(d)[::-1] if kind is PrimitiveKind.BOX else d
        return np.log(d / largest_dimension(kind, d))

    typical_shape = shape(typical_dims)

    def cost(size: np.ndarray) -> float:
        z_size = np.log(largest_dimension(kind, size) / size_m) / max(sigma_size, 1e-6)
        z_shape = (shape(size) - typical_shape) / max(sigma_shape, 1e-6)
        return PRIOR_WEIGHT * float(z_size * z_size + np.sum(z_shape * z_shape))

    return cost


def log_normal_ratio(i: int, j: int, expected: float, sigma: float) -> Callable[[np.ndarray], float]:
    """A proportion prior for ``fit_standing`` where the overall size is free: ``PRIOR_WEIGHT`` *
    z**2, z the log ratio of size parameters i / j to ``expected`` over the relative one-sigma
    ``sigma`` (a mug's handle reach to its radius: what the silhouettes leave open while the
    handle is behind the mug)."""
    log_expected = float(np.log(expected))

    def cost(size: np.ndarray) -> float:
        z = (np.log(float(size[i]) / float(size[j])) - log_expected) / max(sigma, 1e-6)
        return PRIOR_WEIGHT * z * z

    return cost


def lying_start(view_mask: np.ndarray, K: np.ndarray, world_from_cv: np.ndarray, support_z: float = 0.0):
    """Where a long object lying on z = ``support_z`` (a pen) starts a fit: the ends of the mask's
    principal axis (its 2nd and 98th percentiles along it) cast onto the plane: (center x, y, yaw
    [rad], length); None when the mask is empty or an end is above the horizon. The length is what
    the mask shows, short of the object's where a hand or the frame hides an end."""
    ys, xs = np.nonzero(view_mask)
    if len(xs) < 5:
        return None
    pts = np.column_stack([xs, ys]).astype(float)
    mean = pts.mean(axis=0)
    axis = np.linalg.eigh(np.cov((pts - mean).T))[1][:, -1]
    along = (pts - mean) @ axis
    ends = [_onto_plane(*(mean + np.percentile(along, q) * axis), K, world_from_cv, support_z) for q in (2.0, 98.0)]
    if ends[0] is None or ends[1] is None:
        return None
    d = ends[1] - ends[0]
    center = (ends[0] + ends[1]) / 2.0
    return float(center[0]), float(center[1]), float(np.arctan2(d[1], d[0])), float(np.hypot(*d))


def resting_start(kind: PrimitiveKind, view_mask: np.ndarray, K, world_from_cv, xy0, support_z: float = 0.0):
    """Where a fit of a primitive resting as ``kind`` starts: (x, y), its yaw starts [rad] and the
    length its mask shows along it [world units] (None but for a lying cylinder): a lying
    cylinder's on its mask's axis cast onto the plane, along it first (``lying_start``), where it
    has one; else ``xy0`` and the kind's ``yaw_starts``."""
    yaws = yaw_starts(kind)
    lying = lying_start(view_mask, K, world_from_cv, support_z) if kind is PrimitiveKind.LYING_CYLINDER else None
    if lying is None:
        return np.asarray(xy0), yaws, None
    x, y, yaw, length = lying
    return np.array([x, y]), (yaw, *yaws), length


def fit_standing(
    shape: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]],
    size0: np.ndarray,
    views: list[View],
    xy0: np.ndarray,
    *,
    support_z: float = 0.0,
    yaws: tuple[float, ...] = (0.0,),
    free_size: np.ndarray | None = None,
    turn: bool = True,
    maxfev: int = 300,
    convex: bool = False,
    size_cost: Callable[[np.ndarray], float] | None = None,
    step_m: float | None = None,
    step_deg: float = 20.0,
) -> StandingFit:
    """A shape standing on z = ``support_z``: position, yaw and (where ``free_size`` says) its
    size parameters fitted to the views' silhouettes.

    Args:
        shape: size parameters -> (vertices, faces) in the object frame (origin at the bottom's
            center, +Z up).
        size0: the size parameters to start from (all positive: searched on log scale).
        xy0: where to start (world x, y) [m].
        yaws: starting yaws [rad]; each start is refined, the best kept.
        free_size: bool per size parameter, True = fitted (default all).
        turn: whether yaw is fitted (not for a shape symmetric about +Z).
        size_cost: size parameters -> a cost added to 1 - IoU (``log_normal_sizes``).
        step_m, step_deg: the first simplex's steps in position (default 0.15 of the largest size
            parameter) and yaw: small ones keep a frame-to-frame refit near where it starts.
    """
    size0 = np.asarray(size0, float)
    free = np.ones(len(size0), bool) if free_size is None else np.asarray(free_size, bool)
    extent = float(np.max(size0))

    def unpack(p):
        size = size0.copy()
        size[free] = size0[free] * np.exp(p[3 : 3 + free.sum()])
        return p[0], p[1], (p[2] if turn else 0.0), size

    def cost(p):
        x, y, yaw, size = unpack(p)
        v, f = shape(size)
        world = se3.transform_points(standing_pose(x, y, yaw, support_z), v)
        return 1.0 - iou(views, world, f, convex=convex) + prior(size)

    def prior(size) -> float:
        return 0.0 if size_cost is None or not free.any() else size_cost(size)

    best = None
    for yaw in yaws:
        p0 = np.concatenate([[xy0[0], xy0[1], yaw], np.zeros(free.sum())])
        shift = 0.15 * extent if step_m is None else step_m
        steps = np.concatenate([[shift, shift, np.radians(step_deg)], np.full(free.sum(), 0.15)])
        p, c = nelder_mead(cost, p0, steps, maxfev=maxfev)
        p, c = nelder_mead(cost, p, steps / 4, maxfev=maxfev // 2)  # restart: the simplex collapses on plateaus
        if best is None or c < best[1]:
            best = (p, c)
    x, y, yaw, size = unpack(best[0])
    return StandingFit(float(x), float(y), float(yaw), size, 1.0 - best[1] + prior(size), float(best[1]))


def footprint_xy(view_mask: np.ndarray, K: np.ndarray, world_from_cv: np.ndarray, support_z: float = 0.0):
    """Where the mask's lowest pixels' ray meets the plane z = ``support_z`` (world x, y): the
    front of an object standing there; None when the ray points above the horizon."""
    ys, xs = np.nonzero(view_mask)
    if not len(ys):
        return None
    low = ys >= np.percentile(ys, 95)
    return _onto_plane(float(np.median(xs[low])), float(np.percentile(ys, 98)), K, world_from_cv, support_z)


def _onto_plane(u: float, v: float, K: np.ndarray, world_from_cv: np.ndarray, support_z: float):
    """Where pixel (u, v)'s ray meets the plane z = ``support_z`` (world x, y); None when the ray
    points above the horizon."""
    ray = world_from_cv[:3, :3] @ np.array([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], 1.0])
    origin = world_from_cv[:3, 3]
    if ray[2] > -1e-6:
        return None
    return (origin + (support_z - origin[2]) / ray[2] * ray)[:2]


# ----------------------------------------------------------------------------- free pose


def _fibonacci_sphere(n: int) -> np.ndarray:
    i = np.arange(n) + 0.5
    phi = np.arccos(1 - 2 * i / n)
    theta = np.pi * (1 + 5**0.5) * i
    return np.column_stack([np.cos(theta) * np.sin(phi), np.sin(theta) * np.sin(phi), np.cos(phi)])


def _look_rotation(direction: np.ndarray, roll: float) -> np.ndarray:
    """A rotation taking the object's +Z to ``direction`` (camera axes), then turned by ``roll`` about it."""
    z = direction / np.linalg.norm(direction)
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    base = np.column_stack([x, y, z])
    return base @ rot_z(roll)


def _centered(view: View, vertices: np.ndarray, faces: np.ndarray, rot: np.ndarray, z: float):
    """cam_from_object placing the rotated object's centroid on the mask's centroid ray at depth z."""
    ys, xs = np.nonzero(view.mask)
    k = view.K
    ray = np.array([(xs.mean() - k[0, 2]) / k[0, 0], (ys.mean() - k[1, 2]) / k[1, 1], 1.0])
    center = vertices.mean(axis=0)
    return se3.make_pose(rot, z * ray - rot @ center)


def search_free(
    vertices: np.ndarray,
    faces: np.ndarray,
    view: View,
    *,
    directions: int = 150,
    rolls: int = 12,
    keep: int = 6,
) -> list[tuple[float, np.ndarray]]:
    """The ``keep`` best world_from_object poses of a metric mesh for one view, from orientations
    spread over the sphere (``directions`` x ``rolls``), each at the depth where its silhouette's
    area matches the mask's: [(IoU, pose)], best first."""
    area = float(np.count_nonzero(view.mask))
    diameter = float(np.linalg.norm(vertices.max(axis=0) - vertices.min(axis=0)))
    ys, xs = np.nonzero(view.mask)
    extent_px = float(max(xs.max() - xs.min(), ys.max() - ys.min(), 1))
    z0 = view.K[0, 0] * diameter / extent_px
    cv_from_world = se3.invert(view.world_from_cv)
    found = []
    for d in _fibonacci_sphere(directions):
        for roll in np.linspace(0, 2 * np.pi, rolls, endpoint=False):
            rot = _look_rotation(d, roll)
            cam = _centered(view, vertices, faces, rot, z0)
            r = view.render(se3.transform_points(view.world_from_cv @ cam, vertices), faces)
            a = float(np.count_nonzero(r))
            if a < 4:
                continue
            z = z0 * np.sqrt(a / area)
            cam = _centered(view, vertices, faces, rot, z)
            world = view.world_from_cv @ cam
            found.append((iou([view], se3.transform_points(world, vertices), faces), world))
    found.sort(key=lambda f: -f[0])
    del cv_from_world
    return found[:keep]


def perturb(world_from_object: np.ndarray, view: View, p: np.ndarray) -> np.ndarray:
    """The pose moved by p = (rotation vector (3) [rad], shift (3)) in ``view``'s camera frame:
    the shift in x, y is in units of the depth (a fraction of the field of view), in z a log depth
    ratio, all about the object's origin as the camera sees it."""
    cam = se3.invert(view.world_from_cv) @ world_from_object
    z = cam[2, 3]
    rot = cv2.Rodrigues(np.asarray(p[:3], float))[0]
    t = cam[:3, 3]
    t_new = np.array([t[0] / t[2] + p[3], t[1] / t[2] + p[4], 1.0]) * z * np.exp(p[5])
    return view.world_from_cv @ se3.make_pose(rot @ cam[:3, :3], t_new)


def _pose_cost(vertices, faces, views: list[View], world_from_object, convex: bool, cost_extra, edge_weight: float):
    """The cost of ``perturb(world_from_object, views[0], p)``: 1 - IoU, plus ``cost_extra(pose)``,
    plus ``edge_weight`` times the views' mean ``View.edge_cost`` where it is above 0."""

    def cost(p):
        pose = perturb(world_from_object, views[0], p)
        extra = cost_extra(pose) if cost_extra is not None else 0.0
        world = se3.transform_points(pose, vertices)
        if edge_weight > 0:
            extra += edge_weight * float(np.mean([view.edge_cost(world, faces, convex=convex) for view in views]))
        return 1.0 - iou(views, world, faces, convex=convex) + extra

    return cost


def fit_free(
    vertices: np.ndarray,
    faces: np.ndarray,
    views: list[View],
    world_from_object: np.ndarray,
    *,
    maxfev: int = 300,
    step_deg: float = 6.0,
    step_shift: float = 0.01,
    cost_extra: Callable[[np.ndarray], float] | None = None,
    convex: bool = False,
) -> tuple[np.ndarray, float]:
    """The 6-DoF pose of a mesh (object frame) best fitting the views' silhouettes, from
    ``world_from_object``: (pose, IoU). ``cost_extra(pose)`` is added to 1 - IoU."""
    cost = _pose_cost(vertices, faces, views, world_from_object, convex, cost_extra, 0.0)
    steps = np.array([np.radians(step_deg)] * 3 + [step_shift, step_shift, 2 * step_shift])
    p, c = nelder_mead(cost, np.zeros(6), steps, maxfev=maxfev)
    for scale in (0.5, 0.25, 0.125):  # restarts: a collapsed simplex stalls on IoU's plateaus
        q, d = nelder_mead(cost, p, steps * scale, maxfev=maxfev // 2)
        if d < c - 1e-5:
            p, c = q, d
        elif scale < 0.25:
            break
    pose = perturb(world_from_object, views[0], p)
    return pose, iou(views, se3.transform_points(pose, vertices), faces, convex=convex)


def fit_edges(
    vertices: np.ndarray,
    faces: np.ndarray,
    views: list[View],
    world_from_object: np.ndarray,
    edge_weight: float,
    *,
    maxfev: int = 160,
    step_deg: float = 1.0,
    step_shift: float = 0.0025,
    cost_extra: Callable[[np.ndarray], float] | None = None,
    convex: bool = False,
) -> tuple[np.ndarray, float]:
    """A silhouette fit's pose refined with its outline asked onto the frames' image edges: 1 - IoU
    + ``edge_weight`` x the views' mean ``View.edge_cost`` (+ ``cost_extra``), from a small
    simplex: the silhouette finds the object, its edges the last pixels a mask has wrong.
    (pose, IoU); the pose unchanged where no view has an edge map."""
    if edge_weight <= 0 or all(view.edges is None for view in views):
        return world_from_object, iou(views, se3.transform_points(world_from_object, vertices), faces, convex=convex)
    cost = _pose_cost(vertices, faces, views, world_from_object, convex, cost_extra, edge_weight)
    steps = np.array([np.radians(step_deg)] * 3 + [step_shift, step_shift, 2 * step_shift])
    p, _ = nelder_mead(cost, np.zeros(6), steps, maxfev=maxfev)
    pose = perturb(world_from_object, views[0], p)
    return pose, iou(views, se3.transform_points(pose, vertices), faces, convex=convex)


# ----------------------------------------------------------------------------- color


class ColorPosterior:
    """How likely each pixel's color is the object's rather than its surroundings': color
    histograms (``bins`` per RGB channel) of the object's pixels and of a ring around them in one
    frame, P(object | color) = h_object / (h_object + h_around). A tracker that follows these
    probabilities (PWP3D's region term, here as a soft IoU) does not need the masks to be right."""

    def __init__(self, rgb: np.ndarray, inside: np.ndarray, around: np.ndarray, *, bins: int = 16):
        self.bins = bins
        count = bins**3
        idx = self._index(rgb)
        self.h_in = np.bincount(idx[inside], minlength=count).astype(np.float64) + 0.5
        self.h_out = np.bincount(idx[around], minlength=count).astype(np.float64) + 0.5
        self.h_in /= self.h_in.sum()
        self.h_out /= self.h_out.sum()

    def _index(self, rgb: np.ndarray) -> np.ndarray:
        q = (rgb.astype(np.int32) * self.bins) // 256
        return (q[..., 0] * self.bins + q[..., 1]) * self.bins + q[..., 2]

    def __call__(self, rgb: np.ndarray) -> np.ndarray:
        idx = self._index(rgb)
        p_in, p_out = self.h_in[idx], self.h_out[idx]
        return (p_in / (p_in + p_out)).astype(np.float32)

    @staticmethod
    def regions(silhouette_mask: np.ndarray, ignore: np.ndarray | None, *, ring_px: int = 25, gap_px: int = 4):
        """The object's pixels (its silhouette eroded by ``gap_px``) and a ring ``ring_px`` wide
        around it, ``gap_px`` off it, both outside ``ignore``."""
        sil = silhouette_mask.astype(np.uint8)
        inside = cv2.erode(sil, np.ones((2 * gap_px + 1,) * 2, np.uint8)).astype(bool)
        outer = cv2.dilate(sil, np.ones((2 * (ring_px + gap_px) + 1,) * 2, np.uint8)).astype(bool)
        inner = cv2.dilate(sil, np.ones((2 * gap_px + 1,) * 2, np.uint8)).astype(bool)
        around = outer & ~inner
        if ignore is not None:
            inside &= ~ignore
            around &= ~ignore
        return inside, around
