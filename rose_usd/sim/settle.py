"""Resting objects on what supports them: a reconstructed object at its frame-0 pose may sit a few
millimeters inside the scene's collider (the wrap's offset, the support plane's error), and a
simulator then ejects it; or a few millimeters above it (the support measured around its mask
higher than the wrapped surface under it: up to 7 mm with MegaSaM depth), and it then falls and
rocks. Each object is moved straight along gravity until it touches the scene or the objects
already settled under it, lowest objects first. What touches is its collider as the simulator
makes it where that is given: CoACD's convex parts bulge up to a millimetre past the mesh, and a
part 0.4 mm inside the table kicked a resting mug 4 mm in Newton (0.7 mm: 21 mm and 6 deg)."""

from __future__ import annotations

import numpy as np

from rose_usd.core import metrics, se3

CLEARANCE_M = 0.0005
"""Left between an object and its support after lifting [m]."""
TOUCHING_M = 0.001
"""A gap up to this is contact: left alone [m]."""
SUNK_M = 0.0002
"""Penetration up to this is contact; deeper is lifted out [m] (Newton, a mug's convex parts
0.1 / 0.4 / 0.7 mm inside the table: moved 0.2 / 3.6 / 21 mm in 0.3 s)."""


def settle(
    models: list,
    scene: tuple[np.ndarray, np.ndarray] | None,
    *,
    max_lift_m: float = 0.03,
    max_drop_m: float = 0.015,
    max_push_m: float = 0.015,
    pushes: dict[str, np.ndarray] | None = None,
    collider_points: dict[str, np.ndarray] | None = None,
    under: list[tuple[np.ndarray, np.ndarray]] = (),
) -> dict[str, float]:
    """Move each model's ``world_from_object_0`` along gravity into contact; returns the move per
    object [m] (positive up).

    Objects are settled from the lowest up, each against the scene and the objects settled before
    it. A penetration deeper than ``max_lift_m``, or a gap wider than ``max_drop_m`` (an object
    held, not resting), is left alone (it is not a contact error but a wrong pose or scene, or no
    contact at all; moving it would hide that): the caller warns about the first. A gap under
    ``TOUCHING_M`` or a penetration under ``SUNK_M`` is contact.

    First, where the object sinks into something beside it (the scene holds a cup the ball rests
    against), it is moved out sideways, by up to ``max_push_m``: lifted over it instead, it fell
    back against its slope and rolled away in Newton. ``pushes`` receives each sideways move.

    ``collider_points`` (object frame, per object) are its collider's vertices (``object.author.
    collider_of``): they are tested for contact with the mesh's. ``under`` (world vertices, faces)
    are closed meshes that support the models as the scene does and do not move (objects that
    are not settled here)."""
    pushes = {} if pushes is None else pushes
    lifts: dict[str, float] = {}
    supports = ([] if scene is None else [metrics.SignedDistance(*scene)]) + [
        metrics.SignedDistance(v, f) for v, f in under
    ]
    order = sorted(
        models, key=lambda m: float(se3.transform_points(m.world_from_object_0, m.mesh.vertices)[:, 2].min())
    )
    for model in order:
        world = se3.transform_points(model.world_from_object_0, model.mesh.vertices)
        side = _sideways(world, supports, max_push_m)
        model.world_from_object_0[:3, 3] += side
        world = world + side
        pushes[model.name] = side
        extra = (collider_points or {}).get(model.name)
        probe = world if extra is None else np.vstack([world, se3.transform_points(model.world_from_object_0, extra)])
        depth = 0.0
        for signed_distance in supports:
            inside = signed_distance(probe)
            depth = max(depth, float(-inside.min()) if inside.min() < 0 else 0.0)
        lift = depth + CLEARANCE_M if depth > SUNK_M else 0.0
        if lift > max_lift_m:
            lifts[model.name] = float("nan")
            continue
        if depth == 0.0 and supports:  # not touching: lowered onto what is under it
            gap = min(float(np.min(support.drop(probe))) for support in supports)
            lowered = probe - np.array([0.0, 0.0, gap - CLEARANCE_M])
            if TOUCHING_M < gap <= max_drop_m and all(
                float(np.min(support(lowered))) >= -TOUCHING_M for support in supports
            ):
                lift = -(gap - CLEARANCE_M)  # (a vertex-only test: lowering must not sink it)
        model.world_from_object_0[2, 3] += lift
        lifts[model.name] = lift
        supports.append(metrics.SignedDistance(world + np.array([0.0, 0.0, lift]), model.mesh.faces))
    return lifts


def _sideways(world: np.ndarray, supports: list, max_push_m: float) -> np.ndarray:
    """The horizontal move (3,) that takes the points out of what they sink into from the side:
    among the points deeper than ``TOUCHING_M`` inside a support, those whose way out (to the
    nearest surface point) is within 30 deg of horizontal; moved along their mean horizontal way
    out, by the deepest of them along it plus the clearance. Zero when there are none, or when
    the move would exceed ``max_push_m`` (not a contact error: a wrong pose)."""
    best = np.zeros(3)
    for support in supports:
        inside = support(world)
        deep = inside < -TOUCHING_M
        if not deep.any():
            continue
        pts = world[deep]
        closest = support.scene.compute_closest_points(
            support._o3d.core.Tensor(np.ascontiguousarray(pts, dtype=np.float32))
        )["points"].numpy()
        out = closest - pts
        length = np.linalg.norm(out, axis=1)
        side = (length > 0) & (np.abs(out[:, 2]) < 0.5 * np.maximum(length, 1e-12))
        if not side.any():
            continue
        way = out[side, :2].sum(axis=0)
        if np.linalg.norm(way) < 1e-9:
            continue
        way /= np.linalg.norm(way)
        push = float(np.max(out[side, :2] @ way)) + CLEARANCE_M
        if push > max_push_m or push <= np.linalg.norm(best):
            continue
        best = np.array([*(push * way), 0.0])
    return best
