"""The object layer (``/World/Objects/<Name>``): the rigid bodies, their visual meshes and their
default (frame-0) poses, for the stages after it."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pxr import Usd, UsdGeom, UsdPhysics

from rose_usd.core import se3
from rose_usd.errors import StageError
from rose_usd.usd import paths, tokens
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


def is_proxy(stage: Usd.Stage, name: str) -> bool:
    """Whether object ``name``'s shape stands in for it (a category primitive, ``RoseShapeAPI``)."""
    attr = _prim(stage, paths.object_path(name), name).GetAttribute(tokens.SHAPE_PROXY)
    return bool(attr and attr.HasAuthoredValue() and attr.Get())


def default_pose(stage: Usd.Stage, name: str) -> np.ndarray:
    """Object ``name``'s default world pose (4, 4): where the object stage put it at frame 0."""
    xform = UsdGeom.Xformable(_prim(stage, paths.object_path(name), name))
    return np.asarray(xform.ComputeLocalToWorldTransform(Usd.TimeCode.Default()), dtype=float).T


def collision_approximation(stage: Usd.Stage, name: str) -> str | None:
    """How object ``name`` collides (its ``Collision`` child's MeshCollisionAPI approximation,
    e.g. ``convexHull``), None when it has no collision mesh."""
    prim = stage.GetPrimAtPath(paths.object_collision(name))
    if not prim or not prim.HasAPI(UsdPhysics.CollisionAPI):
        return None
    if prim.HasAPI(UsdPhysics.MeshCollisionAPI):
        return str(UsdPhysics.MeshCollisionAPI(prim).GetApproximationAttr().Get())
    return "none"


@dataclass(frozen=True)
class PhysicsPrior:
    """An object's mass and friction with their one-sigma uncertainty (``RosePhysicsPriorAPI``)."""

    mass_kg: float
    mass_sigma_kg: float
    friction: float
    friction_sigma: float
    center_of_mass_m: np.ndarray
    """(3,) in the object's frame."""


def physics_prior(stage: Usd.Stage, name: str) -> PhysicsPrior:
    """Object ``name``'s mass (MassAPI), centre of mass and friction prior with uncertainties;
    uncertainties are 0 where the object stage recorded none."""
    prim = _prim(stage, paths.object_path(name), name)
    mass = UsdPhysics.MassAPI(prim)

    def value(attr, default):
        got = attr.Get() if attr and attr.HasAuthoredValue() else None
        return default if got is None else got

    def prior(token, default):
        return float(value(prim.GetAttribute(token), default))

    return PhysicsPrior(
        mass_kg=float(value(mass.GetMassAttr(), 0.0)),
        mass_sigma_kg=prior(tokens.PRIOR_MASS_UNCERTAINTY, 0.0),
        friction=prior(tokens.PRIOR_FRICTION, 0.5),
        friction_sigma=prior(tokens.PRIOR_FRICTION_UNCERTAINTY, 0.0),
        center_of_mass_m=np.asarray(value(mass.GetCenterOfMassAttr(), (0.0, 0.0, 0.0)), dtype=float),
    )


def describe(stage: Usd.Stage, name: str) -> str:
    """One phrase for a person: object ``name``'s shape (its mesh, or the category primitive that
    stands in for it), its sides in its own frame and its mass: "Cube (mesh) 8.5 x 8.5 x 8.5 cm, 0.58 kg"."""
    prim = _prim(stage, paths.object_path(name), name)
    local = se3.transform_points(se3.invert(default_pose(stage, name)), visual_mesh(stage, name).vertices)
    sides = " x ".join(f"{100 * d:.1f}" for d in sorted(np.ptp(local, axis=0), reverse=True))
    shape = "mesh"
    if is_proxy(stage, name):
        kind = prim.GetAttribute(tokens.SHAPE_PRIMITIVE)
        shape = f"a {kind.Get() if kind and kind.HasAuthoredValue() else 'primitive'} standing in for it"
    return f"{name} ({shape}) {sides} cm, {physics_prior(stage, name).mass_kg:.3g} kg"
