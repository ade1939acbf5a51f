from __future__ import annotations

import enum
from dataclasses import dataclass


class ObjectBackend(enum.Enum):
    ORACLE = "oracle"  # ground-truth meshes, densities and frame-0 poses from gt/ (benchmark cases)


@dataclass(frozen=True, kw_only=True)
class ObjectConfig:
    backend: ObjectBackend = ObjectBackend.ORACLE
    """Which backend reconstructs the object(s); default oracle."""
    convex_tolerance: float = 0.02
    """A mesh whose volume is within this fraction of its convex hull's collides as its hull;
    otherwise by convex decomposition [-] (default 0.02)."""
