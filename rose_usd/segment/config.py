from __future__ import annotations

import enum
from dataclasses import dataclass


class SegmentBackend(enum.Enum):
    ORACLE = "oracle"  # ground-truth masks from gt/masks (benchmark cases)


@dataclass(frozen=True, kw_only=True)
class SegmentConfig:
    backend: SegmentBackend = SegmentBackend.ORACLE
    """Which backend segments the object(s) and the interactor; default oracle."""
