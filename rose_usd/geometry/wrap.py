"""CGAL's 3D alpha wrap: a closed 2-manifold around a point set."""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np


def alpha_wrap(points: np.ndarray, alpha_m: float, offset_m: float) -> tuple[np.ndarray, np.ndarray]:
    """CGAL 3D alpha wrap of a point set: (vertices, faces) of a closed 2-manifold."""
    import trimesh
    from CGAL import CGAL_Alpha_wrap_3 as aw
    from CGAL.CGAL_Kernel import Point_3
    from CGAL.CGAL_Polyhedron_3 import Polyhedron_3

    pts = aw.Point_3_Vector()
    pts.reserve(len(points))
    for p in points.tolist():
        pts.append(Point_3(*p))
    out = Polyhedron_3()
    aw.alpha_wrap_3(pts, float(alpha_m), float(offset_m), out)
    with tempfile.TemporaryDirectory() as tmp:
        path = str(Path(tmp) / "wrap.off")
        out.write_to_file(path)
        mesh = trimesh.load(path, process=False, force="mesh")
    return np.asarray(mesh.vertices, dtype=float), np.asarray(mesh.faces, dtype=np.int64)
