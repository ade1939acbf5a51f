"""The physical check: load the stage in Newton as it is, let it run, see whether objects that
should rest stay put. Static triangle meshes take part only near the objects (``NEAR_M``)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pxr import Gf, Usd, UsdGeom

from rose_usd.core import se3
from rose_usd.errors import ValidationError
from rose_usd.progress import progress
from rose_usd.sim.resting import box_corners


@dataclass(frozen=True)
class RestResult:
    name: str
    max_displacement_m: float
    """Largest displacement of any corner of the object's bounding box from frame 0 [m]."""
    max_rotation_deg: float
    final_displacement_m: float
    simulated_s: float
    """How long was simulated: ``duration_s``, or less where every object had settled or crept
    steadily (``SETTLE_*``, ``CREEP_*``)."""


RIGID_CONTACT_MAX = 16384
"""Contacts the rest simulation has room for (objects of a few dozen convex parts on a scene mesh)."""

NEAR_M = 0.05
"""Static triangle meshes (the scene's collider) are simulated only where a triangle's bounds come
within this of an object's bounds. An object that stays within the rest threshold (5 mm) never
touches the triangles left out, so the verdict and any displacement under this are the full
scene's; one that moves farther fails either way, its displacement then not the full scene's."""


CONTACT_GAP_M = 0.01
"""How far apart two shapes may be for Newton to list their contact (its default: 10 cm). An
object at rest moves far less than this in a step (1/600 s); listing every convex part within
10 cm of every triangle near it takes three times as long for the same result."""

SETTLE_AFTER_S = 0.25
SETTLE_WINDOW_S = 0.1
SETTLE_TOL_M = 2e-5
CREEP_TOL_M = 1e-4
CREEP_GROWTH = 1.1
CREEP_BUDGET_M = 1e-3
"""The simulation stops before ``duration_s`` once ``SETTLE_AFTER_S`` have passed and every
object has settled or creeps steadily (``_settled``): no corner of its box moved ``SETTLE_TOL_M``
in the last ``SETTLE_WINDOW_S``, or it moved under ``CREEP_TOL_M`` and no more than
``CREEP_GROWTH`` times what it moved in the window before, so that the rest of ``duration_s`` at
that growth would add under ``CREEP_BUDGET_M`` (a fifth of the gate's default 5 mm threshold).
XPBD lets a mug of 89 convex parts on the table's triangles slide a steady 0.077 mm every 0.1 s
(10 iterations; 0.04 mm at the gate's 30) from start to end: 0.58 mm more over the rest of a 1 s
check. An object that starts to tip or slide speeds up: what it moves in a window grows by far
more than ``CREEP_GROWTH`` (an inverted pendulum: 2.8 times a window for a 10 cm cube, 1.4 for a
1 m one; sliding from rest down a slope, over 1.1 times for more than 1 s). Measured on the
sample's box (its oracle stage): tipped onto an edge 0.05-0.2 deg short of balance it stays there
in XPBD (0.01-0.09 mm over the whole second, 0.003-0.02 mm when stopped at 0.25 s); 0.5 deg short
it falls back onto its face (12 cm) either way. Nearly all of a step's time is Warp's launch
overhead (134 launches a step on the CPU), so steps saved are time saved."""

ASIDE_M = 1000.0
"""How far below the world objects set aside start (``simulate_rest``'s ``aside``) [m]."""


def _settled(history: list[dict[str, np.ndarray]], window: int, remaining_windows: float) -> bool:
    """Whether every object's corners have come to rest or to a steady creep (``SETTLE_TOL_M``,
    ``CREEP_*``) over the last ``window`` checks of ``history``, with ``remaining_windows``
    windows of the simulation left."""
    if len(history) <= 2 * window:
        return False
    ahead = sum(CREEP_GROWTH**i for i in range(1, int(np.ceil(max(remaining_windows, 0.0))) + 1))
    now, then, before = history[-1], history[-1 - window], history[-1 - 2 * window]
    for n in now:
        moved = float(np.linalg.norm(now[n] - then[n], axis=1).max())
        if moved < SETTLE_TOL_M:
            continue
        earlier = float(np.linalg.norm(then[n] - before[n], axis=1).max())
        if moved >= CREEP_TOL_M or moved > CREEP_GROWTH * earlier or moved * ahead > CREEP_BUDGET_M:
            return False
    return True


def _load(newton, stage: Usd.Stage, object_paths: dict[str, str], poses: dict[str, np.ndarray], aside: dict[str, str]):
    """The stage as a Newton model, and the body index of each object's rigid-body prim (the
    objects of ``object_paths`` and ``aside``). Bodies start at their default poses, or at
    ``poses`` (name -> world pose) where given; those of ``aside`` start ``ASIDE_M`` below."""
    import warp as wp

    builder = newton.ModelBuilder()
    builder.rigid_gap = CONTACT_GAP_M
    result = builder.add_usd(stage)
    body_of = dict(result.get("path_body_map", {}))
    missing = [name for name, path in {**object_paths, **aside}.items() if path not in body_of]
    if missing:
        raise ValidationError(
            f"Newton built no body for object(s) {missing}",
            path=stage.GetRootLayer().identifier,
            hint="check RigidBodyAPI on the object prims",
        )
    start = dict(poses)
    for name, path in aside.items():
        start[name] = default_pose_of(stage, path)
        start[name][2, 3] -= ASIDE_M
    for name, pose in start.items():
        path = {**object_paths, **aside}[name]
        builder.body_q[body_of[path]] = wp.transform(
            wp.vec3(*pose[:3, 3]), wp.quat(*se3.quat_xyzw_from_matrix(pose[:3, :3]))
        )
    _keep_near(newton, builder, _objects_bounds(stage, object_paths, poses), NEAR_M)
    return builder.finalize(device=wp.get_preferred_device()), body_of


def _bbox_cache() -> UsdGeom.BBoxCache:
    """Bounds at the default time over every purpose an object's meshes use (collision: guide)."""
    return UsdGeom.BBoxCache(
        Usd.TimeCode.Default(), [UsdGeom.Tokens.default_, UsdGeom.Tokens.render, UsdGeom.Tokens.guide]
    )


def default_pose_of(stage: Usd.Stage, path: str) -> np.ndarray:
    """The world pose (4, 4) of the prim at ``path`` at the default time."""
    xform = UsdGeom.Xformable(stage.GetPrimAtPath(path))
    return np.asarray(xform.ComputeLocalToWorldTransform(Usd.TimeCode.Default()), dtype=float).T


def _objects_bounds(
    stage: Usd.Stage, object_paths: dict[str, str], poses: dict[str, np.ndarray]
) -> tuple[np.ndarray, np.ndarray]:
    """The world bounds (lo, hi) of all the objects together, each at its pose of ``poses`` or
    else its default pose."""
    corners = body_corners(stage, object_paths)
    world = [
        se3.transform_points(poses[name] if name in poses else default_pose_of(stage, path), corners[name])
        for name, path in object_paths.items()
    ]
    every = np.vstack(world)
    return every.min(axis=0), every.max(axis=0)


def _keep_near(newton, builder, bounds: tuple[np.ndarray, np.ndarray], near_m: float) -> None:
    """Cut every static colliding triangle mesh of ``builder`` down to the triangles whose bounds
    come within ``near_m`` of ``bounds``; one with none stops colliding."""
    import warp as wp

    lo, hi = bounds[0] - near_m, bounds[1] + near_m
    collides = int(newton.ShapeFlags.COLLIDE_SHAPES)
    for i in range(builder.shape_count):
        if builder.shape_body[i] != -1 or builder.shape_type[i] != newton.GeoType.MESH:
            continue
        if not builder.shape_flags[i] & collides:
            continue
        mesh = builder.shape_source[i]
        tf = builder.shape_transform[i]
        world_from_shape = se3.make_pose(np.asarray(wp.quat_to_matrix(tf.q), dtype=float).reshape(3, 3), tf.p)
        world = se3.transform_points(
            world_from_shape, np.asarray(mesh.vertices, float) * np.asarray(builder.shape_scale[i], float)
        )
        tris = np.asarray(mesh.indices, dtype=np.int64).reshape(-1, 3)
        corners = world[tris]
        keep = np.all(corners.max(axis=1) >= lo, axis=1) & np.all(corners.min(axis=1) <= hi, axis=1)
        if keep.all():
            continue
        if not keep.any():
            builder.shape_flags[i] &= ~collides
            continue
        used, inverse = np.unique(tris[keep], return_inverse=True)
        builder.shape_source[i] = newton.Mesh(
            np.asarray(mesh.vertices)[used],
            inverse.reshape(-1).astype(np.int32),
            compute_inertia=False,
            is_solid=mesh.is_solid,
        )


def body_corners(stage: Usd.Stage, object_paths: dict[str, str]) -> dict[str, np.ndarray]:
    """Each object's bounding-box corners in its body frame (the prim frame: Newton bodies are the
    rigid-body prims): the union of its children's bounds relative to it. The prim's own
    untransformed bound is not that: USD takes it as the box of its bound in its parent's frame,
    turned back, whose aligned range is then a square's hull (a box turned 137 deg about up:
    +-8.4 cm for its +-4.4 by 4.1)."""
    corners, bbox = {}, _bbox_cache()
    for name, path in object_paths.items():
        prim = stage.GetPrimAtPath(path)
        box = Gf.Range3d()
        for child in prim.GetChildren():
            box.UnionWith(bbox.ComputeRelativeBound(child, prim).ComputeAlignedRange())
        extent = UsdGeom.Boundable(prim).GetExtentAttr().Get() if prim.IsA(UsdGeom.Boundable) else None
        if extent is not None:  # a body that is itself a mesh: its own extent too
            box.UnionWith(Gf.Range3d(Gf.Vec3d(*extent[0]), Gf.Vec3d(*extent[1])))
        if box.IsEmpty():
            box = Gf.Range3d(Gf.Vec3d(0, 0, 0), Gf.Vec3d(0, 0, 0))  # its origin alone
        corners[name] = box_corners(np.asarray(box.GetMin()), np.asarray(box.GetMax()))
    return corners


def _body_poses(state, body_of: dict[str, int], object_paths: dict[str, str]) -> dict[str, np.ndarray]:
    """Each object's world pose in a Newton state."""
    q = state.body_q.numpy()
    out = {}
    for name, path in object_paths.items():
        p, quat_xyzw = q[body_of[path], :3], q[body_of[path], 3:]
        out[name] = se3.make_pose(se3.matrix_from_quat_xyzw(quat_xyzw), p)
    return out


def simulate_rest(
    stage: Usd.Stage,
    object_paths: dict[str, str],
    *,
    duration_s: float = 1.0,
    dt_s: float = 1.0 / 600.0,
    iterations: int = 10,
    poses: dict[str, np.ndarray] | None = None,
    aside: dict[str, str] | None = None,
) -> list[RestResult]:
    """Simulate ``duration_s`` with Newton's XPBD solver (or until every object has settled:
    ``SETTLE_AFTER_S``) from the stage's default (frame-0) state, or with objects at other
    ``poses``; each object's displacement from where it started.

    Args:
        object_paths: object name -> prim path of its rigid body: the objects measured.
        poses: object name -> its world pose at the start (default: its default pose).
        aside: object name -> prim path of objects not to take part (held at the frame checked):
            they start ``ASIDE_M`` below the world, away from everything.
    """
    from rose_usd.sim.engine import newton as load_newton

    newton = load_newton()
    model, body_of = _load(newton, stage, object_paths, poses or {}, aside or {})
    solver = newton.solvers.SolverXPBD(model, iterations=iterations)
    state_0, state_1 = model.state(), model.state()
    control = model.control()
    # room for every contact: Newton's estimate (1000 here) overflows on stacks of convex parts
    # (they can make nearly twice that) and drops the rest, with a warning per step
    pipeline = newton.CollisionPipeline(model, rigid_contact_max=RIGID_CONTACT_MAX)
    contacts = pipeline.contacts()
    corners = body_corners(stage, object_paths)
    start = _body_poses(state_0, body_of, object_paths)
    start_pts = {n: se3.transform_points(start[n], corners[n]) for n in object_paths}
    max_disp = {n: 0.0 for n in object_paths}
    max_rot = {n: 0.0 for n in object_paths}
    steps = int(round(duration_s / dt_s))
    check_every = max(1, steps // 100)
    window = max(1, int(round(SETTLE_WINDOW_S / (dt_s * check_every))))
    history: list[dict[str, np.ndarray]] = []
    simulated = steps
    for step in progress(range(steps), "newton", total=steps, unit="step"):
        pipeline.collide(state_0, contacts)
        solver.step(state_0, state_1, control, contacts, dt_s)
        state_0, state_1 = state_1, state_0
        if step % check_every == 0 or step == steps - 1:
            now = _body_poses(state_0, body_of, object_paths)
            pts = {n: se3.transform_points(now[n], corners[n]) for n in object_paths}
            for n in object_paths:
                max_disp[n] = max(max_disp[n], float(np.linalg.norm(pts[n] - start_pts[n], axis=1).max()))
                rot = float(se3.rotation_angle_deg(start[n][:3, :3].T @ now[n][:3, :3]))
                max_rot[n] = max(max_rot[n], rot)
            history.append(pts)
            left = (steps - step - 1) * dt_s / SETTLE_WINDOW_S
            if (step + 1) * dt_s >= SETTLE_AFTER_S and _settled(history, window, left):
                simulated = step + 1
                break
    final = _body_poses(state_0, body_of, object_paths)
    return [
        RestResult(
            name=n,
            max_displacement_m=max_disp[n],
            max_rotation_deg=max_rot[n],
            final_displacement_m=float(
                np.linalg.norm(se3.transform_points(final[n], corners[n]) - start_pts[n], axis=1).max()
            ),
            simulated_s=round(simulated * dt_s, 4),
        )
        for n in object_paths
    ]
