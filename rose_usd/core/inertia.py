"""Mass properties of a closed triangle mesh of uniform density."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh

from rose_usd.core import se3


@dataclass(frozen=True)
class MassProperties:
    mass_kg: float
    volume_m3: float
    center_of_mass_m: np.ndarray
    """In the mesh frame, (3,)."""
    inertia_com: np.ndarray
    """Inertia tensor about the center of mass, mesh-frame axes [kg m^2], (3, 3)."""
    diagonal_inertia: np.ndarray
    """Principal moments [kg m^2], ascending, (3,)."""
    principal_axes: np.ndarray
    """Rotation (3, 3) whose columns are the principal axes in the mesh frame (det +1)."""

    @property
    def principal_axes_wxyz(self) -> np.ndarray:
        return se3.quat_wxyz_from_matrix(self.principal_axes)


def mass_properties(vertices: np.ndarray, faces: np.ndarray, density_kg_m3: float) -> MassProperties:
    """Mass, center of mass and inertia of the solid bounded by a closed, outward-oriented mesh."""
    mesh = trimesh.Trimesh(vertices=np.asarray(vertices, dtype=float), faces=np.asarray(faces), process=False)
    props = trimesh.triangles.mass_properties(mesh.triangles, density=density_kg_m3)
    volume = float(props["volume"])
    if volume <= 0:
        raise ValueError(f"mesh encloses no positive volume ({volume:g} m^3): is it closed and outward-oriented?")
    inertia = np.asarray(props["inertia"], dtype=float)  # about the center of mass
    moments, axes = np.linalg.eigh(0.5 * (inertia + inertia.T))
    if np.linalg.det(axes) < 0:
        axes[:, 2] *= -1.0
    return MassProperties(
        mass_kg=float(props["mass"]),
        volume_m3=volume,
        center_of_mass_m=np.asarray(props["center_mass"], dtype=float),
        inertia_com=inertia,
        diagonal_inertia=moments,
        principal_axes=axes,
    )


def _about_origin(inertia_com: np.ndarray, mass: float, com: np.ndarray) -> np.ndarray:
    """Parallel-axis theorem: the inertia tensor about the frame's origin."""
    return inertia_com + mass * (float(com @ com) * np.eye(3) - np.outer(com, com))


def shell_mass_properties(
    vertices: np.ndarray, faces: np.ndarray, density_kg_m3: float, thickness_m: float
) -> MassProperties:
    """Mass properties of a hollow object: a wall ``thickness_m`` thick inside the closed mesh
    (the solid minus the solid shrunk along the vertex normals by the thickness)."""
    mesh = trimesh.Trimesh(vertices=np.asarray(vertices, dtype=float), faces=np.asarray(faces), process=False)
    outer = mass_properties(mesh.vertices, mesh.faces, density_kg_m3)
    inner_vertices = mesh.vertices - thickness_m * mesh.vertex_normals
    try:
        inner = mass_properties(inner_vertices, mesh.faces, density_kg_m3)
    except ValueError:  # thinner than the wall: it is all wall
        return outer
    if inner.volume_m3 >= outer.volume_m3:
        return outer
    mass = outer.mass_kg - inner.mass_kg
    com = (outer.mass_kg * outer.center_of_mass_m - inner.mass_kg * inner.center_of_mass_m) / mass
    about_origin = _about_origin(outer.inertia_com, outer.mass_kg, outer.center_of_mass_m) - _about_origin(
        inner.inertia_com, inner.mass_kg, inner.center_of_mass_m
    )
    inertia = about_origin - mass * (float(com @ com) * np.eye(3) - np.outer(com, com))
    moments, axes = np.linalg.eigh(0.5 * (inertia + inertia.T))
    if np.linalg.det(axes) < 0:
        axes[:, 2] *= -1.0
    return MassProperties(
        mass_kg=float(mass),
        volume_m3=outer.volume_m3 - inner.volume_m3,
        center_of_mass_m=com,
        inertia_com=inertia,
        diagonal_inertia=moments,
        principal_axes=axes,
    )
