from __future__ import annotations

import enum
from dataclasses import dataclass


class ObjectBackend(enum.Enum):
    AUTO = "auto"  # chosen from what the case holds (rose_usd.plan)
    FUSION = "fusion"  # the resting object's masked depth fused and completed where never seen
    IMPORTED = "imported"  # another tool's mesh (TRELLIS GLB, scan, CAD), scaled by silhouettes, posed on its support
    ORACLE = "oracle"  # ground-truth meshes, densities and frame-0 poses from gt/ (benchmark cases)


@dataclass(frozen=True, kw_only=True)
class ObjectConfig:
    backend: ObjectBackend = ObjectBackend.AUTO
    """Which backend reconstructs the object(s) (default auto)."""
    voxel_m: float = 0.002
    """fusion: point spacing of the fused and completed object [m] (default 0.002)."""
    support_gap_m: float = 0.003
    """fusion: points this near the support (z = 0) are dropped as table [m] (default 0.003)."""
    rest_tolerance_m: float = 0.01
    """fusion: the object rests while its median point stays this near its first one [m] (default 0.01)."""
    revolution_tolerance: float = 0.05
    """fusion: a solid of revolution when radial spread within height bands is under this fraction
    of the radius (default 0.05)."""
    max_triangles: int = 8000
    """fusion: the object mesh is decimated to at most this many triangles (default 8000)."""
    scale_search_alpha: float = 1.5
    """imported: rho is searched in [rho_0 / alpha, rho_0 * alpha] (the paper's Eq. 3) [-] (default 1.5)."""
    scale_search_steps: int = 15
    """imported: log-spaced scales tried over that range before refining around the best (default 15)."""
    scale_depth_weight: float = 0.1
    """imported: scale and pose minimize (1 - silhouette IoU) + this x the depth fit's RMS in mm
    (default 0.1: a millimeter of RMS weighs as much as 0.1 of IoU)."""
    convex_tolerance: float = 0.02
    """A mesh whose volume is within this fraction of its convex hull's collides as its hull;
    otherwise by convex decomposition [-] (default 0.02)."""
