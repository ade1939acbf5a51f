from __future__ import annotations

import enum
from dataclasses import dataclass


class TrajectoryBackend(enum.Enum):
    FOUNDATIONPOSE = "foundationpose"  # import FoundationPose's ob_in_cam/ (T_cam<-mesh per frame) through the recovered cameras
    ORACLE = "oracle"  # ground-truth object poses from gt/ (benchmark cases)


@dataclass(frozen=True, kw_only=True)
class TrajectoryConfig:
    backend: TrajectoryBackend = TrajectoryBackend.ORACLE
    """Which backend tracks the object(s); default oracle."""
