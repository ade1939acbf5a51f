"""The trajectory layer: time samples of each object's pose and their confidence."""

from __future__ import annotations

import numpy as np
from pxr import Usd, UsdGeom

from rose_usd.errors import StageError
from rose_usd.usd import paths, tokens


def object_poses(stage: Usd.Stage, name: str, n_frames: int) -> np.ndarray:
    """Object ``name``'s world poses (n_frames, 4, 4) at time codes 0..n_frames-1."""
    prim = stage.GetPrimAtPath(paths.object_path(name))
    if not prim:
        raise StageError(
            f"object {name!r} has no prim in the stage",
            path=stage.GetRootLayer().identifier,
            hint="run the object stage",
        )
    xf = UsdGeom.Xformable(prim)
    return np.array([np.array(xf.ComputeLocalToWorldTransform(Usd.TimeCode(t))).T for t in range(n_frames)])


def confidence(stage: Usd.Stage, name: str, n_frames: int) -> np.ndarray | None:
    """Per-frame confidence of object ``name``'s pose (0 lost, 0.5 interpolated, up to 1), None
    before the trajectory stage has run."""
    attr = stage.GetPrimAtPath(paths.object_path(name)).GetAttribute(tokens.TRAJECTORY_CONFIDENCE)
    if not attr or not attr.HasAuthoredValue():
        return None
    return np.array([float(attr.Get(Usd.TimeCode(t))) for t in range(n_frames)])
