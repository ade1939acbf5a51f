"""Physics authoring the way Newton's USD importer reads it (formats.md).

- gravity from the first PhysicsScene; rigid bodies without joints get a free joint;
- authored MassAPI values win; ``dynamicFriction`` is the friction Newton uses, so static and
  dynamic friction are authored equal;
- colliders are separate ``guide`` meshes, so approximating them never duplicates the visual.
"""

from __future__ import annotations

import enum

import numpy as np
from pxr import Gf, Sdf, Usd, UsdGeom, UsdPhysics, UsdShade

from rose_usd.usd.geom import bind_material

GRAVITY_M_S2 = 9.81


class Approximation(enum.Enum):
    """UsdPhysics.MeshCollisionAPI approximations Newton understands."""

    NONE = "none"  # the triangle mesh itself (static colliders)
    CONVEX_HULL = "convexHull"
    CONVEX_DECOMPOSITION = "convexDecomposition"


def author_physics_scene(stage: Usd.Stage, path: Sdf.Path) -> UsdPhysics.Scene:
    """A PhysicsScene with gravity along -Z (the world's down) of 9.81 m/s^2."""
    scene = UsdPhysics.Scene.Define(stage, path)
    scene.CreateGravityDirectionAttr(Gf.Vec3f(0.0, 0.0, -1.0))
    scene.CreateGravityMagnitudeAttr(GRAVITY_M_S2)
    return scene


def make_collider(prim: Usd.Prim, approximation: Approximation) -> None:
    """Make a mesh prim a collider with the given approximation."""
    UsdPhysics.CollisionAPI.Apply(prim).CreateCollisionEnabledAttr(True)
    UsdPhysics.MeshCollisionAPI.Apply(prim).CreateApproximationAttr(approximation.value)


def make_rigid_body(
    prim: Usd.Prim,
    *,
    mass_kg: float,
    center_of_mass_m: np.ndarray,
    diagonal_inertia: np.ndarray,
    principal_axes_wxyz: np.ndarray,
) -> None:
    """Apply RigidBodyAPI and MassAPI with all mass properties authored (in the body frame)."""
    UsdPhysics.RigidBodyAPI.Apply(prim).CreateRigidBodyEnabledAttr(True)
    mass = UsdPhysics.MassAPI.Apply(prim)
    mass.CreateMassAttr(float(mass_kg))
    mass.CreateCenterOfMassAttr(Gf.Vec3f(*np.asarray(center_of_mass_m, dtype=float).tolist()))
    mass.CreateDiagonalInertiaAttr(Gf.Vec3f(*np.asarray(diagonal_inertia, dtype=float).tolist()))
    w, x, y, z = (float(v) for v in principal_axes_wxyz)
    mass.CreatePrincipalAxesAttr(Gf.Quatf(w, Gf.Vec3f(x, y, z)))


def author_physics_material(
    stage: Usd.Stage, path: Sdf.Path, *, friction: float, restitution: float, density: float | None = None
) -> UsdShade.Material:
    """A physics material; static friction = dynamic friction (Newton reads only the latter)."""
    material = UsdShade.Material.Define(stage, path)
    api = UsdPhysics.MaterialAPI.Apply(material.GetPrim())
    api.CreateStaticFrictionAttr(float(friction))
    api.CreateDynamicFrictionAttr(float(friction))
    api.CreateRestitutionAttr(float(restitution))
    if density is not None:
        api.CreateDensityAttr(float(density))
    return material


def bind_physics_material(prim: Usd.Prim, material: UsdShade.Material) -> None:
    bind_material(prim, material, purpose="physics")


def set_pose_ops(xformable: UsdGeom.Xformable, pose: np.ndarray, time: Usd.TimeCode = Usd.TimeCode.Default()) -> None:
    """Set a prim's translate + orient ops (double precision) from a 4x4 pose, creating them if needed.

    The ops are the object pose contract: defined once by the object stage (default = frame 0),
    time-sampled by the trajectory stage.
    """
    from rose_usd.core import se3

    ops = {op.GetOpName(): op for op in xformable.GetOrderedXformOps()}
    translate = ops.get("xformOp:translate") or xformable.AddTranslateOp(UsdGeom.XformOp.PrecisionDouble)
    orient = ops.get("xformOp:orient") or xformable.AddOrientOp(UsdGeom.XformOp.PrecisionDouble)
    w, x, y, z = se3.quat_wxyz_from_matrix(pose[:3, :3])
    translate.Set(Gf.Vec3d(*np.asarray(pose[:3, 3], dtype=float).tolist()), time)
    orient.Set(Gf.Quatd(float(w), Gf.Vec3d(float(x), float(y), float(z))), time)
