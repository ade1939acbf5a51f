"""Authoring layers/object.usda: one rigid body per object with its visual, collider, mass
properties, physics material and prior provenance. Every object backend ends here."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh
from pxr import Gf, UsdGeom

from rose_usd.core.color import srgb8_to_linear
from rose_usd.core.inertia import MassProperties, mass_properties, shell_mass_properties
from rose_usd.geometry.mesh import check_collider
from rose_usd.io.images import write_rgb
from rose_usd.object.meshes import Surface
from rose_usd.object.priors import PhysicsPrior, lookup
from rose_usd.sim.collider import coacd_parts
from rose_usd.stage_api import StageContext
from rose_usd.usd import paths, schema, tokens
from rose_usd.usd.geom import (
    MeshData,
    author_mesh,
    author_preview_material,
    bind_material,
    relative_asset,
)
from rose_usd.usd.physics import (
    Approximation,
    author_physics_material,
    bind_physics_material,
    make_collider,
    make_rigid_body,
    set_pose_ops,
)


@dataclass(frozen=True)
class PhysicsValues:
    """The values authored, with where they came from and how uncertain they are."""

    prior: PhysicsPrior
    source: str
    """'table', 'user', 'oracle' (schema token)."""
    density_kg_m3: float
    friction: float
    restitution: float
    mass_sigma_kg: float
    friction_sigma: float
    restitution_sigma: float


@dataclass(frozen=True)
class ObjectModel:
    name: str
    mesh: MeshData
    """In the object frame [m]."""
    world_from_object_0: np.ndarray
    """Pose at frame 0 (4, 4): the prim's default xform."""
    mass: MassProperties
    physics: PhysicsValues
    surface: Surface | None = None
    """The visual's textured surface in the object frame [m] (a mesh file's own, ``Surface``);
    None: the visual is ``mesh`` with its colors."""


def collision_approximation(mesh: MeshData, convex_tolerance: float) -> tuple[Approximation, float]:
    """Convex hull when the mesh is nearly convex, else convex decomposition; and volume / hull volume."""
    tm = trimesh.Trimesh(vertices=mesh.vertices, faces=mesh.faces, process=False)
    ratio = float(tm.volume / tm.convex_hull.volume)
    return (Approximation.CONVEX_HULL if ratio >= 1.0 - convex_tolerance else Approximation.CONVEX_DECOMPOSITION), ratio


@dataclass(frozen=True)
class Collider:
    """An object's collider as Newton will simulate it: the approximation, the mesh's volume over
    its hull's, the vertices of its convex pieces (object frame; what it touches the scene with)
    and, for a decomposition, how well the pieces cover the mesh (``decomposition_coverage``)."""

    approximation: Approximation
    convexity: float
    points: np.ndarray
    cover: dict


def collider_of(mesh: MeshData, convex_tolerance: float) -> Collider:
    """The collider Newton makes of the mesh: its hull when nearly convex, else CoACD's parts."""
    approximation, convexity = collision_approximation(mesh, convex_tolerance)
    if approximation is Approximation.CONVEX_HULL:  # the hull covers the mesh; its vertices are the mesh's
        cover = {"collision_parts": 1, "collision_coverage": 1.0, "collision_volume_ratio": round(1.0 / convexity, 4)}
        return Collider(approximation, convexity, np.asarray(mesh.vertices, float), cover)
    parts = coacd_parts(mesh)
    return Collider(approximation, convexity, np.concatenate(parts), decomposition_coverage(mesh, parts))


def decomposition_coverage(mesh: MeshData, parts: list[np.ndarray] | None = None) -> dict:
    """CoACD's convex parts of the collision mesh (as Newton will make them; ``coacd_parts``
    unless given) against the mesh: the part count, the fraction of the mesh's volume inside
    their union (coverage, ideally 1) and the union's volume over the mesh's (over 1: the parts
    bulge out)."""
    import manifold3d

    from rose_usd.core.watertight import manifold_of

    parts = coacd_parts(mesh) if parts is None else parts
    hulls = [manifold3d.Manifold.hull_points(pv) for pv in parts]
    union = manifold3d.Manifold.batch_boolean(hulls, manifold3d.OpType.Add)
    solid = manifold_of(np.asarray(mesh.vertices, np.float32).astype(np.float64), mesh.faces)
    return {
        "collision_parts": len(hulls),
        "collision_coverage": round(float((union ^ solid).volume() / solid.volume()), 4),
        "collision_volume_ratio": round(float(union.volume() / solid.volume()), 4),
    }


def _author_visual(ctx: StageContext, model: ObjectModel, looks) -> None:
    """The object's visual mesh and its look: its file's textured surface (the texture copied to
    ``object_textures/<name>.png``), else its mesh with the mesh's colors."""
    stage = ctx.stage
    if model.surface is None:
        visual = author_mesh(stage, paths.object_visual(model.name), model.mesh)
        look = author_preview_material(
            stage,
            looks.AppendChild("Visual"),
            color=model.mesh.color,
            use_vertex_color=model.mesh.vertex_colors is not None,
        )
    else:
        surface = model.surface
        name = f"{model.name}.png"
        write_rgb(ctx.side_dir("object_textures") / name, surface.image)
        mean = srgb8_to_linear(surface.image.reshape(-1, 3).mean(axis=0, keepdims=True).round())[0]
        mesh = MeshData(surface.vertices, surface.faces, color=tuple(float(c) for c in mean), uv=surface.uv)
        visual = author_mesh(stage, paths.object_visual(model.name), mesh)
        texture = relative_asset(ctx.out_dir / "object_textures" / name, ctx.layer_dir)
        look = author_preview_material(stage, looks.AppendChild("Visual"), texture_asset=texture)
    bind_material(visual.GetPrim(), look)


def author_object(ctx: StageContext, model: ObjectModel, collider: Collider) -> dict:
    """Write one object prim with its ``collider`` (``collider_of``). Returns facts for the layer's
    provenance."""
    check_collider(model.mesh.vertices, model.mesh.faces, f"object {model.name!r} mesh")
    stage = ctx.stage
    UsdGeom.Scope.Define(stage, paths.OBJECTS)
    xform = UsdGeom.Xform.Define(stage, paths.object_path(model.name))
    prim = xform.GetPrim()
    set_pose_ops(xform, model.world_from_object_0)
    make_rigid_body(
        prim,
        mass_kg=model.mass.mass_kg,
        center_of_mass_m=model.mass.center_of_mass_m,
        diagonal_inertia=model.mass.diagonal_inertia,
        principal_axes_wxyz=model.mass.principal_axes_wxyz,
    )
    phys = model.physics
    prim.ApplyAPI(schema.PHYSICS_PRIOR_API)
    prim.GetAttribute(tokens.PRIOR_CATEGORY).Set(phys.prior.category)
    prim.GetAttribute(tokens.PRIOR_SOURCE).Set(phys.source)
    prim.GetAttribute(tokens.PRIOR_DENSITY_RANGE).Set(Gf.Vec2f(*phys.prior.density_range_kg_m3))
    prim.GetAttribute(tokens.PRIOR_DENSITY).Set(float(phys.density_kg_m3))
    prim.GetAttribute(tokens.PRIOR_MASS_UNCERTAINTY).Set(float(phys.mass_sigma_kg))
    prim.GetAttribute(tokens.PRIOR_FRICTION).Set(float(phys.friction))
    prim.GetAttribute(tokens.PRIOR_FRICTION_UNCERTAINTY).Set(float(phys.friction_sigma))
    prim.GetAttribute(tokens.PRIOR_RESTITUTION).Set(float(phys.restitution))
    prim.GetAttribute(tokens.PRIOR_RESTITUTION_UNCERTAINTY).Set(float(phys.restitution_sigma))
    prim.GetAttribute(tokens.PRIOR_HOLLOW).Set(bool(phys.prior.hollow))
    prim.GetAttribute(tokens.PRIOR_SHELL_THICKNESS).Set(float(phys.prior.shell_thickness_m))

    looks = paths.object_looks(model.name)
    UsdGeom.Scope.Define(stage, looks)
    _author_visual(ctx, model, looks)
    collision = author_mesh(
        stage,
        paths.object_collision(model.name),
        MeshData(model.mesh.vertices, model.mesh.faces),
        purpose=UsdGeom.Tokens.guide,
    )
    approximation, cover = collider.approximation, collider.cover
    if cover["collision_coverage"] < 0.98:
        ctx.warn(
            f"object {model.name!r}: its convex parts cover only "
            f"{100 * cover['collision_coverage']:.1f} % of its volume"
        )
    make_collider(collision.GetPrim(), approximation)
    material = author_physics_material(
        stage,
        looks.AppendChild("PhysicsMaterial"),
        friction=phys.friction,
        restitution=phys.restitution,
        density=phys.density_kg_m3,
    )
    bind_physics_material(collision.GetPrim(), material)
    return {
        "mass_kg": round(model.mass.mass_kg, 6),
        "volume_m3": model.mass.volume_m3,
        "approximation": approximation.value,
        "volume_over_hull": round(collider.convexity, 4),
    } | cover


def author_objects(ctx: StageContext, models: list[ObjectModel], convex_tolerance: float) -> dict:
    """Rest the objects' colliders on the scene (sim.settle), then write them all. Returns facts
    per object."""
    from rose_usd.layers.scene import scene_collider
    from rose_usd.sim.settle import settle

    colliders = {m.name: collider_of(m.mesh, convex_tolerance) for m in models}
    pushes: dict = {}
    lifts = settle(
        models, scene_collider(ctx.stage), pushes=pushes, collider_points={n: c.points for n, c in colliders.items()}
    )
    facts = {}
    for model in models:
        lift = lifts.get(model.name, 0.0)
        if not np.isfinite(lift):
            ctx.warn(
                f"object {model.name!r} is more than 3 cm inside the scene at frame 0: "
                "left where it is (check its pose and the scene)"
            )
        elif lift > 0.01:
            ctx.warn(f"object {model.name!r} was {1e3 * lift:.0f} mm inside the scene at frame 0: lifted onto it")
        push = pushes.get(model.name, np.zeros(3))
        facts[model.name] = author_object(ctx, model, colliders[model.name]) | {
            "settle_lift_m": None if not np.isfinite(lift) else round(lift, 5),
            "settle_push_m": [round(float(v), 5) for v in push[:2]],
        }
    return facts


def physics_for(spec, vertices: np.ndarray, faces: np.ndarray, ctx: StageContext, *, wall_modeled: bool = False):
    """Density, friction, restitution from the category prior with rose.toml's overrides; mass
    properties of the solid (or of its wall, for hollow categories, unless ``wall_modeled``: the
    mesh is a vessel's wall already)."""
    prior, warning = lookup(spec.category)
    if warning:
        ctx.warn(f"object {spec.name!r}: {warning}")
    o = spec.overrides
    hollow = bool(o.get("hollow", prior.hollow)) and not wall_modeled
    density = float(o.get("density_kg_m3", prior.density_kg_m3))
    thickness = prior.shell_thickness_m if prior.shell_thickness_m > 0 else 0.003
    props = (
        shell_mass_properties(vertices, faces, density, thickness)
        if hollow
        else mass_properties(vertices, faces, density)
    )
    source = "table"
    mass_sigma = prior.density_sigma_kg_m3 * props.volume_m3
    if "mass_kg" in o:  # the user's mass wins: rescale (the mass distribution keeps its shape)
        k = float(o["mass_kg"]) / props.mass_kg
        props = type(props)(
            props.mass_kg * k,
            props.volume_m3,
            props.center_of_mass_m,
            props.inertia_com * k,
            props.diagonal_inertia * k,
            props.principal_axes,
        )
        density, mass_sigma, source = density * k, 0.0, "user"
    elif "density_kg_m3" in o:
        mass_sigma, source = 0.0, "user"
    physics = PhysicsValues(
        prior=prior,
        source=source,
        density_kg_m3=density,
        friction=float(o.get("friction", prior.friction)),
        restitution=float(o.get("restitution", prior.restitution)),
        mass_sigma_kg=float(mass_sigma),
        friction_sigma=0.0 if "friction" in o else prior.friction_sigma,
        restitution_sigma=0.0 if "restitution" in o else prior.restitution_sigma,
    )
    return physics, props
