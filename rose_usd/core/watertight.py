"""Is a triangle mesh a valid collider: closed, consistently wound, enclosing positive volume?"""

from __future__ import annotations

import numpy as np
import trimesh


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
    return problems
