"""Metric scale for an RGB-only video: no measurement, only priors, each an explicit cue.

A monocular reconstruction (a static camera over a support plane at an unknown height, or a
structure-from-motion map) is right up to one scale factor. The prompted object is segmented in
its prompt frame (GrabCut in the prompt box) and a shape resting on the support plane (a can
standing or lying) is fitted to that silhouette in the reconstruction's units
(``geometry.silhouette.fit_standing``):

- ``mesh``: the object's metric mesh (rose.toml's ``mesh``, not TRELLIS's unit cube), its scale
  free: meters per unit = 1 / the fitted scale (a few % on a clean silhouette);
- ``size-prior``: the category's primitive with free dimensions; its largest dimension against
  the object's ``size_m``;
- ``category-prior``: the same fit against the category's typical size (``geometry.primitives``),
  uncertain by the category's spread (8-60 %);
- ``camera-height``: a hand-held or tripod camera filming a tabletop from about 0.5 m above it
  (+-50 %), when nothing else is known.

The most certain cue is chosen; every cue, its value and its sigma go into the world layer, with
their agreement (each cue's ratio to the chosen one, in sigmas) in the provenance.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from rose_usd.case.config import ObjectSpec
from rose_usd.core import se3
from rose_usd.core.grabcut import SEEDS, box_grabcut
from rose_usd.geometry.primitives import (
    MUG_REACH_SIGMA,
    RESTING_MARGIN,
    PrimitiveKind,
    hull_points,
    largest_dimension,
    resting_kinds,
    turns,
    typical,
)
from rose_usd.geometry.silhouette import (
    View,
    crop_view,
    fit_standing,
    footprint_xy,
    log_normal_ratio,
    resting_start,
)
from rose_usd.progress import progress

CAMERA_HEIGHT_M = (0.5, 0.5)
"""A tabletop video's camera height over the support: (typical [m], relative sigma)."""
LEVEL_GRID_DEG = 10.0
"""The leveling's grid of starts: their spacing in pitch [deg]."""
LEVEL_ROLL_DEG = 8.0
"""The leveling's grid of starts: rolled this far each way, and not [deg]."""
LEVEL_DESCENTS = 4
"""The leveling descends from this many of its grid's best starts."""


@dataclass
class ScaleCue:
    name: str
    """Schema token: mesh, size-prior, category-prior, hand, camera-height."""
    meters_per_unit: float
    sigma: float
    """Relative one-sigma [-]."""
    detail: dict = field(default_factory=dict)


def prompt_silhouette(
    rgb: np.ndarray, box: tuple[float, float, float, float], *, max_side: int = 640, seeds: int = SEEDS
) -> np.ndarray:
    """The object's mask in the prompt frame: GrabCut in the prompt box (``core.grabcut``; one seed
    for a box made around a point prompt, which says nothing of the object's extent), its largest
    part with holes filled (bool, the frame's size)."""
    h, w = rgb.shape[:2]
    s = min(1.0, max_side / max(w, h))
    small = cv2.resize(rgb, (int(round(w * s)), int(round(h * s))), interpolation=cv2.INTER_AREA) if s < 1 else rgb
    x0, y0, x1, y1 = (int(round(v * s)) for v in box)
    x0, y0 = max(x0, 1), max(y0, 1)
    x1, y1 = min(x1, small.shape[1] - 2), min(y1, small.shape[0] - 2)
    fg = box_grabcut(small, (x0, y0, x1, y1), seeds=seeds).astype(np.uint8)
    contours, _ = cv2.findContours(fg, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    cv2.drawContours(fg, contours, -1, 1, thickness=cv2.FILLED)
    return cv2.resize(fg, (w, h), interpolation=cv2.INTER_NEAREST).astype(bool)


def _view(mask: np.ndarray, K: np.ndarray, world_from_cv: np.ndarray) -> View:
    return crop_view(mask, None, K, world_from_cv, max_side=320)


def _standing_start(mask: np.ndarray, K, world_from_cv) -> tuple[float, np.ndarray] | None:
    """Where a fit of an object standing on z = 0 starts: the mask's width at its foot's depth
    (world units) and a centre behind its front (the foot), away from the camera; None when the
    foot is not below the horizon."""
    xy = footprint_xy(mask, K, world_from_cv)
    if xy is None:
        return None
    ys, xs = np.nonzero(mask)
    foot = se3.invert(world_from_cv) @ np.array([*xy, 0.0, 1.0])
    width_units = float(xs.max() - xs.min()) * foot[2] / K[0, 0]
    toward = np.asarray(xy) - world_from_cv[:3, 3][:2]
    return width_units, np.asarray(xy) + 0.3 * width_units * toward / max(np.linalg.norm(toward), 1e-9)


def fit_primitive(
    spec: ObjectSpec,
    view: View,
    mask: np.ndarray,
    K,
    world_from_cv,
    *,
    maxfev: int = 300,
    kinds: tuple[PrimitiveKind, ...] | None = None,
) -> dict | None:
    """The category's primitive resting on z = 0 fitted to the silhouette, in the world's units:
    its kind (a can standing, or lying where that fits clearly better: ``resting_kinds``, or
    ``kinds``),
    dimensions, largest dimension, pose and IoU; None when the object's foot is not below the
    horizon."""
    typ, _ = typical(spec.category)
    start = _standing_start(mask, K, world_from_cv)
    if start is None:
        return None
    best = None
    for kind in kinds or resting_kinds(typ.kind):
        fit = _fit_kind(kind, typ, view, mask, K, world_from_cv, start, maxfev)
        if best is None or fit.iou > best[1].iou + RESTING_MARGIN:
            best = (kind, fit)
    kind, fit = best
    return {
        "kind": kind.value,
        "dims": fit.size,
        "size_units": largest_dimension(kind, fit.size),
        "iou": fit.iou,
        "pose": fit.pose(),
        "typical_size_m": typ.size_m,
        "typical_sigma": typ.sigma,
        "typical_source": typ.source,
    }


def _fit_kind(kind: PrimitiveKind, typ, view: View, mask, K, world_from_cv, start, maxfev: int):
    """One resting kind's fit, from the typical shape scaled to the mask's width at its foot's
    depth (a lying one's: to the length of the mask's axis on the plane, along it)."""
    width_units, xy0 = start
    xy0, yaws, length = resting_start(kind, mask, K, world_from_cv, xy0)
    dims0 = np.asarray(typ.dims) * max(length or 0.0, width_units) / max(typ.size_m, 1e-6)
    # the overall size is what is measured; only a mug's handle reach, which a view from behind
    # leaves open, is held near its typical proportion to the radius
    shape_cost = (
        log_normal_ratio(2, 0, typ.dims[2] / typ.dims[0], MUG_REACH_SIGMA) if kind is PrimitiveKind.MUG else None
    )
    return fit_standing(
        lambda d: hull_points(kind, d),
        dims0,
        [view],
        xy0,
        yaws=yaws,
        turn=turns(kind),
        convex=True,
        maxfev=maxfev,
        size_cost=shape_cost,
    )


def level_by_object(
    spec: ObjectSpec,
    mask: np.ndarray,
    K: np.ndarray,
    world_from_cv: np.ndarray,
    sigma_deg: float,
) -> tuple[np.ndarray, dict]:
    """The world's tilt that makes the prompted object stand on the support best: the rotation
    (4, 4) about the world origin (the object's foot) by which the world's up is corrected, and
    what the search found. A primitive standing on a tilted plane does not fit the silhouette of
    one standing on the true one (a cup's rim ellipse, a box's vertical edges), so the tilt (two
    angles) is fitted with the primitive, with a prior of ``sigma_deg`` on it (the gravity source's
    sigma): one sigma of tilt costs 0.01 of IoU. The identity when nothing improves.

    One image's lines most often misplace the horizon, a pitch error of 30-50 deg where a camera
    looking down at a table is taken for a level one; a local search from the level start stops a
    few degrees out. So the search spans ``level_search_deg(sigma_deg)``: a grid of starts over it
    (``LEVEL_GRID_DEG`` apart in the reference camera's pitch, about its right made horizontal;
    three rolls), then Nelder-Mead from the ``LEVEL_DESCENTS`` best starts and from level: the
    cost is rugged (each value is itself a fit), and the best start's valley is not always the
    deepest (a can pitched 45 deg off, its world turned: 14 deg left from the best start, 0.9 deg
    from the fourth)."""
    from rose_usd.geometry.silhouette import nelder_mead

    span = level_search_deg(sigma_deg)
    at_level = fit_primitive(spec, crop_view(mask, None, K, world_from_cv, max_side=240), mask, K, world_from_cv)
    kinds = (PrimitiveKind(at_level["kind"]),) if at_level is not None else None  # the tilt searched for it

    def cost(tilt_deg):
        if np.hypot(*tilt_deg) > span:
            return 2.0
        pose = _tilt(tilt_deg) @ world_from_cv
        fit = fit_primitive(spec, crop_view(mask, None, K, pose, max_side=240), mask, K, pose, maxfev=150, kinds=kinds)
        iou = fit["iou"] if fit is not None else 0.0
        return 1.0 - iou + 0.01 * float(np.sum(np.square(tilt_deg))) / max(sigma_deg, 0.5) ** 2

    level = cost(np.zeros(2))
    pitches = np.arange(-span, span + 1e-9, LEVEL_GRID_DEG)
    # the tilt turns about the world's x then y; the world's x is the first camera's right, so the
    # reference camera's pitch and roll are turned by its right's heading (to first order)
    c, s = world_from_cv[:2, 0] / max(float(np.linalg.norm(world_from_cv[:2, 0])), 1e-9)
    heading = np.array([[c, -s], [s, c]])
    starts = [heading @ np.array([a, b]) for a in pitches for b in (-LEVEL_ROLL_DEG, 0.0, LEVEL_ROLL_DEG)]
    starts = [x for x in starts if np.hypot(*x) <= span]
    grid = [cost(x) for x in progress(starts, "capture: levelling by the object's fit", unit="tilt")]
    best, best_cost = np.zeros(2), level
    descents = [starts[i] for i in np.argsort(grid)[:LEVEL_DESCENTS]] + [np.zeros(2)]
    for x0 in progress(descents, "capture: refining the tilt", unit="descent"):
        x, c = nelder_mead(cost, x0, np.array([4.0, 4.0]), maxfev=40)
        if c < best_cost:
            best, best_cost = x, c
    record = {"search_deg": round(span, 1), "cost_level": round(level, 4), "cost_tilted": round(best_cost, 4)}
    if best_cost >= level - 0.005:
        return np.eye(4), {"tilt_deg": [0.0, 0.0], **record}
    return _tilt(best), {"tilt_deg": [round(float(a), 2) for a in best], **record}


def level_search_deg(sigma_deg: float) -> float:
    """How far the leveling searches: two sigmas of the gravity source, within 25-60 deg."""
    return float(np.clip(2.0 * sigma_deg, 25.0, 60.0))


def _tilt(tilt_deg) -> np.ndarray:
    """A rotation about the world's x then y axes by the given degrees."""
    a, b = np.radians(tilt_deg)
    rx = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    ry = np.array([[np.cos(b), 0, np.sin(b)], [0, 1, 0], [-np.sin(b), 0, np.cos(b)]])
    return se3.make_pose(ry @ rx, np.zeros(3))


def fit_mesh(vertices: np.ndarray, faces: np.ndarray, view: View, mask, K, world_from_cv) -> dict | None:
    """A metric mesh (its +Z up, its lowest point at z = 0) standing on the support, its scale
    free: the fitted scale (units per meter), pose and IoU."""
    start = _standing_start(mask, K, world_from_cv)
    if start is None:
        return None
    width_units, xy0 = start
    extent = float(np.max(vertices.max(axis=0) - vertices.min(axis=0)))
    rho0 = width_units / max(extent, 1e-9)
    base = vertices - np.array([*(0.5 * (vertices.min(axis=0) + vertices.max(axis=0)))[:2], vertices[:, 2].min()])
    fit = fit_standing(
        lambda r: (base * r[0], faces), np.array([rho0]), [view], xy0, yaws=tuple(np.radians([0.0, 45.0, 90.0, 135.0]))
    )
    return {"rho": float(fit.size[0]), "iou": fit.iou, "pose": fit.pose()}


def choose(cues: list[ScaleCue]) -> tuple[ScaleCue, dict]:
    """The most certain cue and each cue's agreement with it: {name: (ratio, sigmas apart)}."""
    chosen = min(cues, key=lambda c: c.sigma)
    agreement = {}
    for c in cues:
        ratio = c.meters_per_unit / chosen.meters_per_unit
        apart = abs(np.log(ratio)) / max(np.hypot(c.sigma, chosen.sigma), 1e-9) if c is not chosen else 0.0
        agreement[c.name] = {"ratio": round(float(ratio), 4), "sigmas_apart": round(float(apart), 2)}
    return chosen, agreement
