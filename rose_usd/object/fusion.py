"""The ``fusion`` object backend: a metric, watertight mesh of each object from its masked depth,
with no imported mesh. No learned model.

1. **Rest.** The object's masked, back-projected depth (masks eroded by 1 px, away from mixed
   edge pixels) gives a world point cloud per frame. It rests from its first clear view for as
   long as its points of that view, projected into later frames, still meet the depth there
   (within ``rest_tolerance_m``), and until the interactor first touches it; those frames are
   fused (the world frame is the object's frame while it rests). Only those: the frames after,
   mapped into the rest by the tracked trajectory, carry the trajectory's errors into the shape
   and mostly make it worse (``benchmarks/tracked_fusion.py`` measures both).
2. **Clean.** One point per ``voxel_m`` voxel, marked "often seen" when seen at least a tenth as
   often as the most seen voxel near it (``seen_voxels``: the depth noise's tail, a few points per
   frame a few mm off a surface, is not), statistical outliers dropped, points that a
   resting frame sees past dropped (flying pixels at the silhouette, fused over many frames,
   form a dense wall that outlier removal keeps), and points within
   ``support_gap_m`` of the surface around the object dropped (the table at the mask's border;
   that surface's height is measured in a ring of pixels around the mask, since the world's
   z = 0 is one plane for the whole scene and may be off under this object).
3. **Complete** what was never seen. The face on the support is flat at the support under the
   seen footprint (the surface around it, or the top of the object it stands on: the top of a stack's lower
   object seen around the upper one). A solid of revolution (a can, a mug's body: the radial distance of the points to a
   fitted vertical axis varies by under ``revolution_tolerance`` of the radius within each height
   band) is completed by revolving its median profile up to its top. The axis is fitted to the
   side's points only (the top face's points near its rim are not wall) that face away from it
   toward their cameras (each fused point keeps its mean direction to the cameras that saw it: a
   mug's far inner wall, seen over the rim, faces the other way and would make the mug narrow),
   finally by geometric least squares (Kasa's algebraic fit of an arc seen from one
   side is pulled toward the camera and shrunk). A solid of revolution whose inner wall shows
   over its rim (points facing the axis, inside the outer wall) is an open vessel: its cavity has
   the inner wall's radius, down to the inner bottom where seen, else to the wall's thickness
   above the support (``vessel_cavity``); its mass is then that of the modeled wall.
   Anything else is completed as a height field standing on the support: walls go
   straight down from the seen rim to the table, around the convex hull of the often seen points.
   Heights (a column's, the top of a solid of revolution) are upper medians of the points
   (``cell_upper_median``, ``top_height``): the highest point is raised by the depth noise, by
   several millimeters.
4. **Close**: the completed solid is a voxel grid (``voxel_m``) whose occupancy ramps from 1 to 0
   over two voxels across a completed surface, so marching cubes puts the surface where it is,
   not on a voxel face; seen points outside it count only in parts of a dozen voxels or more
   (a mug's handle, not the noise). Its surface is watertight by construction, smoothed (Taubin)
   and decimated to ``max_triangles``, then checked watertight, 2-manifold, oriented and free of
   self-intersections. (Not an alpha wrap of the completed points: it enters the solid and
   returns a thin shell.)
5. **Priors**: density, friction and restitution from the category table (rose.toml may fix any
   of them, or mass_kg); mass = density x volume, or x the wall's volume for hollow categories;
   center of mass and inertia from the mesh.
"""

from __future__ import annotations

import itertools
import warnings
from dataclasses import dataclass

import cv2
import numpy as np
from scipy.spatial import ConvexHull, cKDTree

from rose_usd.capture.depth import depth_is_sensor, metric_depth_reader
from rose_usd.core import se3
from rose_usd.core.color import srgb8_to_linear
from rose_usd.core.inertia import mass_properties, shell_mass_properties
from rose_usd.core.pinhole import masked_world_points, pixels_of, view_counts
from rose_usd.core.watertight import collider_problems
from rose_usd.errors import InputError, MeshError
from rose_usd.io.images import read_mask
from rose_usd.object.author import ObjectModel, PhysicsValues, author_objects
from rose_usd.object.priors import lookup
from rose_usd.progress import progress
from rose_usd.scene.tsdf import self_intersects, transfer_colors
from rose_usd.segment.contact import first_contact, ring_height
from rose_usd.segment.tracks import INTERACTOR
from rose_usd.stage_api import StageContext
from rose_usd.usd import paths
from rose_usd.usd.camera import read_camera
from rose_usd.usd.geom import MeshData


def masked_points(
    depth: np.ndarray, mask: np.ndarray, rgb: np.ndarray, K: np.ndarray, world_from_cv: np.ndarray, erode_px: int = 1
):
    """World points and sRGB colors of the mask's pixels with depth (mask eroded by ``erode_px``:
    its border pixels mix the object's depth with what is behind it). Pixels at a depth
    discontinuity are not all left out as well: that shrinks the object more than it helps."""
    pts, (v, u) = masked_world_points(depth, mask, K, world_from_cv, erode_px=erode_px)
    return pts, rgb[v, u]


def rest_frames(
    ref_frame: int, n: int, sample, tolerance_m: float, *, scale_drift: bool = False
) -> list[tuple[int, float]]:
    """Frames from ``ref_frame`` on in which the object is still where it was then, each with the
    ratio of its depth there to the reference frame's (1 for a sensor).

    ``sample(t)`` gives (depth, mask, K, world_from_cv) of frame t (None when the object is not
    seen). The object's points of the reference frame are projected into frame t; where they
    land on the object's mask, the depth must agree within ``tolerance_m`` for most of them. Newly
    revealed parts (the top of a stack's lower object, once the upper one is lifted) do not count
    as motion, and a hand covering part of the object only leaves fewer points to compare.
    With ``scale_drift`` (depth that is not a sensor's: MegaSaM's scale varies by a few % from
    frame to frame), the frame's median depth ratio (within 6 %) is divided out first."""
    depth, mask, K, pose = sample(ref_frame)
    ref, _ = masked_points(depth, mask, np.zeros((*mask.shape, 3), np.uint8), K, pose)
    ref = ref[:: max(1, len(ref) // 3000)]
    frames = []
    for t in range(ref_frame, n):
        got = sample(t)
        if got is None:
            continue
        depth, mask, K, pose = got
        u, v, z = pixels_of(ref, pose, K, mask.shape[1], mask.shape[0])
        inside = u >= 0
        u, v, zz = u[inside], v[inside], z[inside]
        d = depth[v, u]
        on = mask[v, u] & (d > 0)
        ratio = float(np.median(d[on] / zz[on])) if scale_drift and on.sum() >= 30 else 1.0
        if abs(ratio - 1.0) > 0.06:
            break  # moved along the view (or the depth jumped): not the same rest
        d = d / np.float32(ratio)
        unhidden = ~((d > 0) & (d < zz - tolerance_m))  # nothing (a hand) in front of the point
        if unhidden.sum() < 30:
            continue  # hidden: nothing to compare
        on_mask = float(np.mean(mask[v[unhidden], u[unhidden]]))
        on = unhidden & on
        agree = float(np.mean(np.abs(d[on] - zz[on]) < tolerance_m)) if on.sum() >= 30 else 0.0
        if on_mask < 0.6 or agree < 0.3:
            break  # moved
        if on_mask >= 0.93 and agree >= 0.6:
            frames.append((t, ratio))
    return frames


def _circle_fit(xy: np.ndarray, *, geometric: bool = False, scale_m: float = 0.002) -> tuple[np.ndarray, float]:
    """Least-squares circle: center (2,), radius. Algebraic (Kasa) by default; with ``geometric``,
    refined on the points' distances to the circle (robust, soft L1 beyond ``scale_m``): Kasa's fit
    of an arc seen from one side is pulled toward the arc and shrunk by the noise."""
    a = np.column_stack([2 * xy, np.ones(len(xy))])
    b = (xy**2).sum(axis=1)
    sol, *_ = np.linalg.lstsq(a, b, rcond=None)
    center = sol[:2]
    radius = float(np.sqrt(max(sol[2] + center @ center, 0.0)))
    if geometric and radius > 0:
        from scipy.optimize import least_squares

        fit = least_squares(
            lambda q: np.hypot(xy[:, 0] - q[0], xy[:, 1] - q[1]) - q[2],
            [*center, radius],
            loss="soft_l1",
            f_scale=scale_m,
        )
        center, radius = fit.x[:2], float(fit.x[2])
    return center, radius


def cell_upper_median(cells: np.ndarray, z: np.ndarray, band_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Per cell (``cells``: one integer id per point) the median height of its points within
    ``band_m`` of its highest: a top face's height with its noise averaged (the highest point is
    biased up by it), and a wall's points below the rim left out. Returns (cell ids, heights)."""
    order = np.lexsort((z, cells))
    c, zs = cells[order], z[order]
    starts = np.flatnonzero(np.r_[True, c[1:] != c[:-1]])
    ends = np.r_[starts[1:], len(c)]
    owner = np.repeat(np.arange(len(starts)), ends - starts)
    k = np.add.reduceat((zs >= zs[ends - 1][owner] - band_m).astype(int), starts)  # the last k of each cell
    lo = ends - k
    return c[starts], 0.5 * (zs[lo + (k - 1) // 2] + zs[lo + k // 2])


def top_height(points: np.ndarray, step_m: float, band_m: float = 0.005) -> float:
    """The height of an object's top: the median, over the columns (``step_m`` cells) whose upper
    median (``cell_upper_median``) lies within ``band_m`` of the highest columns' (98th percentile),
    of those upper medians. Unbiased by the depth noise that makes the highest point centimeters'
    fractions too high."""
    ij = np.floor(points[:, :2] / step_m).astype(np.int64)
    ids = (ij[:, 0] - ij[:, 0].min()) * (int(ij[:, 1].max() - ij[:, 1].min()) + 1) + (ij[:, 1] - ij[:, 1].min())
    _, h = cell_upper_median(ids, points[:, 2], band_m)
    return float(np.median(h[h >= np.percentile(h, 98) - band_m]))


def _sector_outer(r: np.ndarray, sector: np.ndarray, n_sectors: int, min_points: int = 5) -> np.ndarray:
    """Each angular sector's outer radius (the 90th percentile of its points' radii; NaN with fewer
    than ``min_points``)."""
    outer = np.full(n_sectors, np.nan)
    order = np.argsort(sector, kind="stable")
    bounds = np.searchsorted(sector[order], np.arange(n_sectors + 1))
    for k in range(n_sectors):
        rr = r[order[bounds[k] : bounds[k + 1]]]
        if len(rr) >= min_points:
            outer[k] = np.percentile(rr, 90)
    return outer


def _polar(xy: np.ndarray, center: np.ndarray, n_sectors: int) -> tuple[np.ndarray, np.ndarray]:
    """Each point's distance from ``center`` and the index of its angular sector."""
    d = xy - center
    sector = ((np.arctan2(d[:, 1], d[:, 0]) + np.pi) / (2 * np.pi) * n_sectors).astype(int) % n_sectors
    return np.hypot(d[:, 0], d[:, 1]), sector


def _facing_out(xy: np.ndarray, toward_xy: np.ndarray | None, center: np.ndarray) -> np.ndarray:
    """Which points face away from the axis through ``center`` toward their cameras (``toward_xy``:
    the horizontal part of the direction to them): an outer wall. A vessel's inner wall, seen over
    its rim from across the axis, faces the other way. All of them without directions."""
    if toward_xy is None:
        return np.ones(len(xy), bool)
    return np.einsum("ij,ij->i", xy - center, toward_xy) > 0


def _axis_fit(xy: np.ndarray, center: np.ndarray, n_sectors: int) -> tuple[np.ndarray, float] | None:
    """A vertical axis (center, radius) fitted from ``center`` on the outer wall of the 10 deg sectors
    whose outer radius agrees (within 5 % of their median), three times, the last by geometric
    least squares; None when too few sectors or points are seen to trust it."""
    for k in range(3):
        r, sector = _polar(xy, center, n_sectors)
        outer = _sector_outer(r, sector, n_sectors)
        if np.count_nonzero(np.isfinite(outer)) < n_sectors // 3:
            return None  # the angular coverage must be enough to trust the axis
        typical = float(np.nanmedian(outer))
        # sectors within 5 %: a handle stands out, and so does a far side seen only as the inner
        # wall over the rim
        agree = np.isfinite(outer) & (np.abs(outer - typical) <= 0.05 * typical)
        wall = agree[sector] & (r >= 0.85 * np.where(np.isfinite(outer), outer, np.inf)[sector])
        if wall.sum() < 30:
            return None
        center, radius = _circle_fit(xy[wall], geometric=k == 2)
    return center, radius


def revolution_profile(
    points: np.ndarray, band_m: float, tolerance: float, *, toward: np.ndarray | None = None, n_sectors: int = 36
):
    """(axis center (2,), heights, radii) when the points are a solid of revolution about a
    vertical axis, else None.

    Looked at in 10 deg sectors around the axis: a solid of revolution has the same outer radius in
    every sector of a height band, up to ``tolerance`` of the radius (the median over the band's
    sectors); a few sectors may stand out (a mug's handle) and are left out of the axis fit and the
    radii (the fit keeps sectors within 5 % of the median, the radii within 15 %). Points inside
    the wall (a mug's inner wall, seen over its rim) never set a sector's outer radius.

    ``toward`` (N, 3), each point's mean unit direction to the cameras that saw it, tells a vessel's
    inner wall from its outer one where only one of them is seen: a camera on one side of a mug
    sees its near outer wall and the far side's inner wall, which by radius alone are one circle
    smaller by half the wall and off the axis by as much (a fit to both makes the vessel narrow)."""
    # the axis is fitted on the side: the top face's points near its rim are not on the wall
    ztop = top_height(points, 0.5 * band_m)
    side = points[:, 2] < ztop - 2 * band_m
    if side.sum() < 100:
        side = np.ones(len(points), bool)
    xy = points[side, :2]
    toward_xy = None if toward is None else toward[:, :2]
    fit = _axis_fit(xy, _circle_fit(xy)[0], n_sectors)
    if fit is None:
        return None
    center, radius = fit
    if toward_xy is not None:  # again on the outer wall's points: the mix's axis is off by half the wall at most
        out = _facing_out(xy, toward_xy[side], center)
        if out.sum() >= 100:
            center, radius = _axis_fit(xy[out], center, n_sectors) or (center, radius)
    if radius <= 0:
        return None
    xy = points[:, :2]
    r, sector = _polar(xy, center, n_sectors)
    wall_side = (points[:, 2] < ztop - 0.5 * band_m) & _facing_out(
        xy, toward_xy, center
    )  # the top face's points are not wall
    z = np.where(wall_side, points[:, 2], np.inf)
    edges = np.arange(0.0, ztop, band_m)
    heights, radii, spread = [], [], []
    for lo, hi in zip(edges[:-1], edges[1:]):
        sel = (z >= lo) & (z < hi)
        if sel.sum() < 20:
            continue
        outer = _sector_outer(r[sel], sector[sel], n_sectors, min_points=3)
        if np.count_nonzero(np.isfinite(outer)) < 3:
            continue
        typical = float(np.nanmedian(outer))
        keep = np.isfinite(outer) & (np.abs(outer - typical) <= 0.15 * typical)  # a handle's sectors out
        rr = r[sel][keep[sector[sel]]]
        # points on the outer wall: the rim of a band seen from above holds inner points too
        wall = rr[rr > 0.8 * np.median(rr)]
        heights.append(0.5 * (lo + hi))
        radii.append(float(np.median(wall)))
        spread.append(float(np.nanmedian(np.abs(outer[np.isfinite(outer)] - typical))) / max(typical, 1e-6))
    if len(heights) < 3 or np.median(spread) > tolerance:
        return None
    return center, np.array(heights), np.array(radii)


def vessel_cavity(
    points: np.ndarray,
    toward: np.ndarray | None,
    center: np.ndarray,
    heights: np.ndarray,
    radii: np.ndarray,
    top: float,
    band_m: float,
    *,
    step_m: float,
):
    """(floor height, heights, inner radii, whether the floor was seen) of the cavity of a solid of
    revolution that is an open vessel (a mug, a bowl), else None.

    A vessel shows its inner wall over its rim: points that face the axis, not away from it, toward
    their cameras (``toward``), at least 1.5 voxels inside the outer wall. At least 60 of them over
    three ``band_m`` bands make it one, unless most of what is seen near the axis is at the top (a
    can's lid). Its inner radius per band is their median radius (the nearest band's where none is
    seen). The floor is the median height of the points seen near the axis below the rim (its
    inner bottom); where that was never seen, as high as the wall is thick (a uniform wall: cameras
    looking over the rim may see the inner wall only part of the way down, and a cavity only that
    deep would leave a heavy solid bottom)."""
    if toward is None:
        return None
    pr = np.hypot(points[:, 0] - center[0], points[:, 1] - center[1])
    outer = np.interp(points[:, 2], heights, radii)
    below_rim = points[:, 2] < top - band_m
    near_axis = pr < 0.5 * outer
    if near_axis.sum() >= 30 and np.mean(points[near_axis, 2] >= top - band_m) > 0.5:
        return None  # a lid
    bottom = near_axis & below_rim
    seen_floor = float(np.median(points[bottom, 2])) if bottom.sum() >= 30 else None
    # the inner wall above the floor (the floor's points near the wall are not wall)
    above_floor = points[:, 2] > (seen_floor + 0.5 * band_m if seen_floor is not None else -np.inf)
    inner = (
        below_rim
        & above_floor
        & ~_facing_out(points[:, :2], toward[:, :2], center)
        & (pr < outer - 1.5 * step_m)
        & (pr > 0.6 * outer)
    )
    bands = np.floor(points[inner, 2] / band_m).astype(int)
    if inner.sum() < 60 or len(np.unique(bands)) < 3:
        return None
    in_heights, in_radii = [], []
    for b in np.unique(bands):
        sel = bands == b
        if sel.sum() >= 10:
            in_heights.append((b + 0.5) * band_m)
            in_radii.append(float(np.median(pr[inner][sel])))
    if len(in_heights) < 2:
        return None
    in_heights, in_radii = np.array(in_heights), np.array(in_radii)
    outer_there = np.interp(in_heights, heights, radii)
    in_radii = np.minimum(in_radii, outer_there - 1.5 * step_m)
    wall = float(np.median(outer_there - in_radii))
    floor = max(seen_floor if seen_floor is not None else wall, 1.5 * step_m)  # a vessel stands on a bottom
    if floor >= top - band_m:
        return None
    return floor, in_heights, in_radii, seen_floor is not None


def solid_from_points(
    points: np.ndarray,
    *,
    step_m: float,
    band_m: float,
    tolerance: float,
    outline: np.ndarray | None = None,
    toward: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, str]:
    """The object's solid as a voxel grid built from the seen points and what completes them:
    (occupancy (X, Y, Z) float in [0, 1], grid origin (3,) = the corner of voxel 0, step, how).
    ``outline`` (bool per point, default all): the points a height field's footprint is drawn
    around (``seen_voxels``' often seen ones). ``toward``: each point's unit direction to its
    cameras (``revolution_profile``).

    Voxel k spans z in [k, k+1) * step, so the solid's bottom face is the support, z = 0. Near a
    completed surface (the revolved wall, a top at its height) the occupancy ramps linearly from 1
    to 0 over two voxels, so that its 0.5 level lies where the surface is, not on a voxel face."""
    from scipy import ndimage

    top = float(points[:, 2].max())
    lo = np.array([*(points[:, :2].min(axis=0) - 3 * step_m), 0.0])
    hi = np.array([*(points[:, :2].max(axis=0) + 3 * step_m), top + step_m])
    shape = tuple(np.ceil((hi - lo) / step_m).astype(int))
    centers = [lo[a] + (np.arange(shape[a]) + 0.5) * step_m for a in range(3)]
    x, y = np.meshgrid(centers[0], centers[1], indexing="ij")
    z = centers[2]
    rev = revolution_profile(points, band_m, tolerance, toward=toward)
    idx = np.clip(np.floor((points - lo) / step_m).astype(int), 0, np.array(shape) - 1)
    if rev is not None:
        center, heights, radii = rev
        rz = np.interp(z, heights, radii)
        r = np.hypot(x - center[0], y - center[1])
        top_face = top_height(points, step_m)  # the grid's ``top`` is the highest point, noise and all
        solid = np.minimum(_ramp(rz[None, None, :] - r[..., None], step_m), _ramp(top_face - z, step_m)[None, None, :])
        # seen points well outside the revolved solid are solid too (a mug's handle); the depth
        # noise's few points a little outside its wall or above its top are not
        pr = np.hypot(points[:, 0] - center[0], points[:, 1] - center[1])
        out = (pr > np.interp(points[:, 2], heights, radii) + 2 * step_m) & (points[:, 2] < top_face)
        solid[_large_parts(idx[out], shape, min_voxels=12)] = 1.0
        how = "revolution"
        cavity = vessel_cavity(points, toward, center, heights, radii, top_face, band_m, step_m=step_m)
        if cavity is not None:  # open at the top, down to its floor
            floor, in_heights, in_radii, floor_seen = cavity
            empty = np.minimum(
                _ramp(np.interp(z, in_heights, in_radii)[None, None, :] - r[..., None], step_m),
                _ramp(z - floor, step_m)[None, None, :],
            )
            solid = np.minimum(solid, 1.0 - empty)
            how = "vessel" if floor_seen else "vessel (floor not seen: as thick as the wall)"
    else:
        # a height field standing on the support: under every seen point the object is solid
        # down to the table; the footprint is the seen one, closed and made convex-hull-tight.
        # A cell's height is its points' upper median: the highest is biased up by the noise
        cells = idx[:, :2]
        ids, upper = cell_upper_median(cells[:, 0] * shape[1] + cells[:, 1], points[:, 2], 0.006)
        height = np.zeros(shape[:2])
        height[ids // shape[1], ids % shape[1]] = upper
        # closed with nothing beyond the grid: by default the erosion takes the border as inside,
        # and a seen cell 2 voxels from the grid's edge grows a spike to it (a wall's height)
        foot = cv2.morphologyEx(
            (height > 0).astype(np.uint8),
            cv2.MORPH_CLOSE,
            np.ones((5, 5), np.uint8),
            borderType=cv2.BORDER_CONSTANT,
            borderValue=0,
        )
        around = points[:, :2] if outline is None or np.count_nonzero(outline) < 3 else points[outline, :2]
        hull = ConvexHull(around)
        poly = np.round((around[hull.vertices] - lo[:2]) / step_m - 0.5).astype(np.int32)[:, ::-1]
        cv2.fillConvexPoly(foot, poly, 1)
        # the walls at the hull's edges, not on the faces of the cells it touches (up to a voxel
        # out): the occupancy ramps across them like a top's, so the cells around the foot join in
        foot = ndimage.binary_dilation(foot.astype(bool), np.ones((3, 3), bool))
        inside_hull = -np.max(
            np.einsum("ijk,nk->ijn", np.stack([x, y], axis=-1), hull.equations[:, :2]) + hull.equations[:, 2], axis=-1
        )
        # the highest point of a cell is biased up by depth noise: take the median of its neighbors'
        seen = height > 0
        with warnings.catch_warnings():  # cells with no seen neighbor: NaN, left as they are
            warnings.simplefilter("ignore", RuntimeWarning)
            smooth = ndimage.generic_filter(
                np.where(seen, height, np.nan), np.nanmedian, size=5, mode="constant", cval=np.nan
            )
        height = np.where(seen & np.isfinite(smooth), smooth, height)
        if np.any(foot & (height <= 0)):  # cells never seen from above: the nearest seen cell's height
            seen_idx = np.argwhere(height > 0)
            missing = np.argwhere(foot & (height <= 0))
            _, nearest = cKDTree(seen_idx).query(missing)
            height[missing[:, 0], missing[:, 1]] = height[seen_idx[nearest, 0], seen_idx[nearest, 1]]
        walls = _ramp(inside_hull, step_m)[..., None]
        solid = np.where(foot[..., None], np.minimum(_ramp(height[..., None] - z[None, None, :], step_m), walls), 0.0)
        how = "height-field"
    solid[..., 0] = np.maximum(solid[..., 0], solid[..., 1])  # the bottom layer under anything standing
    return solid.astype(np.float32), lo, step_m, how


def _ramp(distance_m: np.ndarray, step_m: float) -> np.ndarray:
    """Occupancy of a voxel whose center lies ``distance_m`` inside a surface (negative: outside):
    linear over two voxels around it, 0.5 on it."""
    return np.clip(distance_m / (2 * step_m) + 0.5, 0.0, 1.0)


def _large_parts(idx: np.ndarray, shape: tuple, *, min_voxels: int) -> np.ndarray:
    """The voxels ``idx`` (N, 3) as an occupancy grid, keeping only the 26-connected parts of at
    least ``min_voxels`` voxels."""
    from scipy import ndimage

    grid = np.zeros(shape, bool)
    grid[idx[:, 0], idx[:, 1], idx[:, 2]] = True
    labels, count = ndimage.label(grid, np.ones((3, 3, 3)))
    if not count:
        return grid
    sizes = np.bincount(labels.ravel())
    return (sizes >= min_voxels)[labels] & grid


def mesh_from_solid(
    solid: np.ndarray, lo: np.ndarray, step_m: float, max_triangles: int
) -> tuple[np.ndarray, np.ndarray]:
    """Marching cubes of the closed (morphologically) solid at its 0.5 level, smoothed and
    decimated, checked. ``solid``: occupancy (bool, or float in [0, 1] from ``solid_from_points``);
    voxels that closing adds are full, parts other than the largest empty."""
    from scipy import ndimage
    from skimage.measure import marching_cubes

    field = solid.astype(np.float32)
    inside = field >= 0.5
    closed = ndimage.binary_closing(inside, np.ones((3, 3, 3)), iterations=1, border_value=0) | inside
    closed = ndimage.binary_fill_holes(closed)
    labels, count = ndimage.label(closed)
    if count > 1:  # one object: its largest part
        closed = labels == 1 + int(np.argmax(ndimage.sum(closed, labels, range(1, count + 1))))
    field = np.where(closed & ~inside, 1.0, np.where(~closed & inside, 0.0, field)).astype(np.float32)
    padded = np.pad(field, 1)
    verts, faces, _, _ = marching_cubes(padded, level=0.5, spacing=(step_m,) * 3)
    # padded voxel i has its center at lo + (i - 1 + 0.5) * step; a 0/1 step's 0.5 level is a voxel face
    verts = verts + lo - 0.5 * step_m
    import trimesh

    mesh = trimesh.Trimesh(verts, faces[:, ::-1], process=True)  # outward winding
    trimesh.smoothing.filter_taubin(mesh, iterations=10)
    mesh = decimate(mesh, max_triangles)
    if mesh.volume < 0:
        mesh.invert()
    return np.asarray(mesh.vertices, dtype=float), np.asarray(mesh.faces, dtype=np.int64)


@dataclass
class RestingCloud:
    """What the object's resting frames show: its cleaned world points above the support with
    their sRGB colors, the frames they came from, and its masks (None where barely visible)."""

    points: np.ndarray
    colors: np.ndarray
    frames: list[int]
    masks: list
    often: np.ndarray
    """Per point: seen about as often as the points around it (``seen_voxels``); a footprint is
    drawn around these, not around the depth noise's tail."""
    toward: np.ndarray
    """Per point: the mean unit direction from it to the cameras that saw it (which way a wall faces)."""
    ground: float = 0.0
    """The height of the surface around the object [m] (0 = the world's support plane)."""


def resting_clouds(ctx: StageContext, cameras, depth_of) -> dict[str, RestingCloud]:
    """Every object's points while it rests before the interactor first touches it (all objects
    first: one may stand on another). InputError when an object is never clearly seen."""
    case, cfg, n = ctx.case, ctx.config, ctx.time_info.n_frames
    drifts = not depth_is_sensor(ctx.stage)
    clouds = {}
    for spec in case.config.objects:
        folder = ctx.out_dir / "masks" / spec.name
        if not folder.is_dir():
            raise InputError(f"no masks of object {spec.name!r}", path=folder, hint="run the segment stage")
        masks, per_frame, visible = [], [], np.zeros(n)
        for t in progress(range(n), f"object {spec.name}: masked depth", total=n):
            mask = read_mask(folder / f"{t:06d}.png")
            if mask.shape != (case.height, case.width):
                raise InputError(
                    f"mask is {mask.shape[1]}x{mask.shape[0]}, frames are {case.width}x{case.height}",
                    path=folder / f"{t:06d}.png",
                    hint="re-run the segment stage",
                )
            visible[t] = mask.sum()
            masks.append(mask if visible[t] >= 50 else None)
        if not np.any(visible >= 50):
            raise InputError(
                f"object {spec.name!r} is never visible (every mask is empty)",
                path=folder,
                hint="check its masks (segment stage) or its prompt",
            )
        clear = np.flatnonzero(visible >= 0.5 * np.percentile(visible[visible >= 50], 90))

        def sample(t, masks=masks):
            return None if masks[t] is None else (depth_of(t), masks[t], cameras.K[t], cameras.world_from_cv[t])

        touched = first_contact(masks, ctx.out_dir / "masks" / INTERACTOR, depth_of, n)
        rests = [
            (t, r)
            for t, r in rest_frames(int(clear[0]), n, sample, cfg.rest_tolerance_m, scale_drift=drifts)
            if t < touched
        ]
        if not rests:
            raise InputError(
                f"object {spec.name!r} is never clearly visible",
                path=folder,
                hint="check its masks (segment stage) or its prompt",
            )
        frames = [t for t, _ in rests]
        typical = float(np.median([r for _, r in rests]))
        carve_at = {rests[i][0] for i in np.unique(np.linspace(0, len(rests) - 1, min(16, len(rests))).astype(int))}
        views = []  # the resting views that carve the fused points (their depth read once)
        for t, ratio in rests:  # every frame's depth brought to the rest's typical scale
            depth = depth_of(t) * np.float32(typical / ratio)
            pts, cols = masked_points(depth, masks[t], case.rgb(t), cameras.K[t], cameras.world_from_cv[t])
            toward = (cameras.world_from_cv[t][:3, 3] - pts).astype(np.float32)
            per_frame.append((pts, cols, toward / np.maximum(np.linalg.norm(toward, axis=1, keepdims=True), 1e-9)))
            if t in carve_at:
                views.append((depth, cameras.K[t], cameras.world_from_cv[t]))
        ground = ring_height(ctx, spec.name, [(t, typical / ratio) for t, ratio in rests], masks, depth_of, cameras)
        pts, cols, toward = (np.concatenate(parts) for parts in zip(*per_frame))
        pts, cols, toward, often = clean_cloud(pts, cols, toward, cfg.voxel_m, ground + cfg.support_gap_m)
        keep = free_space_carve(pts, views)
        pts, cols, toward, often = pts[keep], cols[keep], toward[keep], often[keep]
        if len(pts) < 200:
            raise InputError(
                f"object {spec.name!r}: only {len(pts)} points above the support in {len(frames)} resting frames",
                path=folder,
                hint="check its masks and the depth",
            )
        clouds[spec.name] = RestingCloud(pts, cols, frames, masks, often, toward, ground)
    return clouds


def free_space_carve(
    points: np.ndarray, views: list, *, tolerance_m: float = 0.004, fraction: float = 0.3, min_views: int = 2
) -> np.ndarray:
    """Which points no view sees through (a mask): free-space carving.

    A sensor's flying pixels at a silhouette land a few mm off the surface, a few per frame, and
    fused over a rest they make a dense wall that outlier removal keeps (a strip 5-30 mm above a
    box's top edge lifts an object stacked on it that high). A point is dropped when, in
    at least ``min_views`` views and ``fraction`` of the views it falls in, even the nearest depth
    of the 3x3 pixels around it lies beyond it by ``tolerance_m``: that view saw past it. Things
    in front (a hand) only make depth nearer. ``views``: (depth, K, world_from_cv) of frames in
    which the object rests."""
    if not len(points) or not views:
        return np.ones(len(points), bool)
    through, _, observed = view_counts(points, views, tol_m=tolerance_m, window=3)
    return ~((through >= min_views) & (through >= fraction * observed))


def decimate(mesh, max_triangles: int, *, check: bool = True):
    """Quadric decimation of a trimesh to at most ``max_triangles``; with ``check``, the input is
    kept when the decimated mesh would not be a closed, self-intersection-free 2-manifold."""
    import trimesh

    if len(mesh.faces) <= max_triangles:
        return mesh
    # the decimator's default aggression (7) can open a vessel's thin wall (5 mm, 2.5 voxels): then
    # every target fails the check and the mesh keeps all its triangles; at 3 it stays closed
    for target, aggression in itertools.product(
        (max_triangles, int(0.75 * max_triangles), int(0.5 * max_triangles)), (7, 3)
    ):
        simple = mesh.simplify_quadric_decimation(face_count=target, aggression=aggression)
        # the decimator may leave collapsed (two-vertex) triangles: drop them
        simple = trimesh.Trimesh(simple.vertices, simple.faces[simple.nondegenerate_faces()], process=True)
        if not check or not (
            collider_problems(simple.vertices, simple.faces) or self_intersects(simple.vertices, simple.faces)
        ):
            return simple
    return mesh


def run(ctx: StageContext) -> None:
    case = ctx.case
    cfg = ctx.config
    n = ctx.time_info.n_frames
    cameras = read_camera(ctx.stage, paths.CAMERA, n)
    depth_of = metric_depth_reader(ctx.stage, case, cache=8)
    models, facts = [], {}
    clouds = resting_clouds(ctx, cameras, depth_of)
    for spec in case.config.objects:
        cloud = clouds[spec.name]
        pts, cols, frames = cloud.points, cloud.colors, cloud.frames
        support = support_height(
            pts, [c.points for name, c in clouds.items() if name != spec.name], ground=cloud.ground
        )
        vertices, faces, how, above = complete(pts, cloud.toward, cloud.often, support, cfg)
        pts, cols = pts[above], cols[above]
        problems = collider_problems(vertices, faces)
        if problems or self_intersects(vertices, faces):
            raise MeshError(
                f"object {spec.name!r}: the mesh is {', '.join(problems) or 'self-intersecting'}",
                hint="try a larger object.voxel_m",
            )
        # the object frame: world axes at frame 0, origin on its support under its footprint center
        foot = vertices[vertices[:, 2] < support + 0.5 * cfg.voxel_m]
        origin = np.array([*(foot[:, :2].mean(axis=0) if len(foot) else vertices[:, :2].mean(axis=0)), support])
        local = vertices - origin
        colors = transfer_colors(vertices, pts, srgb8_to_linear(cols))
        mesh = MeshData(vertices=local, faces=faces, vertex_colors=colors)
        physics, mass = physics_for(spec, local, faces, ctx, wall_modeled=how.startswith("vessel"))
        models.append(ObjectModel(spec.name, mesh, se3.make_pose(np.eye(3), origin), mass, physics))
        facts[spec.name] = {
            "rest_frames": [frames[0], frames[-1]],
            "fused_points": int(len(pts)),
            "support_height_m": round(float(support), 4),
            "completion": how,
            "triangles": int(len(faces)),
        }
    for name, authored in author_objects(
        ctx, models, cfg.convex_tolerance
    ).items():  # everything built and checked: now author
        facts[name] |= authored
    ctx.record(objects=facts)


def complete(
    points: np.ndarray, toward: np.ndarray, often: np.ndarray, support: float, cfg
) -> tuple[np.ndarray, np.ndarray, str, np.ndarray]:
    """Steps 3 and 4 for one object's cleaned world points standing on ``support``: its closed
    surface (vertices in the world, faces), how it was completed, and which points were used
    (those above the support by ``cfg.support_gap_m``)."""
    above = points[:, 2] > support + cfg.support_gap_m
    lift = np.array([0.0, 0.0, support])
    solid, lo, step, how = solid_from_points(
        points[above] - lift,
        step_m=cfg.voxel_m,
        band_m=4 * cfg.voxel_m,
        tolerance=cfg.revolution_tolerance,
        outline=often[above],
        toward=toward[above],
    )
    vertices, faces = mesh_from_solid(solid, lo, step, cfg.max_triangles)
    return vertices + lift, faces, how, above


def support_height(
    points: np.ndarray, others: list[np.ndarray], *, ground: float = 0.0, margin_m: float = 0.01
) -> float:
    """What the object stands on: the top of another object under its footprint (a stack), else
    the surface around it (``ground``). Another object's points count when they lie under the
    object's footprint (grown by ``margin_m``) and no higher than its lowest seen point plus ``margin_m``."""
    lowest = float(points[:, 2].min())
    lo, hi = points[:, :2].min(axis=0) - margin_m, points[:, :2].max(axis=0) + margin_m
    best = ground
    for other in others:
        under = other[np.all((other[:, :2] >= lo) & (other[:, :2] <= hi), axis=1) & (other[:, 2] <= lowest + margin_m)]
        if len(under) >= 30:
            best = max(best, float(np.percentile(under[:, 2], 95)))
    return min(best, lowest)


def seen_voxels(
    points: np.ndarray, values: np.ndarray, voxel_m: float, *, keep_fraction: float = 0.1, reach: int = 2
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The points fused over many frames, one per ``voxel_m`` voxel (the mean of its points and of
    their ``values`` (N, k): colors, directions to the camera), and which of them are seen often:
    at least ``keep_fraction`` as often as the most seen voxel within ``reach`` voxels of them.
    Returns (points, mean values (float), often).

    A surface seen in many frames fills its voxels many times over; the depth noise's tail and the
    registration's jitter put a few points per frame a few millimeters off it. A plain voxel
    downsample gives both one point each, so the fused wall becomes a slab as thick as the noise's
    extremes, and a footprint drawn around it lies on its outside: an object comes out a few
    millimeters too wide on the sides the camera saw. A voxel of the tail is
    seen a fraction as often as its neighbors, so a height field's footprint is drawn around the
    often seen voxels only (``outline`` of ``solid_from_points``). Where every voxel around is seen
    at most 3 times (one frame's pixels), all count as often seen.

    ``keep_fraction`` 0.1, not more: a top face's far edge is seen less often than its middle
    (voxels partly covered, the sensor's dropouts at depth edges), and a higher fraction (0.35)
    pulls the sides seen only as such edges a few millimeters in. The rarely seen points stay in
    the cloud: dropping them makes a revolved profile worse."""
    # voxels as one integer each, on a grid padded by ``reach`` so a neighbor is an offset away
    key = np.floor(points / voxel_m).astype(np.int64)
    lo = key.min(axis=0) - reach
    dims = key.max(axis=0) + reach - lo + 1
    ids, owner, count = np.unique(
        ((key[:, 0] - lo[0]) * dims[1] + (key[:, 1] - lo[1])) * dims[2] + (key[:, 2] - lo[2]),
        return_inverse=True,
        return_counts=True,
    )
    owner = owner.ravel()
    mean = (
        np.column_stack([np.bincount(owner, weights=points[:, a], minlength=len(ids)) for a in range(3)])
        / count[:, None]
    )
    values = np.asarray(values, dtype=float).reshape(len(points), -1)
    value = (
        np.column_stack([np.bincount(owner, weights=values[:, a], minlength=len(ids)) for a in range(values.shape[1])])
        / count[:, None]
    )
    # the most seen voxel around each: every offset looked up in the (sorted) voxel ids
    most = count.copy()
    steps = range(-reach, reach + 1)
    for dx, dy, dz in itertools.product(steps, steps, steps):
        other = ids + (dx * dims[1] + dy) * dims[2] + dz
        j = np.minimum(np.searchsorted(ids, other), len(ids) - 1)
        hit = ids[j] == other
        most[hit] = np.maximum(most[hit], count[j[hit]])
    often = (count >= keep_fraction * most) | (most <= 3)  # up to 3 (one frame's pixels): nothing to compare
    return mean, value, often


def clean_cloud(
    points: np.ndarray, colors: np.ndarray, toward: np.ndarray, voxel_m: float, above_m: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Points higher than ``above_m`` (the table is left out), one per voxel (``seen_voxels``),
    outliers and stray clusters dropped. ``toward``: each point's unit direction to its camera.
    Returns (points, sRGB8 colors, mean unit directions to the cameras, often seen)."""
    import open3d as o3d

    def inliers(pts: np.ndarray) -> np.ndarray:  # Open3D's statistical outlier test, as indices
        _, kept = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts)).remove_statistical_outlier(
            nb_neighbors=16, std_ratio=2.0
        )
        return np.asarray(kept, dtype=np.int64)

    keep = points[:, 2] > above_m
    pts, values, often = seen_voxels(points[keep], np.column_stack([colors[keep], toward[keep]]), voxel_m)
    cols = np.clip(values[:, :3] + 0.5, 0, 255).astype(np.uint8)
    toward = values[:, 3:] / np.maximum(np.linalg.norm(values[:, 3:], axis=1, keepdims=True), 1e-12)
    kept = inliers(pts)
    if len(kept) > 50:  # keep the largest cluster (stray mask pixels on the background)
        labels = np.asarray(
            o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts[kept])).cluster_dbscan(eps=3 * voxel_m, min_points=4)
        )
        if labels.max() >= 0:
            kept = kept[labels == np.bincount(labels[labels >= 0]).argmax()]
    pts, cols, toward, often = pts[kept], cols[kept], toward[kept], often[kept]
    # an often seen voxel alone among the rarely seen ones (a flying pixels' strip, seen by few
    # frames but each time) is an outlier of the often seen
    marked = np.flatnonzero(often)
    if len(marked) > 50:
        often[:] = False
        often[marked[inliers(pts[marked])]] = True
    return pts, cols, toward, often


def physics_for(spec, vertices: np.ndarray, faces: np.ndarray, ctx: StageContext, *, wall_modeled: bool = False):
    """Density, friction, restitution from the category prior with rose.toml's overrides; mass
    properties of the solid (or of its wall, for hollow categories, unless ``wall_modeled``: the
    mesh is a vessel's wall already)."""
    prior, warning = lookup(spec.category)
    if warning:
        ctx.warn(f"object {spec.name!r}: {warning}")
    o = spec.overrides
    hollow = bool(o.get("hollow", prior.hollow)) and not wall_modeled
    density = float(o.get("density_kg_m3", prior.density_kg_m3))
    thickness = prior.shell_thickness_m if prior.shell_thickness_m > 0 else 0.003
    props = (
        shell_mass_properties(vertices, faces, density, thickness)
        if hollow
        else mass_properties(vertices, faces, density)
    )
    source = "table"
    mass_sigma = prior.density_sigma_kg_m3 * props.volume_m3
    if "mass_kg" in o:  # the user's mass wins: rescale (the mass distribution keeps its shape)
        k = float(o["mass_kg"]) / props.mass_kg
        props = type(props)(
            props.mass_kg * k,
            props.volume_m3,
            props.center_of_mass_m,
            props.inertia_com * k,
            props.diagonal_inertia * k,
            props.principal_axes,
        )
        density, mass_sigma, source = density * k, 0.0, "user"
    elif "density_kg_m3" in o:
        mass_sigma, source = 0.0, "user"
    physics = PhysicsValues(
        prior=prior,
        source=source,
        density_kg_m3=density,
        friction=float(o.get("friction", prior.friction)),
        restitution=float(o.get("restitution", prior.restitution)),
        mass_sigma_kg=float(mass_sigma),
        friction_sigma=0.0 if "friction" in o else prior.friction_sigma,
        restitution_sigma=0.0 if "restitution" in o else prior.restitution_sigma,
    )
    return physics, props
