"""Gravity and the world frame.

Sources of the up direction, in the tracking frame (the first camera's):

- ``plane``: the dominant horizontal support plane of the fused points. Hand-held cameras are held
  roughly upright, so the cameras' mean image-up direction is a prior that picks the horizontal
  planes among all planes; the up vector is then the common normal of the horizontal planes
  found (table and floor are parallel), fitted by least squares on their inliers.
- ``geocalib``: GeoCalib's up vector of one frame (OpenCV camera axes), rotated into the tracking frame.
- ``imu``: per-frame gravity vectors in camera axes (``imu/gravity.txt``), averaged in the tracking frame.

The world frame (architecture.md section 2): +Z up, origin on the support surface under the
object at frame 0, +X the first camera's image-right direction made horizontal.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rose_usd.core import se3
from rose_usd.errors import InputError


@dataclass(frozen=True)
class Plane:
    normal: np.ndarray
    """Unit normal, oriented up (toward the cameras' up prior)."""
    offset: float
    """Plane: normal . x = offset."""
    inliers: int
    angle_to_prior_deg: float

    def project(self, point: np.ndarray) -> np.ndarray:
        return point - (self.normal @ point - self.offset) * self.normal


@dataclass(frozen=True)
class GravityEstimate:
    up: np.ndarray
    """Unit up vector in the tracking frame."""
    source: str
    support: Plane | None
    """The support plane (plane method), or None."""
    planes: list[Plane]
    uncertainty_deg: float


def camera_up_prior(world_from_camera: np.ndarray) -> np.ndarray:
    """Mean image-up direction (-y of OpenCV cameras) in the tracking frame."""
    up = -world_from_camera[:, :3, 1].mean(axis=0)
    return up / np.linalg.norm(up)


def fit_planes(
    points: np.ndarray,
    viewpoint: np.ndarray,
    *,
    max_planes: int = 6,
    distance_m: float = 0.01,
    min_points: int = 500,
    connected_m: float | None = None,
    seed: int = 0,
) -> list[Plane]:
    """Planes found by repeated RANSAC (``ransac_plane``), normals oriented toward ``viewpoint``
    (the cameras see every surface from its front, so a support plane's normal points up).

    Each RANSAC plane is refitted: inliers are reselected around the current fit with a band of
    three robust sigmas (a band around RANSAC's 3-point hypothesis would lean the refit toward
    it), and weighted by the depth noise at their distance from the cameras (axial noise grows
    with the square of depth).

    With ``connected_m``, a plane is only its largest patch of inliers connected in steps of at
    most that length (see ``largest_patch``); the other patches stay for later planes. Sparse
    points need it: in 7-Scenes' kitchen, COLMAP's points on a far counter and on a near table
    15 cm lower, with the bare cupboard fronts between them, made one RANSAC plane tilted 10 deg."""
    rng = np.random.default_rng(seed)
    all_pts = np.asarray(points, dtype=float)
    planes = []
    for _ in range(max_planes):
        if len(all_pts) < min_points:
            break
        normal, offset, count = ransac_plane(all_pts, distance_m, rng)
        if count < min_points:
            break
        region = np.ones(len(all_pts), dtype=bool)
        if connected_m is not None:
            region = largest_patch(all_pts, normal, offset, distance_m, connected_m)
            if region.sum() < min_points:
                # too small alone: leave RANSAC's inliers out of the next search, plane or not
                all_pts = all_pts[np.abs(all_pts @ normal - offset) >= distance_m]
                continue
        weights_all = 1.0 / (0.001 + 0.002 * (np.linalg.norm(all_pts - viewpoint, axis=1) - 0.4) ** 2) ** 2
        band = distance_m
        for _ in range(4):
            residual = all_pts @ normal - offset
            keep = (np.abs(residual) < band) & region
            pts, w = all_pts[keep], weights_all[keep]
            centroid = (w[:, None] * pts).sum(axis=0) / w.sum()
            centered = (pts - centroid) * np.sqrt(w)[:, None]
            normal = np.linalg.svd(centered, full_matrices=False)[2][2]
            offset = float(normal @ centroid)
            r = pts @ normal - offset
            band = float(np.clip(3.0 * 1.4826 * np.median(np.abs(r)), 0.003, distance_m))
        if normal @ (viewpoint - centroid) < 0:
            normal, offset = -normal, -offset
        planes.append(Plane(normal, offset, int(keep.sum()), 0.0))
        all_pts = all_pts[~keep]
    return planes


def largest_patch(
    points: np.ndarray, normal: np.ndarray, offset: float, distance_m: float, step_m: float
) -> np.ndarray:
    """Which ``points`` lie near the largest connected patch of the plane's inliers (within
    ``distance_m`` of it): the inliers binned on the plane in cells of ``step_m``, cells joined to
    their 8 neighbours; the patch's cells and their neighbours, as a mask over all points."""
    from scipy import ndimage

    inlier = np.abs(points @ normal - offset) < distance_m
    e1 = np.cross(normal, [1.0, 0.0, 0.0] if abs(normal[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    uv = np.stack([points @ e1, points @ np.cross(normal, e1)], axis=1)
    lo = uv[inlier].min(axis=0)
    cell = np.floor((uv - lo) / step_m).astype(np.int64)
    size = cell[inlier].max(axis=0) + 1
    if size.prod() > 4_000_000:  # a few far outliers: coarser cells rather than a huge grid
        step_m *= float(np.sqrt(size.prod() / 4_000_000))
        cell = np.floor((uv - lo) / step_m).astype(np.int64)
        size = cell[inlier].max(axis=0) + 1
    counts = np.zeros(size, dtype=np.int64)
    np.add.at(counts, tuple(cell[inlier].T), 1)
    labels, n = ndimage.label(counts > 0, structure=np.ones((3, 3)))
    if n <= 1:
        return np.ones(len(points), dtype=bool)
    sizes = ndimage.sum_labels(counts, labels, index=np.arange(1, n + 1))
    patch = ndimage.binary_dilation(labels == 1 + int(np.argmax(sizes)), structure=np.ones((3, 3)))
    inside = np.all((cell >= 0) & (cell < size), axis=1)
    region = np.zeros(len(points), dtype=bool)
    region[inside] = patch[tuple(cell[inside].T)]
    return region


RANSAC_ITERATIONS = 3000
"""Random triples per plane. With 1000 the 7-Scenes gravity test (<= 2 deg) passed for two seeds
of three (2.23 deg for seed 0); with 3000 for all three."""


def ransac_plane(
    points: np.ndarray,
    distance_m: float,
    rng: np.random.Generator,
    *,
    iterations: int = RANSAC_ITERATIONS,
    batch: int = 50,
) -> tuple[np.ndarray, float, int]:
    """The plane (unit normal, offset: normal . x = offset) through 3 of ``points`` that has the
    most points within ``distance_m``, among ``iterations`` random triples; and that count. NumPy
    on one thread, so the same points and generator give the same plane on every run (Open3D's
    ``segment_plane`` counted in parallel and its planes moved from run to run)."""
    pts = np.asarray(points, dtype=np.float64)
    pts32 = pts.astype(np.float32)
    triples = rng.integers(0, len(pts), size=(iterations, 3))
    a, b, c = pts[triples[:, 0]], pts[triples[:, 1]], pts[triples[:, 2]]
    normals = np.cross(b - a, c - a)
    norms = np.linalg.norm(normals, axis=1)
    ok = norms > 1e-12
    normals[ok] /= norms[ok, None]
    offsets = np.einsum("ij,ij->i", normals, a)
    best, best_count = 0, -1
    for start in range(0, iterations, batch):
        n = normals[start : start + batch].astype(np.float32)
        d = offsets[start : start + batch].astype(np.float32)
        counts = (np.abs(pts32 @ n.T - d) < distance_m).sum(axis=0)
        counts[~ok[start : start + batch]] = -1
        i = int(np.argmax(counts))
        if counts[i] > best_count:
            best, best_count = start + i, int(counts[i])
    return normals[best], float(offsets[best]), best_count


def plane_under(planes: list[Plane], anchor: np.ndarray | None, biggest: int, min_height_m: float) -> Plane | None:
    """The plane just below ``anchor`` (between ``min_height_m`` and 35 cm under it) among planes
    of at least 5 % of the biggest plane's support, or None. (A floor seen for the whole video
    can hold 5x the points of the table the object stands on: the table must still win.)"""
    if anchor is None:
        return None
    below = [p for p in planes if min_height_m <= p.normal @ anchor - p.offset <= 0.35 and p.inliers >= 0.05 * biggest]
    return min(below, key=lambda p: p.normal @ anchor - p.offset) if below else None


def gravity_from_planes(
    points: np.ndarray,
    world_from_camera: np.ndarray,
    *,
    anchor: np.ndarray | None = None,
    anchor_min_height_m: float = 0.005,
    max_roll_deg: float = 25.0,
    max_pitch_deg: float = 80.0,
    upside_down_check: bool = False,
    upside_down_margin: float = 2.0,
    upside_down_support: float = 0.3,
    min_points: int = 500,
    distance_m: float = 0.01,
    connected_m: float | None = None,
) -> GravityEstimate:
    """Up from the horizontal planes of ``points`` (tracking frame).

    A hand-held camera filming a tabletop is rolled little and pitched down by up to ~70 deg, so
    a horizontal plane's normal is nearly perpendicular to the cameras' mean image-right axis and
    within ``max_pitch_deg`` of their image-up. Candidates passing that test are grouped by
    direction (table and floor are parallel; a wall facing the camera, a box side or the object's
    face are not). The group that holds a sizable plane just below ``anchor`` (a point on the
    prompted object, at least ``anchor_min_height_m`` above its support; or where the first view
    looks, which may lie on the support itself) wins, else the group with the most support,
    weighted toward image-up. Up is the group's inlier-weighted normal; the support plane is its
    plane under the anchor (or its largest).

    A camera mounted upside down (rolled 180 deg, as on some rigs) sees the table's normal along
    its image-down, so the candidates are also chosen with the prior reversed. With
    ``upside_down_check`` (the anchor is on a prompted object) the camera is taken to be upside
    down when that finds a plane under the anchor more than 1 cm nearer to it, holding at least
    ``upside_down_support`` times the points of the upright choice's plane under it (or the
    upright choice finds none): the object stands on the plane right under it, a far wall that
    passes the upright test lies farther below. (A small board standing behind a stack of two cans
    faces an upright camera as a table faces one upside down, nearer to the top can than its
    table: 1,578 points against the table's 14,432 on a synthetic clip, where it tipped the world
    by 66 deg.) (Where a view merely centers, on a cupboard's front say,
    nothing stands on it.) Without it, when the reversed choice's group has ``upside_down_margin``
    times the weighted support of the upright one: on an upside-down clip with no prompt the
    table held 2.8 times the support of a plane facing the image-up (and was not chosen).
    """
    prior = camera_up_prior(world_from_camera)
    right = world_from_camera[:, :3, 0].mean(axis=0)
    right /= np.linalg.norm(right)
    view = world_from_camera[:, :3, 3].mean(axis=0)
    planes = fit_planes(points, view, min_points=min_points, distance_m=distance_m, connected_m=connected_m)
    choice = _horizontal_group(planes, prior, right, anchor, anchor_min_height_m, max_roll_deg, max_pitch_deg)
    flipped = _horizontal_group(planes, -prior, right, anchor, anchor_min_height_m, max_roll_deg, max_pitch_deg)
    if anchor is not None and upside_down_check:
        if flipped is not None and flipped[1] is not None:
            if (
                choice is None
                or choice[1] is None
                or (
                    _height(flipped[1], anchor) < _height(choice[1], anchor) - 0.01
                    and flipped[1].inliers >= upside_down_support * choice[1].inliers
                )
            ):
                choice = flipped
    elif flipped is not None and (choice is None or _score(flipped[0]) > upside_down_margin * _score(choice[0])):
        # no object to stand on the support: a camera upside down sees its table's plane along
        # its image-down, holding many times the points of what faces its image-up
        choice = flipped
    if choice is None:
        raise InputError(
            f"no horizontal support plane among {len(planes)} planes found in the depth",
            hint="film the surface the object rests on, or give gravity (perception/geocalib.json or imu/gravity.txt)",
        )
    group, under, rated = choice
    weights = np.array([p.inliers for p in group], dtype=float)
    up = (weights[:, None] * np.array([p.normal for p in group])).sum(axis=0)
    up /= np.linalg.norm(up)
    main = under or group[0]
    support = Plane(up, float(up @ (main.offset * main.normal)), main.inliers, main.angle_to_prior_deg)
    sigma = float(np.degrees(0.01 / np.sqrt(max(main.inliers, 1)) / 0.1))  # ~1 cm noise over ~10 cm of lever
    return GravityEstimate(up, "plane", support, rated, max(sigma, disagreement_deg(up, rated), PLANE_MIN_SIGMA_DEG))


PLANE_MIN_SIGMA_DEG = 1.0
"""The least uncertainty of gravity from a support plane [deg]: a plane's least squares over
thousands of points claims hundredths of a degree, but depth calibration, the table's own
flatness and (structure from motion) the map's rotations and self-calibrated focal length are off
by more: the benchmark's realistic rgbd cases came out 0.17-0.33 deg off against 0.06-0.20
claimed, its rgb cases 0.5 and 1.2 deg against 0.23."""


def disagreement_deg(up: np.ndarray, planes: list[Plane], within_deg: float = 20.0) -> float:
    """The inlier-weighted RMS angle between ``up`` and the planes' normals within ``within_deg`` of
    it: how far the near-horizontal planes scatter around the up chosen. Parallel table and floor
    give about 0; a sparse map's noisy patches several degrees (7-Scenes' kitchen through COLMAP:
    2-10 deg apart), which the least-squares sigma of one plane does not show."""
    angles = np.degrees(np.arccos(np.clip([p.normal @ up for p in planes], -1.0, 1.0)))
    near = angles < within_deg
    if not near.any():
        return 0.0
    weights = np.array([p.inliers for p in planes], dtype=float)[near]
    return float(np.sqrt((weights * angles[near] ** 2).sum() / weights.sum()))


def _height(plane: Plane, point: np.ndarray) -> float:
    return float(plane.normal @ point - plane.offset)


def _horizontal_group(planes, prior, right, anchor, anchor_min_height_m, max_roll_deg, max_pitch_deg):
    """(group, its plane under the anchor or None, planes rated against ``prior``) of the winning
    group of parallel candidate planes (see gravity_from_planes), None without candidates."""
    rated = [
        Plane(p.normal, p.offset, p.inliers, float(np.degrees(np.arccos(np.clip(p.normal @ prior, -1, 1)))))
        for p in planes
    ]
    candidates = [
        p
        for p in rated
        if abs(p.normal @ right) < np.sin(np.radians(max_roll_deg)) and p.angle_to_prior_deg < max_pitch_deg
    ]
    if not candidates:
        return None
    groups: list[list[Plane]] = []
    for p in sorted(candidates, key=lambda p: -p.inliers):
        for group in groups:
            if np.degrees(np.arccos(np.clip(p.normal @ group[0].normal, -1, 1))) < 5.0:
                group.append(p)
                break
        else:
            groups.append([p])
    biggest = max(p.inliers for p in candidates)
    under = {id(g): plane_under(g, anchor, biggest, anchor_min_height_m) for g in groups}
    with_object = [g for g in groups if under[id(g)] is not None]
    group = max(with_object or groups, key=_score)
    return group, under[id(group)], rated


def _score(group: list[Plane]) -> float:
    """A group of parallel planes' support, weighted toward the prior (its first plane's angle to it)."""
    return sum(p.inliers for p in group) * max(float(np.cos(np.radians(group[0].angle_to_prior_deg))), 0.0) ** 2


def refine_with_planes(
    prior: GravityEstimate,
    points: np.ndarray,
    world_from_camera: np.ndarray,
    *,
    anchor: np.ndarray | None,
    floor_deg: float,
    anchor_min_height_m: float = 0.005,
) -> GravityEstimate:
    """Fuse an up estimate (GeoCalib, IMU) with the normal of the support planes that agree with
    it, by inverse-variance weights. The plane's sigma is that of a least-squares normal from its
    inliers, but never below ``floor_deg`` (depth errors are correlated over the image). Returns
    the prior unchanged when no plane agrees within 3 sigma (or 5 deg)."""
    planes = fit_planes(points, world_from_camera[:, :3, 3].mean(axis=0))
    tol = max(3.0 * prior.uncertainty_deg, 5.0)
    agree = [p for p in planes if np.degrees(np.arccos(np.clip(p.normal @ prior.up, -1, 1))) < tol]
    if not agree:
        return prior
    main = plane_under(agree, anchor, max(p.inliers for p in planes), anchor_min_height_m) or max(
        agree, key=lambda p: p.inliers
    )
    parallel = [p for p in agree if np.degrees(np.arccos(np.clip(p.normal @ main.normal, -1, 1))) < 3.0]
    weights = np.array([p.inliers for p in parallel], dtype=float)
    plane_up = (weights[:, None] * np.array([p.normal for p in parallel])).sum(axis=0)
    plane_up /= np.linalg.norm(plane_up)
    sigma_plane = max(float(np.degrees(0.005 / (0.2 * np.sqrt(max(main.inliers, 1))))), floor_deg)
    w_prior, w_plane = 1.0 / max(prior.uncertainty_deg, 1e-3) ** 2, 1.0 / sigma_plane**2
    up = w_prior * prior.up + w_plane * plane_up
    up /= np.linalg.norm(up)
    support = Plane(up, float(up @ (main.offset * main.normal)), main.inliers, 0.0)
    return GravityEstimate(up, f"{prior.source}+plane", support, planes, float(1.0 / np.sqrt(w_prior + w_plane)))


def gravity_from_geocalib(path: Path, world_from_camera: np.ndarray) -> GravityEstimate:
    from rose_usd.io.geocalib import read_geocalib

    calib = read_geocalib(path)
    if not 0 <= calib.frame < len(world_from_camera):
        raise InputError(
            f"geocalib.json is for frame {calib.frame}, the video has frames 0..{len(world_from_camera) - 1}",
            path=path,
            hint="calibrate a frame of this video",
        )
    up = world_from_camera[calib.frame, :3, :3] @ calib.up_cam
    sigma = np.degrees(max(calib.roll_uncertainty or 0.0, calib.pitch_uncertainty or 0.0)) or 1.0
    return GravityEstimate(up / np.linalg.norm(up), "geocalib", None, [], float(sigma))


def gravity_from_imu(path: Path, world_from_camera: np.ndarray) -> GravityEstimate:
    """``imu/gravity.txt``: one gravity (down) vector per frame in OpenCV camera axes, or one line for all."""
    try:
        g = np.atleast_2d(np.loadtxt(path, dtype=float))
    except ValueError as exc:
        raise InputError(
            f"not numeric ({exc})", path=path, hint="write gx gy gz per frame, in OpenCV camera axes"
        ) from None
    if g.shape[1] != 3 or len(g) not in (1, len(world_from_camera)):
        raise InputError(
            f"has shape {g.shape}, expected 1 or {len(world_from_camera)} rows of 3",
            path=path,
            hint="write gx gy gz per frame, in OpenCV camera axes",
        )
    g = np.broadcast_to(g, (len(world_from_camera), 3))
    norms = np.linalg.norm(g, axis=1)
    if np.any(norms <= 0) or not np.all(np.isfinite(g)):
        raise InputError(
            "has zero or invalid gravity vectors", path=path, hint="write gx gy gz per frame, in OpenCV camera axes"
        )
    down = np.einsum("nij,nj->ni", world_from_camera[:, :3, :3], g / norms[:, None])
    mean = down.mean(axis=0)
    spread = float(np.degrees(np.arccos(np.clip(down @ (mean / np.linalg.norm(mean)), -1, 1))).std())
    return GravityEstimate(-mean / np.linalg.norm(mean), "imu", None, [], spread)


def support_plane_for(
    up: np.ndarray,
    points: np.ndarray,
    world_from_camera: np.ndarray,
    anchor: np.ndarray | None = None,
    anchor_min_height_m: float = 0.005,
) -> Plane:
    """The support plane perpendicular to ``up`` among ``points`` (when gravity came from
    elsewhere): the one just below ``anchor``, else the largest."""
    planes = fit_planes(points, world_from_camera[:, :3, 3].mean(axis=0))
    horizontal = [p for p in planes if np.degrees(np.arccos(np.clip(p.normal @ up, -1, 1))) < 10.0]
    if not horizontal:
        raise InputError(
            "no support plane perpendicular to gravity in the depth", hint="film the surface the object rests on"
        )
    main = plane_under(horizontal, anchor, max(p.inliers for p in planes), anchor_min_height_m) or max(
        horizontal, key=lambda p: p.inliers
    )
    return Plane(up, float(up @ (main.offset * main.normal)), main.inliers, main.angle_to_prior_deg)


def world_from_tracking(up: np.ndarray, support: Plane, anchor: np.ndarray, first_camera: np.ndarray) -> np.ndarray:
    """The contract's world frame from the tracking frame: +Z = ``up``, origin = ``anchor``
    projected onto the support plane, +X = the first camera's image-right made horizontal."""
    z = up / np.linalg.norm(up)
    right = first_camera[:3, 0]
    x = right - (right @ z) * z
    if np.linalg.norm(x) < 1e-6:  # camera looking straight down with right = up? use its image-down
        x = first_camera[:3, 1] - (first_camera[:3, 1] @ z) * z
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    origin = support.project(np.asarray(anchor, dtype=float))
    rot = np.stack([x, y, z])  # rows: world axes in tracking coordinates
    return se3.make_pose(rot, -rot @ origin)
