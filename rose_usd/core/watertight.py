"""Is a triangle mesh a valid collider: closed, 2-manifold, consistently wound, enclosing positive
volume? Checked by two libraries (trimesh and manifold3d), never assumed."""

from __future__ import annotations

import numpy as np
import trimesh


def manifold_of(vertices: np.ndarray, faces: np.ndarray):
    """The manifold3d solid of a triangle mesh; check ``.status()`` (``Error.NoError`` when valid)."""
    import manifold3d

    return manifold3d.Manifold(
        manifold3d.Mesh(
            vert_properties=np.ascontiguousarray(vertices, dtype=np.float32),
            tri_verts=np.ascontiguousarray(faces, dtype=np.uint32),
        )
    )


def is_closed(tm: trimesh.Trimesh) -> bool:
    """Watertight, consistently wound and enclosing positive volume (faces wound outward), by
    trimesh alone: enough to draw a silhouette from the camera-facing triangles."""
    return bool(tm.is_watertight and tm.is_winding_consistent and tm.volume > 0)


def collider_problems(vertices: np.ndarray, faces: np.ndarray) -> list[str]:
    """What keeps the mesh from being a closed, consistently oriented solid (empty when valid)."""
    tm = trimesh.Trimesh(vertices=vertices, faces=faces, process=False)
    problems = []
    if not tm.is_watertight:
        problems.append("not watertight")
    if not tm.is_winding_consistent:
        problems.append("inconsistent winding")
    if tm.is_watertight and tm.volume <= 0:
        problems.append("inside-out (negative volume)")
    import manifold3d

    status = manifold_of(vertices, faces).status()
    if status != manifold3d.Error.NoError:
        problems.append(f"not a 2-manifold for manifold3d ({status.name})")
    return problems
