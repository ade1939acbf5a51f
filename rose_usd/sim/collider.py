"""The convex parts Newton simulates a ``convexDecomposition`` collider as: what the object stage
tests for contact when it rests an object on the scene, and the trajectory stage when it rests a
set-down pose. CoACD takes seconds on an object's mesh, and every stage after the object's asks
for the same parts: they are kept in the cache (``core.cache``), keyed by the mesh, the settings
and CoACD's version."""

from __future__ import annotations

import hashlib
import importlib.metadata
import json

import numpy as np
import trimesh

from rose_usd.core.cache import cache_dir, load_arrays, save_arrays
from rose_usd.usd.geom import MeshData

NEWTON_COACD = {"threshold": 0.05, "mcts_nodes": 20, "mcts_iterations": 5, "mcts_max_depth": 1, "merge": False}
"""The CoACD settings Newton 1.8 uses for ``convexDecomposition`` colliders
(``ModelBuilder.approximate_meshes``): running CoACD with them (per connected part, as Newton
does) gives the parts Newton will simulate."""


def coacd_parts(mesh: MeshData) -> list[np.ndarray]:
    """The vertices of each convex part CoACD makes of the mesh with Newton's settings (from the
    cache when this mesh was split before)."""
    vertices = np.asarray(mesh.vertices, np.float32).astype(np.float64)  # as authored (USD points are float)
    faces = np.ascontiguousarray(mesh.faces, dtype=np.int64)
    path = cache_dir("coacd") / f"{_parts_key(vertices, faces)}.parts.npz"
    parts = load_arrays(path)
    if parts is None:
        parts = _run_coacd(vertices, faces)
        save_arrays(path, parts)
    return parts


def _parts_key(vertices: np.ndarray, faces: np.ndarray) -> str:
    settings = {"coacd": importlib.metadata.version("coacd"), "settings": NEWTON_COACD}
    digest = hashlib.sha256(json.dumps(settings, sort_keys=True).encode())
    for data in (vertices, faces):
        digest.update(np.asarray(data.shape, np.int64).tobytes())
        digest.update(data.tobytes())
    return digest.hexdigest()


def _run_coacd(vertices: np.ndarray, faces: np.ndarray) -> list[np.ndarray]:
    import coacd

    coacd.set_log_level("error")
    tm = trimesh.Trimesh(vertices, faces, process=False)
    return [
        np.asarray(pv, np.float64)
        for part in tm.split(only_watertight=False)
        for pv, _ in coacd.run_coacd(coacd.Mesh(np.asarray(part.vertices), np.asarray(part.faces)), **NEWTON_COACD)
    ]
