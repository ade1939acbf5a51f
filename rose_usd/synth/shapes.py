"""Closed, consistently oriented triangle meshes for synthetic scenes and target objects.

Target objects are built in their own frame: origin at the center of the face they rest on,
+Z up. Booleans (the mug) go through manifold3d, so every mesh here is a valid 2-manifold.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

import manifold3d
import numpy as np
import trimesh

from rose_usd.core.watertight import manifold_of


class ObjectShape(enum.Enum):
    """Target object shapes the generator can make."""

    BOX = "box"
    CAN = "can"
    MUG = "mug"
    PEN = "pen"  # thinner than the gripper's pads are long; always lies on its side


# category (rose_usd.object.priors) of each shape
SHAPE_CATEGORY = {ObjectShape.BOX: "box", ObjectShape.CAN: "can", ObjectShape.MUG: "mug", ObjectShape.PEN: "pen"}


def to_manifold(mesh: trimesh.Trimesh) -> manifold3d.Manifold:
    m = manifold_of(mesh.vertices, mesh.faces)
    if m.status() != manifold3d.Error.NoError:
        raise ValueError(f"mesh is not a manifold: {m.status()}")
    return m


def from_manifold(m: manifold3d.Manifold) -> trimesh.Trimesh:
    mesh = m.to_mesh()
    return trimesh.Trimesh(
        vertices=np.asarray(mesh.vert_properties)[:, :3], faces=np.asarray(mesh.tri_verts), process=True
    )


def box(extents, center=(0.0, 0.0, 0.0)) -> trimesh.Trimesh:
    """Axis-aligned box with ``extents`` (x, y, z) [m] centered at ``center``."""
    mesh = trimesh.creation.box(extents=np.asarray(extents, dtype=float))
    mesh.apply_translation(center)
    return mesh


def cylinder(radius: float, height: float, *, sections: int = 48, z0: float = 0.0) -> trimesh.Trimesh:
    """Z-axis cylinder from z0 to z0 + height [m]."""
    mesh = trimesh.creation.cylinder(radius=radius, height=height, sections=sections)
    mesh.apply_translation([0.0, 0.0, z0 + height / 2.0])
    return mesh


def sphere(radius: float, center, *, subdivisions: int = 3) -> trimesh.Trimesh:
    mesh = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    mesh.apply_translation(center)
    return mesh


def mug(
    radius: float, height: float, wall: float, *, handle_radius: float | None = None, sections: int = 48
) -> trimesh.Trimesh:
    """A mug: a cylinder hollowed from the top (bottom thickness = wall) with a ring handle on +X."""
    outer = manifold3d.Manifold.cylinder(height, radius, radius, sections)
    inner = manifold3d.Manifold.cylinder(height, radius - wall, radius - wall, sections).translate([0.0, 0.0, wall])
    handle_radius = handle_radius if handle_radius is not None else 0.32 * height
    tube = 0.45 * wall + 0.004
    ring = manifold3d.CrossSection.circle(tube, 16).translate([handle_radius, 0.0])
    torus = manifold3d.Manifold.revolve(ring, 32)  # about Z, in the XY plane
    # stand the ring up in the XZ plane, at the side of the mug, halfway up
    torus = torus.rotate([90.0, 0.0, 0.0]).translate([radius, 0.0, height / 2.0])
    body = (outer + torus) - inner
    return from_manifold(body)


@dataclass(frozen=True)
class ShapeSpec:
    """A sampled target object."""

    shape: ObjectShape
    mesh: trimesh.Trimesh
    """In the object frame: origin at the bottom center, +Z up [m]."""
    size_m: tuple[float, float, float]
    """Bounding box extents [m]."""


def sample_object(shape: ObjectShape, rng: np.random.Generator) -> ShapeSpec:
    """A target object of the given shape with sizes drawn from everyday ranges."""
    if shape is ObjectShape.BOX:
        ext = (rng.uniform(0.06, 0.11), rng.uniform(0.05, 0.09), rng.uniform(0.05, 0.12))
        mesh = box(ext, center=(0.0, 0.0, ext[2] / 2.0))
    elif shape is ObjectShape.CAN:
        r, h = rng.uniform(0.03, 0.042), rng.uniform(0.09, 0.13)
        mesh = cylinder(r, h, sections=64)
    elif shape is ObjectShape.MUG:
        r, h = rng.uniform(0.036, 0.045), rng.uniform(0.08, 0.10)
        mesh = mug(r, h, wall=0.005)
    elif shape is ObjectShape.PEN:
        r, h = rng.uniform(0.005, 0.0075), rng.uniform(0.12, 0.15)
        mesh = cylinder(r, h, sections=32)
    else:  # pragma: no cover - enum is closed
        raise ValueError(shape)
    return ShapeSpec(shape=shape, mesh=mesh, size_m=tuple(float(v) for v in mesh.extents))


def hand_proxy() -> trimesh.Trimesh:
    """A hand-sized interactor: a flattened palm and a forearm along +X, in its own frame.

    The palm's center is the origin; the palm faces -X (toward what it touches)."""
    palm = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    palm.apply_scale([0.035, 0.045, 0.055])
    forearm = trimesh.creation.capsule(height=0.30, radius=0.032, count=[24, 12])
    # capsule along Z -> along +X, starting behind the palm and rising (the arm comes from above)
    forearm.apply_transform(trimesh.transformations.rotation_matrix(np.radians(90 - 35), [0, 1, 0]))
    forearm.apply_translation([0.03 + 0.15 * np.cos(np.radians(35)), 0.0, 0.15 * np.sin(np.radians(35))])
    return from_manifold(to_manifold(palm) + to_manifold(forearm))
