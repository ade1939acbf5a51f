from __future__ import annotations

import enum
from dataclasses import dataclass


class SceneBackend(enum.Enum):
    ORACLE = "oracle"  # ground-truth scene parts, materials and lights from gt/ (benchmark cases)


@dataclass(frozen=True, kw_only=True)
class SceneConfig:
    backend: SceneBackend = SceneBackend.ORACLE
    """Which backend reconstructs the scene; default oracle."""
