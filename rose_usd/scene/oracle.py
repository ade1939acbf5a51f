"""Oracle scene: the ground-truth static parts with their looks, their manifold union as the
collider, and the ground-truth lights."""

from __future__ import annotations

import numpy as np

from rose_usd.core import se3
from rose_usd.core.watertight import manifold_of
from rose_usd.errors import MeshError
from rose_usd.oracle import world_from_gt
from rose_usd.render.lighting import Lighting, PointLight
from rose_usd.scene.author import ScenePart, author_scene
from rose_usd.stage_api import StageContext
from rose_usd.usd.geom import MeshData


def run(ctx: StageContext) -> None:
    import manifold3d

    gt = ctx.case.gt
    to_world = world_from_gt(ctx)
    parts = []
    for p in gt.parts:
        mesh = gt.part_mesh(p)
        mesh.vertices = se3.transform_points(to_world, mesh.vertices)
        parts.append(ScenePart(p.name, mesh))
    union = None
    for part in parts:
        m = manifold_of(part.mesh.vertices, part.mesh.faces)
        if m.status() != manifold3d.Error.NoError:
            raise MeshError(
                f"ground-truth part {part.name!r} is not a manifold ({m.status().name})",
                path=gt.root / "meshes",
                hint="regenerate the case",
            )
        union = m if union is None else union + m
    mesh = union.to_mesh()
    collision = MeshData(
        vertices=np.asarray(mesh.vert_properties, dtype=float)[:, :3], faces=np.asarray(mesh.tri_verts, dtype=np.int64)
    )
    lighting = Lighting.from_json(gt.lighting)
    lighting = Lighting(
        lighting.ambient,
        tuple(
            PointLight(tuple(se3.transform_points(to_world, np.array([light.position_m]))[0].tolist()), light.intensity)
            for light in lighting.points
        ),
    )
    author_scene(ctx, parts, collision, lighting)
    ctx.record(collision_triangles=int(len(collision.faces)), parts=len(parts))
