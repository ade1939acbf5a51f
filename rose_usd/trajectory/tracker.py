"""The ``tracker`` trajectory backend: a classical model-based tracker on masked metric depth, for when
no pose files are given (the paper's FoundationPose role, with no learned model).

1. **Model.** The object stage's visual mesh at its frame-0 pose (the world frame), sampled
   evenly (``model_points``) with normals. The tracker estimates, per frame, the rigid motion
   ``D_t`` that carries the frame-0 object to where frame t sees it; ``D_0`` is the identity up to
   what ICP corrects at frame 0 (the object stage already registered the mesh there: by its own
   fusion, or by the imported backend's silhouette-checked ICP). The track is then moved rigidly
   so that frame 0 is the object stage's default pose, as every backend does.
2. **Observation.** The object's mask of the frame (eroded by ``erode_px``: border pixels mix the
   object with what lies behind it) back-projected with the frame's metric depth, at most
   ``max_points`` points. The hand and other objects are outside the mask, so occlusion only
   removes points.
3. **Registration.** Point-to-plane ICP (Gauss-Newton, Cauchy weights) of the observed points
   onto the model, from a constant-velocity prediction (from the last pose when the two frames
   before were not both tracked: the step onto a re-acquired pose is no velocity, and carried on
   it spun a ball 93 deg a frame), coarse to fine (3 cm, 1.5 cm, 8 mm
   correspondence radius). Model points facing away from the camera are never matched (a mug's
   far wall). A weak pull toward the prediction keeps what depth cannot see (a can's spin about
   its axis) at the predicted motion instead of drifting. It is one damping for all six
   coordinates, a fraction of the depth's mean stiffness: weak on position, strong on the turn
   of a small object (its rotation terms are ~size^2 smaller), a filter on the turn rate.
   Damping each coordinate by its own stiffness instead filters the turn far less, and the
   rotation comes out noisier. The object's texture measures what depth leaves free
   (``flow``): corners of the previous frame's object, their Lucas-Kanade window clear of the
   hand (whose moving edge drags them) and their depth within 1 cm of the mesh, followed into
   this frame, add their reprojection errors to the ICP, each coordinate weighing as much as
   ``flow_weight`` depth points (realistic place-mug, lying in a palm: APE 18.1 -> 3.0 mm;
   rotate-mug's turn 47 -> 19 deg; default place-mug, flat-coloured under a moving camera,
   3.1 -> 6.2 deg: its corners are on its outline, whose window takes in the background). Not
   for a category that is a solid of revolution (can, cup, ...): corners on its outline do not
   turn with it (lift-can 5.5 -> 14 deg).
   Observed points more than ``OCCLUDER_M`` in front of the fitted model's surface are a hand
   on it that its mask took (a palm over a lying mug: realistic place-mug's track was lost as it
   was lifted, APE 57.6 mm, 17.9 mm without them): the fit is made again, from itself, without
   them. Not from the prediction: a mug turned in the hand shows its handle in front of where
   it was predicted, and the turn is lost with it. Then, where the matched normals leave a
   direction free (``weak_axis``: a can or a cup seen only by its wall, a hand on its top), the
   pose is slid along it to where fitness plus silhouette IoU is best (``slide``, within
   ``slide_span_m``; silhouettes drawn from ``SILHOUETTE_FACES`` triangles of the model, in the
   window it projects into): a real cup seen by its wall slid 5 cm along its axis in ten frames
   without it. After the refit, not before: slid by a mask with a palm in it, the lying mug's
   track went from 17.8 to 38 mm.
4. **Confidence.** The fraction of observed points within 5 mm of the model after ICP. A frame
   with fewer than ``min_points`` observed points, or a fit under ``min_fitness``, is lost: the pose
   holds, confidence 0. When the object shows again it is re-acquired: ICP from the last pose
   moved onto the observed points and turned about the vertical in 45 deg steps, the best by
   fitness and silhouette IoU against the mask, among those turned no more than a hand turns an
   object in the time it was hidden (``max_turn_deg_s``: real cups' cup, hidden one frame, was
   re-acquired spun 132 deg, and the robot could not follow the spin). A re-acquisition that holds for fewer than 3
   frames before the object is lost again is dropped (``confirmed``: a glimpse between fingers).
   Frames lost between two tracked ones are then interpolated on SE(3) (confidence 0.5); lost at
   the end they hold (confidence 0).
5. **Rest.** Objects move only when touched: while the interactor's mask has not come near the
   object's (``geometry.contact.touches``, within ``TOUCH_REACH_PX``) for ``release_frames`` frames
   and the last pose still fits the depth, the pose holds. When it first holds after a touch, the
   pose is moved along gravity to where fitness plus silhouette IoU is best
   (``settle_along_gravity``): a can's wall fits its depth at any height, and a hand on its top
   hid the face that fixes it. (A can standing beside a stack it is not part of would otherwise
   follow depth noise and masks that grow onto a neighbor.) A case with no interactor masks has
   no gate. A fit that moves an untouched object is counted (``moved_untouched``).
6. **Smoothing.** A centered (zero-lag) binomial window of ``smooth_window`` frames on SE(3) over
   tracked frames: it removes per-frame ICP noise without delaying the motion at contacts.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import time
from dataclasses import dataclass

import cv2
import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from rose_usd.core import se3
from rose_usd.core.pinhole import backproject, nearest_depth, pixels_of, projected_box, silhouette
from rose_usd.core.runs import true_runs
from rose_usd.core.watertight import is_closed
from rose_usd.errors import InputError
from rose_usd.geometry.contact import touches
from rose_usd.geometry.mesh import decimate
from rose_usd.geometry.primitives import typical
from rose_usd.layers.masks import INTERACTOR, read_masks
from rose_usd.layers.objects import default_pose, visual_mesh
from rose_usd.layers.world import metric_depth_reader, read_cameras
from rose_usd.progress import progress
from rose_usd.stage_api import StageContext
from rose_usd.trajectory import flow
from rose_usd.trajectory.author import author_trajectory, fill_gaps, from_default_pose
from rose_usd.trajectory.colour_turns import colour_consistent
from rose_usd.trajectory.rests import rest_poses

SCHEDULE = ((0.03, 6), (0.015, 6), (0.008, 8))
"""(correspondence radius [m], Gauss-Newton iterations) of each ICP level."""
INLIER_M = 0.005
"""An observed point within this distance of the model after ICP counts toward fitness [m]."""
OCCLUDER_M = 0.01
"""An observed point nearer the camera than the fitted model's surface by more than this is on
something in front of it (a finger), and the fit is made again without it [m]."""
MIN_LEFT = 30
"""... unless fewer points than this would remain."""


SILHOUETTE_FACES = 1500
"""Triangles the model's silhouettes are drawn from (a quadric decimation of its mesh, or the mesh
itself where the decimator cannot thin it): each is
one OpenCV fill, and the slide along a weak axis draws about 25 silhouettes a frame. A fused mug's
8000 triangles took 6.4 ms a silhouette, 1500 take 1.8 ms; their IoU with its masks differs by at
most 0.004 (150 random poses)."""


@dataclass
class Model:
    """The object's surface at its frame-0 pose (world coordinates), for registration."""

    points: np.ndarray
    normals: np.ndarray
    center: np.ndarray
    tree: cKDTree
    vertices: np.ndarray
    faces: np.ndarray
    """The mesh its silhouettes are drawn from (about ``SILHOUETTE_FACES`` triangles)."""
    closed: bool = False
    """Watertight and wound outward: silhouettes are drawn from camera-facing triangles only."""

    @classmethod
    def from_mesh(cls, vertices: np.ndarray, faces: np.ndarray, count: int) -> Model:
        import trimesh

        mesh = trimesh.Trimesh(vertices, faces, process=False)
        points, tri = trimesh.sample.sample_surface_even(mesh, count, seed=0)
        normals = mesh.face_normals[tri]
        outline = decimate(mesh, SILHOUETTE_FACES, check=False)
        return cls(
            points,
            normals,
            points.mean(axis=0),
            cKDTree(points),
            np.asarray(outline.vertices, dtype=float),
            np.asarray(outline.faces, dtype=np.int64),
            is_closed(outline),
        )


@dataclass
class Fit:
    motion: np.ndarray
    """D_t: world pose of the frame-0 object -> its pose at frame t (4, 4)."""
    fitness: float
    rms_m: float


def _exp(xi: np.ndarray) -> np.ndarray:
    """A twist (rotation vector, translation) as a 4x4 transform (rotation first order exact)."""
    return se3.make_pose(Rotation.from_rotvec(xi[:3]).as_matrix(), xi[3:])


def register(
    model: Model,
    observed: np.ndarray,
    camera: np.ndarray,
    start: np.ndarray,
    *,
    prior_weight: float = 0.0,
    schedule=SCHEDULE,
    features: flow.Features | None = None,
    flow_weight: float = 1.0,
) -> Fit:
    """Point-to-plane ICP of ``observed`` (world points of frame t) onto ``model`` from motion
    ``start``; ``camera`` is the frame's camera center (for the facing test). ``prior_weight``
    pulls toward ``start``, as a fraction of the depth's mean stiffness (trace / 6). Returns the
    motion, the inlier fraction and the inliers' RMS distance. ``features``: the object's texture
    tracked from the previous frame (``flow``), each corner's coordinates weighing as much as
    ``flow_weight`` depth points each."""
    c = model.center
    # work on the model side: observed points pulled back by the inverse motion, centered at c
    inv = se3.invert(start)
    dir_world = observed - camera  # viewing rays
    acc = np.zeros(6)  # the correction accumulated since ``start`` (for the prior)
    for radius, iters in schedule:
        for _ in range(iters):
            p = se3.transform_points(inv, observed)
            d, idx = model.tree.query(p, distance_upper_bound=radius)
            ok = np.isfinite(d)
            idx = np.where(ok, idx, 0)
            n = model.normals[idx]
            # model normals brought to frame t must face the camera
            facing = np.einsum("ij,ij->i", n @ se3.invert(inv)[:3, :3].T, dir_world) < 0
            ok &= facing
            if ok.sum() < 12:
                break
            pc, m, n = p[ok] - c, model.points[idx[ok]] - c, n[ok]
            r = np.einsum("ij,ij->i", n, pc - m)
            w = 1.0 / (1.0 + (r / 0.003) ** 2)
            J = np.hstack([np.cross(pc, n), n])
            H = (J * w[:, None]).T @ J
            g = (J * w[:, None]).T @ r
            # one damping for all six coordinates, a fraction of the depth's mean stiffness: the
            # rotation terms are ~(object size)^2 smaller than the translation terms, so for a
            # 5-10 cm object this is a weak pull on position and a strong one on the turn
            lam = prior_weight * np.trace(H) / 6.0
            if features is not None:  # the texture's pull is on top of that of depth
                Hf, gf = flow.terms(features, se3.invert(inv), c, flow_weight)
                H, g = H + Hf, g + gf
            try:
                xi = np.linalg.solve(H + lam * np.eye(6), -g - lam * acc)
            except np.linalg.LinAlgError:  # all matches on one plane, no prior: move along none of its free directions
                xi = np.linalg.lstsq(H + lam * np.eye(6), -g - lam * acc, rcond=None)[0]
            step = se3.make_pose(np.eye(3), c) @ _exp(xi) @ se3.make_pose(np.eye(3), -c)
            inv = step @ inv
            acc += xi
            if np.linalg.norm(xi[:3]) < 1e-5 and np.linalg.norm(xi[3:]) < 1e-5:
                break
    return evaluate(model, observed, se3.invert(inv))


def evaluate(model: Model, observed: np.ndarray, motion: np.ndarray) -> Fit:
    """The fit of ``observed`` points to the model moved by ``motion``: the fraction within
    ``INLIER_M`` and their RMS distance."""
    return evaluate_many(model, observed, motion[None])[0]


def evaluate_many(model: Model, observed: np.ndarray, motions: np.ndarray) -> list[Fit]:
    """``evaluate`` at each of ``motions`` (M, 4, 4), the nearest model points found in one query
    on both cores. Nearest points are searched within ``INLIER_M`` only: the fit needs no farther
    distance, and the bounded search is faster (0.5 against 0.8 ms for 1500 points)."""
    n = len(observed)
    if not len(motions):
        return []
    pulled = np.concatenate([se3.transform_points(se3.invert(m), observed) for m in motions])
    d = model.tree.query(pulled, distance_upper_bound=INLIER_M, workers=-1 if len(motions) > 1 else 1)[0]
    fits = []
    for m, dm in zip(motions, d.reshape(len(motions), n)):
        inl = dm < INLIER_M
        rms = float(np.sqrt(np.mean(dm[inl] ** 2))) if inl.any() else float("inf")
        fits.append(Fit(m, float(inl.mean()) if n else 0.0, rms))
    return fits


def silhouette_iou(
    model: Model, motion: np.ndarray, mask: np.ndarray, ignore: np.ndarray, world_from_cv: np.ndarray, K: np.ndarray
) -> float:
    """IoU of the model's silhouette at ``motion`` with ``mask``, pixels of ``ignore`` (hand and
    other objects: they may hide the object) left out."""
    h, w = mask.shape
    vertices = se3.transform_points(motion, model.vertices)
    box = projected_box(vertices, world_from_cv, K, w, h)
    if box is None:
        return 0.0
    # the silhouette is drawn only in the window its vertices project into (the same pixels): a
    # vertex is drawn at its rounded pixel, a pixel's margin either side
    x0, y0 = max(0, int(np.floor(box[0])) - 1), max(0, int(np.floor(box[1])) - 1)
    x1, y1 = min(w, int(np.ceil(box[2])) + 2), min(h, int(np.ceil(box[3])) + 2)
    sil = silhouette(vertices, model.faces, world_from_cv, K, w, h, closed=model.closed, window=(x0, y0, x1, y1))
    seen = np.count_nonzero(mask & ~ignore)
    sil &= ~ignore[y0:y1, x0:x1]
    in_mask = mask[y0:y1, x0:x1]
    inter = np.count_nonzero(sil & in_mask)
    union = seen + np.count_nonzero(sil & ~in_mask)
    return float(inter / union) if union else 0.0


def smooth(motions: np.ndarray, good: np.ndarray, window: int) -> np.ndarray:
    """A centered binomial window on SE(3) over the ``good`` frames (others kept as they are)."""
    if window < 3:
        return motions
    half = window // 2
    weights = np.array([math.comb(2 * half, k) for k in range(2 * half + 1)], float)
    out = motions.copy()
    n = len(motions)
    rots = Rotation.from_matrix(motions[:, :3, :3])
    for t in np.flatnonzero(good):
        idx = np.arange(max(0, t - half), min(n, t + half + 1))
        idx = idx[good[idx]]
        # a symmetric window: as many frames on each side (no lag at the ends of a motion)
        reach = min(t - idx.min(), idx.max() - t)
        idx = idx[np.abs(idx - t) <= reach]
        if len(idx) < 3:
            continue
        wt = weights[idx - t + half]
        wt = wt / wt.sum()
        rel = (rots[t].inv() * rots[idx]).as_rotvec()
        out[t, :3, :3] = (rots[t] * Rotation.from_rotvec(wt @ rel)).as_matrix()
        out[t, :3, 3] = wt @ motions[idx, :3, 3]
    return out


def _observed(
    depth: np.ndarray, mask: np.ndarray, K: np.ndarray, world_from_cv: np.ndarray, erode_px: int, max_points: int
) -> np.ndarray:
    if erode_px:
        mask = cv2.erode(mask.astype(np.uint8), np.ones((2 * erode_px + 1,) * 2, np.uint8)).astype(bool)
    v, u = np.nonzero(mask & (depth > 0))
    if len(v) > max_points:  # an even subsample: every k-th pixel in scan order
        pick = np.linspace(0, len(v) - 1, max_points).astype(int)
        v, u = v[pick], u[pick]
    return se3.transform_points(world_from_cv, backproject(u, v, depth[v, u], K))


def _unoccluded(
    model: Model,
    observed: np.ndarray,
    motion: np.ndarray,
    world_from_cv: np.ndarray,
    K: np.ndarray,
    shape: tuple[int, int],
    *,
    tol_m: float = OCCLUDER_M,
) -> np.ndarray:
    """``observed`` without the points nearer the camera than the model's surface at ``motion`` by
    more than ``tol_m``, where the model shows (within 3 px): a palm and fingers on the object
    that its mask took. Points beside the model's silhouette stay (it may have moved there). All
    are kept when fewer than ``MIN_LEFT`` would remain."""
    h, w = shape
    near = nearest_depth(se3.transform_points(motion, model.points), world_from_cv, K, w, h, window_px=7)
    ou, ov, oz = pixels_of(observed, world_from_cv, K, w, h, min_z=0.05)
    inside = ou >= 0
    front = np.zeros(len(observed), bool)
    surface = near[ov[inside], ou[inside]]
    front[inside] = np.isfinite(surface) & (oz[inside] < surface - tol_m)
    return observed if np.count_nonzero(~front) < MIN_LEFT else observed[~front]


def _predict(motions: list[np.ndarray], damping: float = 0.7) -> np.ndarray:
    """Constant velocity (damped) from the last two motions."""
    if len(motions) < 2:
        return motions[-1]
    velocity = motions[-1] @ se3.invert(motions[-2])
    rv = Rotation.from_matrix(velocity[:3, :3]).as_rotvec() * damping
    step = se3.make_pose(Rotation.from_rotvec(rv).as_matrix(), velocity[:3, 3] * damping)
    # the velocity applied about the object's current position, not the world origin
    return step @ motions[-1]


def _reacquire(
    model: Model,
    observed: np.ndarray,
    camera: np.ndarray,
    last: np.ndarray,
    score,
    *,
    max_turn_deg: float = 180.0,
    margin: float = 0.05,
) -> Fit:
    """The fit from ``last`` (an object hidden for a while has often not moved), unless a start
    moved so the model's center meets the observed points' (pushed back by half the object along
    the view) and turned about the vertical in 45 deg steps scores ``margin`` better (a solid of
    revolution scores alike at every turn: it keeps its last spin). A fit turned more than
    ``max_turn_deg`` from ``last`` (more than a hand turns an object in the time it was hidden)
    is not taken."""
    best = register(model, observed, camera, last, prior_weight=0.0)
    best_score = score(best) + margin
    radius = float(np.max(np.linalg.norm(model.points - model.center, axis=1)))
    seen = observed.mean(axis=0)
    ray = (seen - camera) / np.linalg.norm(seen - camera)
    target = seen + 0.5 * radius * ray
    here = se3.transform_points(last, model.center[None])[0]
    for yaw in np.radians(np.arange(0, 360, 45)):
        turn = se3.make_pose(se3.rotation_about(np.array([0.0, 0.0, 1.0]), yaw), np.zeros(3))
        start = se3.make_pose(np.eye(3), target) @ turn @ se3.make_pose(np.eye(3), -here) @ last
        fit = register(model, observed, camera, start, prior_weight=0.0)
        if se3.rotation_angle_deg((fit.motion @ se3.invert(last))[:3, :3]) > max_turn_deg:
            continue
        s = score(fit)
        if s > best_score:
            best, best_score = fit, s
    return best


def weak_axis(
    model: Model,
    observed: np.ndarray,
    motion: np.ndarray,
    camera: np.ndarray,
    *,
    radius_m: float = 0.008,
    ratio: float = 0.05,
) -> np.ndarray | None:
    """The world direction along which moving the model barely changes its point-to-plane fit
    to ``observed`` (the smallest eigenvector of the matched camera-facing normals' scatter),
    when its stiffness is under ``ratio`` of the largest; else None. A can seen only by its
    wall (a hand on its top) has no normal along its axis: its wall fits at any height."""
    d, idx = model.tree.query(se3.transform_points(se3.invert(motion), observed), distance_upper_bound=radius_m)
    ok = np.isfinite(d)
    if ok.sum() < 12:
        return None
    n = model.normals[idx[ok]] @ motion[:3, :3].T
    n = n[np.einsum("ij,ij->i", n, observed[ok] - camera) < 0]
    if len(n) < 12:
        return None
    values, vectors = np.linalg.eigh(n.T @ n / len(n))
    return vectors[:, 0] if values[0] < ratio * values[-1] else None


def slide(
    model: Model,
    observed: np.ndarray,
    here: Fit,
    axis: np.ndarray,
    score,
    *,
    span_m: float,
    step_m: float,
    margin: float,
) -> Fit:
    """``here`` (a fit of ``observed``) moved along ``axis`` by the offset (within +-``span_m``,
    ``step_m`` steps, then 1 mm steps around the best) that ``score`` rates best, when it beats
    ``here`` by at least ``margin``; else ``here``."""

    def at(offsets: np.ndarray) -> list[Fit]:
        moves = [se3.make_pose(np.eye(3), float(o) * axis) @ here.motion for o in offsets]
        return evaluate_many(model, observed, np.stack(moves)) if moves else []

    coarse = np.arange(-span_m, span_m + 1e-9, step_m)
    top_score, top, best_offset = max(
        ((score(f), f, o) for o, f in zip(coarse, at(coarse))),
        key=lambda c: c[0],
    )
    fine = best_offset + np.arange(-step_m + 0.001, step_m - 1e-9, 0.001)
    for f in at(fine):
        sc = score(f)
        if sc > top_score:
            top_score, top = sc, f
    return top if top_score > score(here) + margin else here


def settle_along_gravity(
    model: Model,
    observed: np.ndarray,
    here: Fit,
    score,
    *,
    span_m: float = 0.08,
    step_m: float = 0.004,
    margin: float = 0.02,
) -> Fit:
    """``here`` slid along gravity to where ``score`` (fitness + silhouette IoU) is best. Depth
    cannot tell where along its axis a can seen from the side is: its wall matches the model at
    any height, and a hand on its top hides the one face that could: put down, a can may be held
    centimeters above the table. Its silhouette's bottom edge can tell."""
    return slide(model, observed, here, np.array([0.0, 0.0, 1.0]), score, span_m=span_m, step_m=step_m, margin=margin)


def _settings_for(ctx: StageContext, name: str):
    """The tracker's settings for object ``name``: no texture flow for a solid of revolution
    (its category's): corners on its outline do not turn with it (a can's spin went 5 -> 14 deg)."""
    category = next((o.category for o in ctx.case.config.objects if o.name == name), "generic")
    cfg = ctx.config.tracker
    return dataclasses.replace(cfg, flow_weight=0.0) if typical(category)[0].revolution else cfg


class _Texture:
    """The object's corners followed from one tracked frame to the next (module step 3, ``flow``)."""

    def __init__(self, ctx: StageContext, cfg, cameras, model: Model, occluders):
        self.case, self.cfg, self.cameras, self.model, self.occluders = ctx.case, cfg, cameras, model, occluders
        self._frames: dict[int, tuple[np.ndarray, np.ndarray]] = {}

    def frame(self, t: int) -> tuple[np.ndarray, np.ndarray]:
        """Frame t in grey, and where a corner's Lucas-Kanade window (at full resolution; the
        coarser pyramid levels see farther) would take in a hand or another object, whose moving
        edges drag it along. Made once: frame t is the later frame, then the earlier one."""
        if t not in self._frames:
            self._frames = {k: v for k, v in self._frames.items() if k == t - 1}
            near = cv2.dilate(self.occluders(t).astype(np.uint8), np.ones((flow.WINDOW_PX,) * 2, np.uint8))
            self._frames[t] = cv2.cvtColor(self.case.rgb(t), cv2.COLOR_RGB2GRAY), near.astype(bool)
        return self._frames[t]

    def features(self, seen, t: int, mask: np.ndarray, motion_prev: np.ndarray) -> flow.Features | None:
        """The corners of ``seen`` = (frame, the object's mask, depth) at pose ``motion_prev``,
        followed into frame ``t`` where ``mask`` is; those whose depth was not within 1 cm of the
        mesh are on something else (a finger) and left out."""
        if seen is None or self.cfg.flow_weight <= 0:
            return None
        s, mask_s, depth_s = seen
        (gray_s, near_s), (gray_t, near_t) = self.frame(s), self.frame(t)
        cams, box = self.cameras, np.ones((2 * self.cfg.erode_px + 1,) * 2, np.uint8)
        where = cv2.erode(mask_s.astype(np.uint8), box).astype(bool) & ~near_s
        region = cv2.dilate(mask.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool) & ~near_t
        views = (cams.world_from_cv[s], cams.K[s]), (cams.world_from_cv[t], cams.K[t])
        got = flow.track_features((gray_s, where, depth_s), gray_t, *views, motion_prev, region=region)
        return got and got.subset(self.model.tree.query(got.points)[0] < 2 * INLIER_M)


def track(ctx: StageContext, name: str, model: Model, cameras, depth_of) -> tuple[np.ndarray, np.ndarray, dict]:
    """Motions D_t (N, 4, 4), confidence (N,) and facts of object ``name``."""
    cfg, n = _settings_for(ctx, name), ctx.time_info.n_frames
    shape = (ctx.case.height, ctx.case.width)
    layer = read_masks(ctx.stage, n, shape)
    layer.require(name)
    has_hand = layer.has(INTERACTOR)

    def occluders(t: int) -> np.ndarray:
        return layer.occluders(name, t, shape, grow_px=2)

    def silhouette_score(t: int, mask: np.ndarray):
        """Fitness plus silhouette IoU at frame t, the hand and other objects left out (read once)."""
        ignore = occluders(t)
        return lambda f: (
            f.fitness + silhouette_iou(model, f.motion, mask, ignore, cameras.world_from_cv[t], cameras.K[t])
        )

    motions, tracked, fitness = [np.eye(4)], np.zeros(n, bool), np.zeros(n)
    lost_since, reacquired, iou0, last_touch, moved_untouched, settled, slid = None, 0, float("nan"), -n, 0, 0, 0
    texture = _Texture(ctx, cfg, cameras, model, occluders)
    seen = None  # the last tracked frame, its mask and depth (for the texture's corners)
    for t in progress(range(n), f"trajectory {name}: tracking", total=n):
        mask = layer.mask(name, t)
        mask = np.zeros(shape, bool) if mask is None else mask
        cam, K, depth = cameras.world_from_cv[t], cameras.K[t], depth_of(t)
        hand = layer.mask(INTERACTOR, t) if has_hand and mask.any() else None
        if not has_hand or (hand is not None and touches(hand, mask, depth)):
            last_touch = t
        observed = (
            _observed(depth, mask, K, cam, cfg.erode_px, cfg.max_points)
            if mask.sum() >= cfg.min_points
            else np.zeros((0, 3))
        )
        prev = motions[-1] if t else np.eye(4)
        if len(observed) < cfg.min_points:
            motions.append(prev) if t else None
            lost_since = t if lost_since is None else lost_since
            continue
        hold = evaluate(model, observed, prev) if t else None
        if t and t - last_touch > cfg.release_frames and hold.fitness >= cfg.min_fitness:
            # untouched and still where it was: it rests (objects move only when touched)
            fit = hold
            if last_touch >= 0 and t - last_touch == cfg.release_frames + 1:
                # just let go: where it rests along gravity, by its silhouette (module step 5)
                fit = settle_along_gravity(model, observed, hold, silhouette_score(t, mask))
                settled += fit is not hold
                hold = fit
        elif lost_since is not None and lost_since < t:
            hidden_s = (t - lost_since + 1) / ctx.time_info.fps
            turn = min(180.0, cfg.max_turn_deg_s * hidden_s)
            fit = _reacquire(model, observed, cam[:3, 3], prev, silhouette_score(t, mask), max_turn_deg=turn)
            reacquired += 1
        else:
            score = functools.partial(silhouette_score, t, mask)
            steady = t >= 2 and tracked[t - 1] and tracked[t - 2]
            view = (cam, K, shape, texture.features(seen, t, mask, motions[-1]) if t and tracked[t - 1] else None)
            fit, moved = _registered(model, observed, view, motions, t, cfg, score, steady=steady)
            slid += moved
        if t == 0:
            iou0 = silhouette_iou(model, fit.motion, mask, occluders(0), cam, K)
        if fit.fitness < cfg.min_fitness:
            motions.append(prev) if t else None
            lost_since = t if lost_since is None else lost_since
            continue
        if t and t - last_touch > cfg.release_frames and fit is not hold:
            moved_untouched += 1
        lost_since = None
        if t:
            motions.append(fit.motion)
        else:
            motions[0] = fit.motion
        tracked[t], fitness[t], seen = True, fit.fitness, (t, mask, depth)
    counts = {"reacquired": reacquired, "moved_untouched": moved_untouched, "flow_weight": cfg.flow_weight}
    counts |= {"settled_along_gravity": settled, "slid_along_weak_axis": slid}
    return _finish(name, np.stack(motions), tracked, fitness, cfg, counts, iou0, layer.where(name))


def confirmed(tracked: np.ndarray, *, run: int = 3) -> np.ndarray:
    """``tracked`` without the runs of fewer than ``run`` frames after a loss: a pose re-acquired
    in a frame or two between lost ones is a guess from a glimpse (a ball in a hand, seen between
    the fingers: such frames jumped 3-10 cm and back), and the frames around it are interpolated
    instead. The first run of the video is kept whatever its length."""
    out = tracked.copy()
    for first, last in true_runs(tracked):
        if first > 0 and last - first + 1 < run and out[:first].any():
            out[first : last + 1] = False
    return out


def _finish(name: str, motions, tracked, fitness, cfg, counts: dict, iou0: float, where):
    """Smoothed motions with the lost frames filled, confidence per frame, and the facts."""
    n = len(tracked)
    if not tracked.any():
        raise InputError(
            f"object {name!r} was never tracked: no frame has {cfg.min_points} masked depth points fitting its mesh",
            path=where,
            hint="check its masks (segment stage) and the object mesh",
        )
    kept = confirmed(tracked)
    unconfirmed, tracked = int(tracked.sum() - kept.sum()), kept
    motions = smooth(motions, tracked, cfg.smooth_window)
    filled, confidence = fill_gaps(motions, tracked)
    confidence[tracked] = np.clip(fitness[tracked], 0.0, 1.0)
    facts = {
        "frames_tracked": int(tracked.sum()),
        "unconfirmed": int(unconfirmed),
        "frames_lost": int(n - tracked.sum()),
        **counts,
        "fitness_mean": round(float(fitness[tracked].mean()), 3),
        "silhouette_iou_frame0": round(iou0, 3),
    }
    return filled, confidence, facts


def _registered(model: Model, observed: np.ndarray, view, motions: list, t: int, cfg, score, *, steady: bool):
    """Registration from the damped constant-velocity prediction (from the last pose when the two
    frames before were not both tracked: the step from a held or re-acquired pose is no velocity);
    made again without the points in front of the fit (a hand on the object, taken into its
    mask); where depth then leaves a direction free, slid along it to where ``score()`` (fitness
    plus silhouette IoU) is best (module step 3). ``view``: the frame's camera pose, K, image
    shape and the texture's corners followed from the frame before (``flow.Features`` or None).
    Returns the fit and whether the slide moved it."""
    cam, K, shape, features = view
    start = (_predict(motions) if steady else motions[-1]) if t else np.eye(4)
    solve = functools.partial(register, prior_weight=cfg.prior_weight, features=features, flow_weight=cfg.flow_weight)
    fit = solve(model, observed, cam[:3, 3], start)
    if not t:
        return fit, False
    clear = _unoccluded(model, observed, fit.motion, cam, K, shape)
    if len(clear) < len(observed):
        fit = solve(model, clear, cam[:3, 3], fit.motion)
    axis = weak_axis(model, clear, fit.motion, cam[:3, 3]) if cfg.slide_span_m > 0 else None
    if axis is None:
        return fit, False
    slid = slide(model, clear, fit, axis, score(), span_m=cfg.slide_span_m, step_m=0.004, margin=0.005)
    return slid, slid is not fit


def run(ctx: StageContext) -> None:
    n = ctx.time_info.n_frames
    cameras = read_cameras(ctx.stage, n)
    depth_of = metric_depth_reader(ctx.stage, ctx.case, cache=4)
    results, facts = {}, {}
    for spec in ctx.case.config.objects:  # every object tracked before anything is written
        mesh = visual_mesh(ctx.stage, spec.name)  # world coordinates at the default (frame-0) pose
        model = Model.from_mesh(mesh.vertices, mesh.faces, ctx.config.tracker.model_points)
        start = time.perf_counter()
        motions, confidence, fact = track(ctx, spec.name, model, cameras, depth_of)
        fact["frames_per_s"] = round(n / (time.perf_counter() - start), 1)
        lost = fact["frames_lost"]
        if lost:
            ctx.warn(
                f"object {spec.name!r}: lost in {lost} of {n} frames (too few masked depth points, or no fit): "
                "interpolated between tracked frames (confidence 0.5) or held at the ends (0)"
            )
        world0 = default_pose(ctx.stage, spec.name)
        results[spec.name] = (np.einsum("nij,jk->nik", motions, world0), confidence)
        facts[spec.name] = fact
    final = {name: from_default_pose(ctx, name, poses) for name, (poses, _) in results.items()}
    masks = read_masks(ctx.stage, n, (ctx.case.height, ctx.case.width))
    for name in final:
        final[name], facts[name]["colour_turns"] = colour_consistent(
            ctx.stage, name, final[name], masks.track(name), cameras, ctx.case.rgb
        )
    for name, rests in rest_poses(ctx, final).items():
        facts[name]["rests"] = rests
    for name, (_, confidence) in results.items():
        author_trajectory(ctx, name, final[name], confidence, "tracker")
    ctx.record(objects=facts)
