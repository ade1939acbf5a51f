"""The convex parts Newton simulates a ``convexDecomposition`` collider as: what the object stage
tests for contact when it rests an object on the scene, and the trajectory stage when it rests a
set-down pose."""

from __future__ import annotations

import numpy as np
import trimesh

from rose_usd.usd.geom import MeshData

NEWTON_COACD = {"threshold": 0.05, "mcts_nodes": 20, "mcts_iterations": 5, "mcts_max_depth": 1, "merge": False}
"""The CoACD settings Newton 1.8 uses for ``convexDecomposition`` colliders
(``ModelBuilder.approximate_meshes``): running CoACD with them (per connected part, as Newton
does) gives the parts Newton will simulate."""


def coacd_parts(mesh: MeshData) -> list[np.ndarray]:
    """The vertices of each convex part CoACD makes of the mesh with Newton's settings."""
    import coacd

    coacd.set_log_level("error")
    vertices = np.asarray(mesh.vertices, np.float32).astype(np.float64)  # as authored (USD points are float)
    tm = trimesh.Trimesh(vertices, mesh.faces, process=False)
    return [
        np.asarray(pv, np.float64)
        for part in tm.split(only_watertight=False)
        for pv, _ in coacd.run_coacd(coacd.Mesh(np.asarray(part.vertices), np.asarray(part.faces)), **NEWTON_COACD)
    ]
