"""Mesh validity and simplification: CGAL's self-intersection test, the collider check every
stage runs before it writes a collider, submeshes, faces facing a set of cameras, decimation."""

from __future__ import annotations

import itertools
import tempfile
from pathlib import Path

import numpy as np

from rose_usd.core.watertight import collider_problems
from rose_usd.errors import MeshError


def self_intersects(vertices: np.ndarray, faces: np.ndarray) -> bool:
    """CGAL's exact self-intersection test (the mesh goes to CGAL through an OFF file)."""
    import trimesh
    from CGAL import CGAL_Alpha_wrap_3  # noqa: F401  before PMP: once PMP is loaded first, SWIG no longer matches alpha_wrap_3's arguments (seen with cgal 6.0.1)
    from CGAL import CGAL_Polygon_mesh_processing as pmp
    from CGAL.CGAL_Polyhedron_3 import Polyhedron_3

    with tempfile.TemporaryDirectory() as tmp:
        path = str(Path(tmp) / "mesh.off")
        trimesh.Trimesh(vertices=vertices, faces=faces, process=False).export(path)
        poly = Polyhedron_3(path)
    if poly.size_of_facets() != len(faces):
        raise MeshError(
            f"CGAL read {poly.size_of_facets()} of {len(faces)} triangles", hint="the mesh is not a valid polygon mesh"
        )
    return bool(pmp.does_self_intersect(poly))


def faces_facing(vertices: np.ndarray, faces: np.ndarray, centers: np.ndarray) -> np.ndarray:
    """Triangles (bool (F,)) whose front faces at least one of the camera ``centers`` (N, 3).
    A closed mesh's other triangles are hidden from every one of them by the mesh itself."""
    tri = vertices[faces]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    centroid = tri.mean(axis=1)
    out = np.zeros(len(faces), bool)
    for c in centers:
        out |= np.einsum("ij,ij->i", normal, c - centroid) > 0
        if out.all():
            break
    return out


def longest_edge(vertices: np.ndarray, faces: np.ndarray) -> float:
    """The longest triangle edge of the mesh [its units]."""
    return float(np.max(np.linalg.norm(vertices[faces] - vertices[np.roll(faces, 1, axis=1)], axis=2)))


def submesh(vertices: np.ndarray, faces: np.ndarray, keep: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The triangles ``keep`` (bool (F,)) with only the vertices they use, renumbered."""
    kept = faces[keep]
    used, inverse = np.unique(kept, return_inverse=True)
    return vertices[used], inverse.reshape(kept.shape).astype(np.int64)


def check_collider(vertices: np.ndarray, faces: np.ndarray, what: str) -> None:
    """Raise MeshError unless the mesh is watertight, consistently wound and encloses volume."""
    problems = collider_problems(vertices, faces)
    if problems:
        raise MeshError(
            f"{what} is {', '.join(problems)}", hint="repair it (the scene backend must produce a closed 2-manifold)"
        )


def decimate(mesh, max_triangles: int, *, check: bool = True):
    """Quadric decimation of a trimesh to at most ``max_triangles``; with ``check``, the input is
    kept when the decimated mesh would not be a closed, self-intersection-free 2-manifold."""
    import trimesh

    if len(mesh.faces) <= max_triangles:
        return mesh
    # the decimator's default aggression (7) can open a vessel's thin wall (5 mm, 2.5 voxels): then
    # every target fails the check and the mesh keeps all its triangles; at 3 it stays closed
    for target, aggression in itertools.product(
        (max_triangles, int(0.75 * max_triangles), int(0.5 * max_triangles)), (7, 3)
    ):
        simple = mesh.simplify_quadric_decimation(face_count=target, aggression=aggression)
        # the decimator may leave collapsed (two-vertex) triangles: drop them
        simple = trimesh.Trimesh(simple.vertices, simple.faces[simple.nondegenerate_faces()], process=True)
        if not check or not (
            collider_problems(simple.vertices, simple.faces) or self_intersects(simple.vertices, simple.faces)
        ):
            return simple
    return mesh
