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
   several millimeters. A height field is then carved where the resting views saw past it
   (``carve_solid``): its walls are a guess, the other completions are fitted to what was seen.
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

import warnings
from dataclasses import replace

import cv2
import numpy as np
import trimesh
from scipy.spatial import ConvexHull, cKDTree

from rose_usd.core import se3
from rose_usd.core.color import srgb8_to_linear
from rose_usd.core.watertight import collider_problems
from rose_usd.errors import MeshError
from rose_usd.geometry.mesh import decimate, self_intersects
from rose_usd.geometry.texture import transfer_colors
from rose_usd.layers.world import metric_depth_reader, read_cameras
from rose_usd.object.author import ObjectModel, author_objects, physics_for
from rose_usd.object.rest import free_space_carve, level_rotation, resting_clouds, support_height
from rose_usd.stage_api import StageContext
from rose_usd.usd.geom import MeshData

CARVE_TOLERANCE_M = 0.003
"""A completed voxel is carved where a resting view's depth, at the voxel's pixel, lies this far
beyond it. Voxels behind the seen surface are never carved (the depth there is nearer), so the
sensor's noise at the surface only decides about the voxels right at it."""


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

    top = float(points[:, 2].max())
    rev = revolution_profile(points, band_m, tolerance, toward=toward)
    xy_lo, xy_hi = points[:, :2].min(axis=0), points[:, :2].max(axis=0)
    if rev is not None:  # the far side, never seen, is revolved too: the grid holds the whole solid
        xy_lo = np.minimum(xy_lo, rev[0] - rev[2].max())
        xy_hi = np.maximum(xy_hi, rev[0] + rev[2].max())
    lo = np.array([*(xy_lo - 3 * step_m), 0.0])
    hi = np.array([*(xy_hi + 3 * step_m), top + step_m])
    shape = tuple(np.ceil((hi - lo) / step_m).astype(int))
    centers = [lo[a] + (np.arange(shape[a]) + 0.5) * step_m for a in range(3)]
    x, y = np.meshgrid(centers[0], centers[1], indexing="ij")
    z = centers[2]
    idx = np.clip(np.floor((points - lo) / step_m).astype(int), 0, np.array(shape) - 1)
    grid = (x, y, z)
    if rev is not None:
        solid, how = _revolved_solid(points, toward, rev, idx, shape, grid, top, step_m, band_m)
    else:
        solid, how = _height_field_solid(points, outline, idx, shape, lo, grid, step_m)
    solid[..., 0] = np.maximum(solid[..., 0], solid[..., 1])  # the bottom layer under anything standing
    return solid.astype(np.float32), lo, step_m, how


def _revolved_solid(points, toward, rev, idx, shape, grid, top, step_m: float, band_m: float):
    """A solid of revolution's occupancy (and, where its inner wall shows over the rim, an open
    vessel's), plus seen points well outside it (a mug's handle). Returns (occupancy, how)."""
    x, y, z = grid
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
    return solid, how


def _height_field_solid(points, outline, idx, shape, lo, grid, step_m: float):
    """A height field standing on the support: under every seen point the object is solid down to
    the table; the footprint is the seen one, closed and made convex-hull-tight. Returns
    (occupancy, how)."""
    from scipy import ndimage

    x, y, z = grid
    # a cell's height is its points' upper median: the highest is biased up by the noise
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
    return solid, how


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


def carve_solid(solid: np.ndarray, lo_world: np.ndarray, step_m: float, views) -> np.ndarray:
    """``solid`` emptied where the resting views saw past it (``rest.free_space_carve`` on its
    voxels' centers, each view's own pixel; ``lo_world``: voxel 0's corner in the world). A
    completion guesses what was never seen: a height field's walls stand straight down from the
    edge a camera sees, and under a lying can's near side that camera sees the table where they
    stand. Voxels the views never see past (behind the seen surface) keep what the completion
    made of them."""
    filled = np.argwhere(solid > 0)
    if not len(views) or not len(filled):
        return solid
    centers = lo_world + (filled + 0.5) * step_m
    free = ~free_space_carve(centers, views, tolerance_m=CARVE_TOLERANCE_M, window=1)
    carved = solid.copy()
    carved[tuple(filled[free].T)] = 0.0
    # a bottom voxel lies within the tolerance of the table behind it: it goes with the one above
    carved[..., 0] = np.where(carved[..., 1] < solid[..., 1], carved[..., 1], carved[..., 0])
    return carved


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


def run(ctx: StageContext) -> None:
    case = ctx.case
    cfg = ctx.config
    n = ctx.time_info.n_frames
    cameras = read_cameras(ctx.stage, n)
    depth_of = metric_depth_reader(ctx.stage, case, cache=8)
    models, facts = [], {}
    clouds = resting_clouds(ctx, cameras, depth_of)
    for spec in case.config.objects:
        cloud = clouds[spec.name]
        pts, cols, frames = cloud.points, cloud.colors, cloud.frames
        support = support_height(
            pts, [c.points for name, c in clouds.items() if name != spec.name], ground=cloud.ground
        )
        vertices, faces, how, above = _closed_surface(ctx, spec.name, pts, cloud, support, cfg)
        pts, cols = pts[above], cols[above]
        # the object frame: world axes at frame 0, origin on its support under its footprint center
        foot = vertices[vertices[:, 2] < support + 0.5 * cfg.voxel_m]
        origin = np.array([*(foot[:, :2].mean(axis=0) if len(foot) else vertices[:, :2].mean(axis=0)), support])
        colors = transfer_colors(vertices, pts, srgb8_to_linear(cols))
        # a fused round object (a ball) has no flat bottom: turned by up to 6 deg onto the hull
        # face nearest its center of mass it rests; as seen it rolled off its flat pad in Newton
        level = level_rotation(vertices, faces)
        com = trimesh.Trimesh(vertices, faces, process=False).center_mass
        vertices = (vertices - com) @ level.T + com
        local = vertices - origin
        mesh = MeshData(vertices=local, faces=faces, vertex_colors=colors)
        physics, mass = physics_for(spec, local, faces, ctx, wall_modeled=how.startswith("vessel"))
        models.append(ObjectModel(spec.name, mesh, se3.make_pose(np.eye(3), origin), mass, physics))
        facts[spec.name] = {
            "rest_frames": [frames[0], frames[-1]],
            "fused_points": int(len(pts)),
            "support_height_m": round(float(support), 4),
            "completion": how,
            "levelled_deg": round(float(se3.rotation_angle_deg(level)), 2),
            "triangles": int(len(faces)),
        }
    for name, authored in author_objects(
        ctx, models, cfg.convex_tolerance
    ).items():  # everything built and checked: now author
        facts[name] |= authored
    ctx.record(objects=facts)


def _closed_surface(ctx: StageContext, name: str, pts: np.ndarray, cloud, support: float, cfg):
    """``complete`` at ``cfg.voxel_m``, else at 1.5x and 2x it with a warning: marching cubes
    over a real sensor's sparse, noisy cloud can leave a non-manifold edge at 2 mm that a coarser
    grid does not (cups-rgbd's ball: not watertight at 2 mm, closed at 3 and 4 mm)."""
    problems: list[str] = []
    first: list[str] = []
    for factor in (1.0, 1.5, 2.0):
        step = replace(cfg, voxel_m=cfg.voxel_m * factor)
        vertices, faces, how, above = complete(pts, cloud.toward, cloud.often, support, step, views=cloud.views)
        problems = _mesh_problems(vertices, faces)
        if not problems:
            if factor > 1.0:
                ctx.warn(
                    f"object {name!r}: the mesh closed only on a {1000 * step.voxel_m:g} mm grid "
                    f"({1000 * cfg.voxel_m:g} mm left it {', '.join(first)})"
                )
            return vertices, faces, how, above
        first = first or problems
    raise MeshError(
        f"object {name!r}: the mesh is {', '.join(problems)} at {1000 * cfg.voxel_m:g}-{2000 * cfg.voxel_m:g} mm",
        hint="try a larger object.voxel_m",
    )


def _mesh_problems(vertices: np.ndarray, faces: np.ndarray) -> list[str]:
    """What keeps a closed mesh from being a collider; CGAL's self-intersection test last (it
    cannot read a mesh whose surfaces touch at a single vertex, which no edge test sees)."""
    problems = collider_problems(vertices, faces)
    if problems:
        return problems
    try:
        return ["self-intersecting"] if self_intersects(vertices, faces) else []
    except MeshError:
        return ["pinched at a vertex"]


def complete(
    points: np.ndarray, toward: np.ndarray, often: np.ndarray, support: float, cfg, *, views=()
) -> tuple[np.ndarray, np.ndarray, str, np.ndarray]:
    """Steps 3 and 4 for one object's cleaned world points standing on ``support``: its closed
    surface (vertices in the world, faces), how it was completed, and which points were used
    (those above the support by ``cfg.support_gap_m``). ``views`` (depth, K, world_from_cv) of
    resting frames carve a height field (``carve_solid``)."""
    above = points[:, 2] > support + cfg.support_gap_m
    lift = np.array([0.0, 0.0, support])
    solid, lo, step, how = solid_from_points(
        points[above] - lift,
        step_m=cfg.voxel_m,
        band_m=4 * cfg.voxel_m,
        tolerance=cfg.fusion.revolution_tolerance,
        outline=often[above],
        toward=toward[above],
    )
    if how == "height-field":  # a revolved solid and a vessel are fitted to what was seen
        solid = carve_solid(solid, lo + lift, step, views)
    vertices, faces = mesh_from_solid(solid, lo, step, cfg.max_triangles)
    return vertices + lift, faces, how, above
