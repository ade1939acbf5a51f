from __future__ import annotations

import enum
from dataclasses import dataclass


class CaptureBackend(enum.Enum):
    ORACLE = "oracle"  # ground-truth cameras and gravity from gt/ (benchmark cases)


@dataclass(frozen=True, kw_only=True)
class CaptureConfig:
    backend: CaptureBackend = CaptureBackend.ORACLE
    """Which backend recovers the cameras; default oracle (the only one so far)."""
