"""Resting the trajectory where the video shows the object at rest (``sim.resting``: seen, untouched,
still). A tracker's set-down pose is a measurement: a millimetre or two into the table, or a few
degrees off level, and a simulator started there ejects the object (realistic suite, rgbd, the
gate's rest check from the last frame: set-downs 1.5-1.8 mm lower than the settled start moved
16-68 mm). Each resting run after the first frame holds one pose, the run's mean, levelled onto
the face the object rested on at frame 0 when within ``LEVEL_DEG`` of it, and moved along gravity
into contact with the scene and the other objects at that frame (``sim.settle``, as the object
stage rests frame 0); a run from frame 0 holds the object stage's default pose, settled already.
A run whose poses spread more than ``SPREAD_M`` (a drifting track) or that settle leaves alone
(more than 3 cm inside the scene) keeps its poses; one more than 1.5 cm over what is under it is
held where it is (the gate's rest check shows it)."""

from __future__ import annotations

import functools
import math
from types import SimpleNamespace

import numpy as np
import trimesh
from pxr import Usd
from scipy.spatial.transform import Rotation

from rose_usd.core import se3
from rose_usd.layers.masks import read_masks
from rose_usd.layers.objects import collision_approximation
from rose_usd.layers.scene import scene_collider
from rose_usd.sim.collider import coacd_parts
from rose_usd.sim.resting import (
    box_corners,
    min_run_frames,
    posed_corners,
    resting_runs,
    still_frames,
    untouched_frames,
)
from rose_usd.sim.settle import settle
from rose_usd.stage_api import StageContext
from rose_usd.usd import paths
from rose_usd.usd.geom import read_mesh

SPREAD_M = 0.01
"""A resting run whose poses put a corner of the object's box farther than this from where the
run's mean pose puts it is left as tracked [m]."""


EASE_DEG_S = 45.0
"""A held run's change fades in and out no faster than this turn [deg/s] ..."""
EASE_M_S = 0.1
"""... and this shift [m/s] (over at least ``sim.resting.MIN_RUN_S``)."""

MAX_DROP_M = 0.05
"""A resting run's pose is lowered onto what is under it from up to this high [m]: the object rests
(untouched and still), so it stands on something; turning it upright raises a cup's base 2 cm."""

LEVEL_DEG = 10.0
"""A set-down pose whose up is within this of the object's up at its frame-0 rest is levelled [deg]."""

MIN_TIP_DEG = 5.0
"""A face holds the object when its center of mass stands this far inside the face's edges, as
the tilt that would tip it over [deg]."""


def mean_pose(poses: np.ndarray) -> np.ndarray:
    """The mean of poses (N, 4, 4): mean translation, chordal mean rotation."""
    return se3.make_pose(se3.orthonormalize(poses[:, :3, :3].sum(axis=0)), poses[:, :3, 3].mean(axis=0))


def rest_poses(ctx: StageContext, poses: dict[str, np.ndarray], *, measured: bool = True) -> dict[str, list[dict]]:
    """Hold and settle the resting runs of each object's poses (name -> (n, 4, 4) world poses, the
    backend's, changed in place); returns per object what was done with each run. Poses not
    ``measured`` in depth (silhouettes alone, whose support plane may be tilted by the
    vanishing points' tens of degrees) are only levelled, never turned onto another face, and
    lowered by no more than ``sim.settle``'s 1.5 cm: moved along gravity, a pen fitted 4 cm over
    openreal2sim-marker-rgb's desk left its silhouette (track IoU 0.77 -> 0.36)."""
    stage, n = ctx.stage, ctx.time_info.n_frames
    masks = read_masks(stage, n)
    meshes = {name: read_mesh(stage.GetPrimAtPath(paths.object_collision(name)), world=False) for name in poses}
    corners = {
        name: box_corners(meshes[name].vertices.min(axis=0), meshes[name].vertices.max(axis=0)) for name in poses
    }
    still = {name: still_frames(poses[name], corners[name]) for name in poses}
    runs = {
        name: resting_runs(still[name] & untouched_frames(masks, name, n), min_run_frames(ctx.time_info.fps))
        for name in poses
    }
    # still at frame 0, the object stands as the object stage rested it: the face to set it down on
    upright = {name: poses[name][0].copy() if still[name][0] else None for name in poses}
    fps = ctx.time_info.fps
    fixed = {name: _in_runs(runs[name], n) for name in poses}
    scene = scene_collider(stage)
    colliders = functools.cache(lambda name: _collider_points(stage, name, meshes[name]))
    return {
        name: [
            {
                "frames": [first, last],
                **_rest_run(
                    name,
                    first,
                    last,
                    poses,
                    meshes,
                    corners[name],
                    scene,
                    colliders,
                    upright[name],
                    fps,
                    fixed[name],
                    measured=measured,
                ),
            }
            for first, last in runs[name]
        ]
        for name in poses
    }


def _rest_run(
    name, first, last, poses, meshes, corners, scene, colliders, upright, fps: float, fixed, *, measured: bool = True
) -> dict:
    """Hold object ``name`` over frames first..last at one settled pose (in ``poses``), standing
    as at its resting pose ``upright`` (``_upright``), the change eased in and out (``_ease``, at
    ``fps``; ``fixed``: the frames of its runs); what was done."""
    run = poses[name][first : last + 1]
    if first == 0:
        pose, lift = run[0].copy(), 0.0
    else:
        pose = mean_pose(run)
        tracked = posed_corners(run, corners)
        spread = float(np.linalg.norm(tracked - se3.transform_points(pose, corners), axis=2).max())
        if spread > SPREAD_M:
            return {"held": False, "why": f"poses spread {1e3 * spread:.0f} mm"}
        pose = _upright(pose, upright, meshes[name].vertices, may_turn=measured)
        model = SimpleNamespace(name=name, mesh=meshes[name], world_from_object_0=pose)
        others = [
            (se3.transform_points(poses[o][last], meshes[o].vertices), meshes[o].faces) for o in poses if o != name
        ]
        drop = {"max_drop_m": MAX_DROP_M} if measured else {}
        lift = settle([model], scene, under=others, collider_points={name: colliders(name)}, **drop)[name]
        if not np.isfinite(lift):
            return {"held": False, "why": "more than 3 cm inside the scene"}
        pose = model.world_from_object_0
    ends = run[0].copy(), run[-1].copy()
    poses[name][first : last + 1] = pose
    _ease(poses[name], first, last, ends, pose, meshes[name].vertices.mean(axis=0), fps, fixed)
    return {"held": True, "settle_lift_m": round(float(lift), 5)}


def _ease(track, first, last, ends, pose, centre, fps: float, fixed: np.ndarray) -> None:
    """Spread the change a held run made at its ends (``ends``: the tracked poses at ``first`` and
    ``last``, now ``pose``) over the frames before and after it, fading out (the set-down's last
    lowering, the pick-up's first lift): over ``sim.resting.MIN_RUN_S``, longer where the change would turn
    faster than ``EASE_DEG_S`` or move faster than ``EASE_M_S``; ``fixed`` frames (other runs) are
    left as they are. A held pose a few degrees off the tracked one is then no jump between two
    frames (a robot following the path would have to make it). The change is a turn about the
    object's ``centre`` (object frame) and a shift of it."""
    for end, step in ((first, -1), (last, 1)):
        was = ends[0] if step < 0 else ends[1]
        turn = Rotation.from_matrix(pose[:3, :3] @ was[:3, :3].T).as_rotvec()
        shift = se3.transform_points(pose, centre[None])[0] - se3.transform_points(was, centre[None])[0]
        frames = max(
            min_run_frames(fps),
            math.ceil(np.degrees(np.linalg.norm(turn)) / EASE_DEG_S * fps),
            math.ceil(float(np.linalg.norm(shift)) / EASE_M_S * fps),
        )
        for j in range(1, frames + 1):
            t = end + step * j
            if not 0 <= t < len(track) or fixed[t]:
                break
            w = 1.0 - j / (frames + 1)
            at = se3.transform_points(track[t], centre[None])[0] + w * shift
            rot = Rotation.from_rotvec(w * turn).as_matrix() @ track[t][:3, :3]
            track[t] = se3.make_pose(rot, at - rot @ centre)


def _in_runs(runs: list[tuple[int, int]], n: int) -> np.ndarray:
    out = np.zeros(n, bool)
    for first, last in runs:
        out[first : last + 1] = True
    return out


def _upright(pose: np.ndarray, resting: np.ndarray | None, vertices: np.ndarray, *, may_turn: bool) -> np.ndarray:
    """``pose`` levelled onto the face it rested on at frame 0 (``level``, with ``resting``);
    set down farther from it and ``may_turn``, first turned onto the face of its hull nearest down
    (``stable_down``): at rest on a support, an object stands on a face it can stand on."""
    if resting is not None:
        levelled = level(pose, resting, vertices)
        if levelled is not pose or not may_turn:
            return levelled
    elif not may_turn:
        return pose
    turned = _turned(pose, stable_down(vertices, pose), vertices)
    return turned if resting is None else level(turned, resting, vertices)


def level(pose: np.ndarray, resting: np.ndarray, vertices: np.ndarray) -> np.ndarray:
    """``pose`` turned about its vertices' centre so that the object's up (at the ``resting``
    pose) is up again, where it is within ``LEVEL_DEG`` of it: set down on the face it stood on, a
    tracked tilt of a few degrees is error (lift-can-lying-s302's can, set down 8.3 deg off level
    and 1.6 mm low, moved 15.7 mm in the gate's rest check; levelled and rested, 1.7 mm); farther,
    it was set down on another face, and the pose stays."""
    up = resting[:3, :3].T @ np.array([0.0, 0.0, 1.0])  # the object's up, in its own frame
    now = pose[:3, :3] @ up
    if np.degrees(np.arccos(np.clip(now[2], -1.0, 1.0))) > LEVEL_DEG:
        return pose
    return _turned(pose, se3.rotation_between(now, np.array([0.0, 0.0, 1.0])), vertices)


def _turned(pose: np.ndarray, turn: np.ndarray, vertices: np.ndarray) -> np.ndarray:
    """``pose`` turned by ``turn`` (3, 3, world) about the centre of its ``vertices`` (object frame)."""
    centre = se3.transform_points(pose, vertices).mean(axis=0)
    return se3.make_pose(turn, centre - turn @ centre) @ pose


def stable_down(vertices: np.ndarray, world_from_object: np.ndarray, faces: np.ndarray | None = None) -> np.ndarray:
    """The rotation (3, 3, world) that turns the posed object onto the face it can stand on that
    faces most nearly down: a face of its convex hull (coplanar triangles one face) on which its
    center of mass (of the mesh with ``faces``, else of the hull) stands at least ``MIN_TIP_DEG``
    inside the face's edges (``standing_faces``), or the steadiest face where none does. A round
    object's small facets hold it by a degree or two: Newton rolls it off them."""
    world = se3.transform_points(world_from_object, vertices)
    com = trimesh.Trimesh(world, faces, process=False).center_mass if faces is not None else None
    normals, tip_deg = standing_faces(world, com)
    ok = tip_deg >= min(MIN_TIP_DEG, float(tip_deg.max()))
    i = int(np.argmin(np.where(ok, normals[:, 2], np.inf)))
    return se3.turn_down(normals[i], tiny=1e-9)


def standing_faces(points: np.ndarray, com: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The faces of the convex hull of ``points`` (coplanar triangles merged): their outward unit
    normals (F, 3) and how far the center of mass ``com`` (default the hull's) stands inside each,
    as the tilt [deg] that would tip it over the nearest edge (negative: it falls off that face)."""
    hull = trimesh.convex.convex_hull(points)
    com = hull.center_mass if com is None else np.asarray(com, float)
    groups = [np.asarray(g) for g in hull.facets]
    merged = np.zeros(len(hull.faces), bool)
    for g in groups:
        merged[g] = True
    groups += [np.array([i]) for i in np.flatnonzero(~merged)]
    normals = np.array([hull.face_normals[g[0]] for g in groups])
    tips = np.empty(len(groups))
    for k, g in enumerate(groups):
        tri = hull.triangles[g]
        height = float(np.dot(com - tri[0, 0], -normals[k]))
        foot = com + height * normals[k]
        inside = np.any(
            np.all(trimesh.triangles.points_to_barycentric(tri, np.repeat(foot[None], len(g), 0)) >= -1e-9, axis=1)
        )
        edges = np.sort(hull.faces[g][:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
        unique, count = np.unique(edges, axis=0, return_counts=True)
        a, b = hull.vertices[unique[count == 1, 0]], hull.vertices[unique[count == 1, 1]]
        ab = b - a
        along = np.clip(np.einsum("ij,ij->i", foot - a, ab) / np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-18), 0, 1)
        margin = float(np.linalg.norm(a + along[:, None] * ab - foot, axis=1).min())
        tips[k] = np.degrees(np.arctan2(margin if inside else -margin, max(height, 1e-9)))
    return normals, tips


def _collider_points(stage: Usd.Stage, name: str, mesh) -> np.ndarray:
    """The vertices of the collider Newton makes of object ``name`` (object frame): its mesh's for a
    convex hull, CoACD's parts' for a decomposition."""
    if collision_approximation(stage, name) == "convexDecomposition":
        return np.concatenate(coacd_parts(mesh))
    return np.asarray(mesh.vertices, float)
