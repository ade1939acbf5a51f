"""Resting objects on what supports them: a reconstructed object at its frame-0 pose may sit a few
millimeters inside the scene's collider (the wrap's offset, the support plane's error), and a
simulator then ejects it. Each object is lifted straight up (against gravity) until it no longer
penetrates the scene or the objects already settled under it, lowest objects first."""

from __future__ import annotations

import numpy as np

from rose_usd.core import metrics, se3
from rose_usd.usd import paths
from rose_usd.usd.geom import read_mesh

CLEARANCE_M = 0.0005
"""Left between an object and its support after lifting [m]."""
TOUCHING_M = 0.001
"""Penetration up to this is contact, not an error: left alone [m]."""


def scene_collider(stage) -> tuple[np.ndarray, np.ndarray] | None:
    """The scene layer's collider (world), or None when there is none."""
    prim = stage.GetPrimAtPath(paths.SCENE_COLLISION)
    if not prim:
        return None
    mesh = read_mesh(prim, world=True)
    return mesh.vertices, mesh.faces


def settle(models: list, scene: tuple[np.ndarray, np.ndarray] | None, *, max_lift_m: float = 0.03) -> dict[str, float]:
    """Lift each model's ``world_from_object_0`` out of penetration; returns the lift per object [m].

    Objects are settled from the lowest up, each against the scene and the objects settled before
    it. A penetration deeper than ``max_lift_m`` is left alone (it is not a contact error but a
    wrong pose or scene, and lifting would hide it): the caller warns."""
    lifts: dict[str, float] = {}
    supports = [] if scene is None else [metrics.SignedDistance(*scene)]
    order = sorted(models, key=lambda m: float(se3.transform_points(m.world_from_object_0, m.mesh.vertices)[:, 2].min()))
    for model in order:
        world = se3.transform_points(model.world_from_object_0, model.mesh.vertices)
        depth = 0.0
        for signed_distance in supports:
            inside = signed_distance(world)
            depth = max(depth, float(-inside.min()) if inside.min() < 0 else 0.0)
        lift = depth + CLEARANCE_M if depth > TOUCHING_M else 0.0
        if lift > max_lift_m:
            lifts[model.name] = float("nan")
            continue
        model.world_from_object_0[2, 3] += lift
        lifts[model.name] = lift
        supports.append(metrics.SignedDistance(world + np.array([0.0, 0.0, lift]), model.mesh.faces))
    return lifts
