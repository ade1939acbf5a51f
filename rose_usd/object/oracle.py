"""Oracle objects: ground-truth meshes, densities, friction and frame-0 poses of a benchmark case."""

from __future__ import annotations

from rose_usd.core.inertia import mass_properties
from rose_usd.object.author import ObjectModel, PhysicsValues, author_objects
from rose_usd.object.priors import lookup
from rose_usd.oracle import world_from_gt
from rose_usd.stage_api import StageContext


def run(ctx: StageContext) -> None:
    gt = ctx.case.gt
    to_world = world_from_gt(ctx)
    models = []
    for spec in ctx.case.config.objects:
        truth = gt.object(spec.name)
        prior, warning = lookup(truth.category)
        if warning:
            ctx.warn(warning)
        mesh = gt.object_mesh(spec.name)
        mass = mass_properties(mesh.vertices, mesh.faces, truth.density_kg_m3)
        physics = PhysicsValues(
            prior=prior,
            source="oracle",
            density_kg_m3=truth.density_kg_m3,
            friction=truth.friction,
            restitution=truth.restitution,
            mass_sigma_kg=0.0,
            friction_sigma=0.0,
            restitution_sigma=0.0,
        )
        models.append(ObjectModel(spec.name, mesh, to_world @ gt.object_poses(spec.name)[0], mass, physics))
    facts = author_objects(ctx, models, ctx.config.convex_tolerance)  # everything read and checked: now author
    ctx.record(objects=facts)
