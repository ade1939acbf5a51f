"""The scene layer (``/World/Scene``): its static collider and the support pads laid in it."""

from __future__ import annotations

import numpy as np
from pxr import Usd

from rose_usd.usd import paths, schema, tokens
from rose_usd.usd.geom import read_mesh


def scene_collider(stage: Usd.Stage) -> tuple[np.ndarray, np.ndarray] | None:
    """The scene's collider in world coordinates (vertices, faces), None when there is none."""
    prim = stage.GetPrimAtPath(paths.SCENE_COLLISION)
    if not prim:
        return None
    mesh = read_mesh(prim, world=True)
    return mesh.vertices, mesh.faces


def support_heights(stage: Usd.Stage) -> dict[str, float]:
    """Object name -> the height [m] of the flat pad the scene laid under it while it rests
    (``RoseSupportAPI``); empty when the scene laid none."""
    prim = stage.GetPrimAtPath(paths.SCENE_COLLISION)
    if not prim or not prim.HasAPI(schema.SUPPORT_API):
        return {}
    names = list(prim.GetAttribute(tokens.SUPPORT_OBJECTS).Get() or [])
    heights = list(prim.GetAttribute(tokens.SUPPORT_HEIGHTS).Get() or [])
    return {str(n): float(h) for n, h in zip(names, heights, strict=True)}
