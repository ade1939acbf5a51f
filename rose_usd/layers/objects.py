"""The object layer (``/World/Objects/<Name>``): the rigid bodies, their visual meshes and their
default (frame-0) poses, for the stages after it."""

from __future__ import annotations

import numpy as np
from pxr import Usd, UsdGeom, UsdPhysics

from rose_usd.errors import StageError
from rose_usd.usd import paths
from rose_usd.usd.geom import MeshData, read_mesh


def object_paths(stage: Usd.Stage) -> dict[str, str]:
    """Object name -> prim path, for every rigid body under /World/Objects."""
    objects = stage.GetPrimAtPath(paths.OBJECTS)
    if not objects:
        return {}
    return {
        child.GetName(): str(child.GetPath())
        for child in objects.GetChildren()
        if child.HasAPI(UsdPhysics.RigidBodyAPI)
    }


def _prim(stage: Usd.Stage, path, name: str) -> Usd.Prim:
    prim = stage.GetPrimAtPath(path)
    if not prim:
        raise StageError(
            f"object {name!r} has no prim at {path} in the stage",
            path=stage.GetRootLayer().identifier,
            hint="run the object stage first (rose-usd run object ...)",
        )
    return prim


def visual_mesh(stage: Usd.Stage, name: str) -> MeshData:
    """Object ``name``'s visual mesh in world coordinates at its default (frame-0) pose."""
    return read_mesh(_prim(stage, paths.object_visual(name), name))


def default_pose(stage: Usd.Stage, name: str) -> np.ndarray:
    """Object ``name``'s default world pose (4, 4): where the object stage put it at frame 0."""
    xform = UsdGeom.Xformable(_prim(stage, paths.object_path(name), name))
    return np.asarray(xform.ComputeLocalToWorldTransform(Usd.TimeCode.Default()), dtype=float).T
