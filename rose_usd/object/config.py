from __future__ import annotations

import enum
from dataclasses import dataclass, field

from rose_usd.stage_config import limits


class ObjectBackend(enum.Enum):
    AUTO = "auto"  # chosen from what the case holds (rose_usd.plan)
    FUSION = "fusion"  # the resting object's masked depth fused and completed where never seen
    IMPORTED = "imported"  # another tool's mesh (TRELLIS GLB, scan, CAD), scaled by silhouettes, posed on its support
    SILHOUETTE = "silhouette"  # RGB only: the mesh, or a category primitive (a proxy), fitted to the masks
    ORACLE = "oracle"  # ground-truth meshes, densities and frame-0 poses from gt/ (benchmark cases)


@dataclass(frozen=True, kw_only=True)
class FusionConfig:
    """Settings of the fusion backend."""

    revolution_tolerance: float = 0.05
    """A solid of revolution when radial spread within height bands is under this fraction
    of the radius (default 0.05)."""


@dataclass(frozen=True, kw_only=True)
class ImportedConfig:
    """Settings of the imported backend."""

    scale_search_alpha: float = 1.5
    """rho is searched in [rho_0 / alpha, rho_0 * alpha] (the paper's Eq. 3) [-] (default 1.5)."""
    scale_search_steps: int = 15
    """Log-spaced scales tried over that range before refining around the best (default 15)."""
    scale_depth_weight: float = field(default=0.1, metadata=limits(0.0))
    """Scale and pose minimize (1 - silhouette IoU) + this x the depth fit's RMS in mm
    (default 0.1: a millimeter of RMS weighs as much as 0.1 of IoU)."""


@dataclass(frozen=True, kw_only=True)
class SilhouetteConfig:
    """Settings of the silhouette backend (RGB only)."""

    rest_iou: float = 0.85
    """The object rests while its mask overlaps its first clear mask by this image IoU [-] (default 0.85)."""
    views: int = 6
    """At most this many resting frames are fitted at once (default 6)."""
    max_side_px: int = 320
    """Each view is cropped around the mask and downscaled to this long side [px] (default 320)."""
    held_margin: float = 0.05
    """A metric mesh fitting free (6-DoF) by this much more IoU than standing is held in the air (default 0.05)."""
    free_directions: int = 150
    """Orientations tried for a free fit: this many directions times 12 turns (default 150)."""


@dataclass(frozen=True, kw_only=True)
class ObjectConfig:
    backend: ObjectBackend = ObjectBackend.AUTO
    """Which backend reconstructs the object(s) (default auto)."""
    voxel_m: float = 0.002
    """fusion, imported: point spacing of the fused resting object (and of the completed one) [m] (default 0.002)."""
    support_gap_m: float = field(default=0.003, metadata=limits(0.0))
    """fusion, imported: resting points this near the support are dropped as table [m] (default 0.003)."""
    rest_tolerance_m: float = 0.01
    """fusion, imported: the object rests while its median point stays this near its first one [m]
    (default 0.01)."""
    max_triangles: int = 8000
    """fusion, imported: the object mesh is decimated to at most this many triangles (default 8000)."""
    convex_tolerance: float = 0.02
    """A mesh whose volume is within this fraction of its convex hull's collides as its hull;
    otherwise by convex decomposition [-] (default 0.02)."""
    fusion: FusionConfig = field(default_factory=FusionConfig)
    imported: ImportedConfig = field(default_factory=ImportedConfig)
    silhouette: SilhouetteConfig = field(default_factory=SilhouetteConfig)
