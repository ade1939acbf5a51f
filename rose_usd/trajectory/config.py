from __future__ import annotations

import enum
from dataclasses import dataclass


class TrajectoryBackend(enum.Enum):
    ORACLE = "oracle"  # ground-truth object poses from gt/ (benchmark cases)


@dataclass(frozen=True, kw_only=True)
class TrajectoryConfig:
    backend: TrajectoryBackend = TrajectoryBackend.ORACLE
    """Which backend tracks the object(s); default oracle."""
