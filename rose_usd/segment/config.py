from __future__ import annotations

import enum
from dataclasses import dataclass


class SegmentBackend(enum.Enum):
    AUTO = "auto"  # chosen from what the case holds (rose_usd.plan)
    CLASSICAL = "classical"  # no learned model: prompt (or interactor contact) + 3D propagation + static-world residual
    SAM2 = "sam2"  # import SAM 2's masks from perception/masks (DAVIS paletted PNGs or per-object folders)
    FLOW = "flow"  # no depth needed (RGB-only video): prompt + GrabCut, optical-flow propagation, look-alike tracks
    ORACLE = "oracle"  # ground-truth masks from gt/masks (benchmark cases)


@dataclass(frozen=True, kw_only=True)
class SegmentConfig:
    backend: SegmentBackend = SegmentBackend.AUTO
    """Which backend segments the object(s) and the interactor (default auto)."""
    prompts: str = ""
    """classical, flow: prompts overriding rose.toml's, ";"-separated "Name=frame:x0,y0,x1,y1" (a box)
    or "Name=frame:x,y" (a point) [px]; "Name=" may be left out when there is one object (default:
    rose.toml's)."""
    min_height_m: float = 0.004
    """classical: a pixel stands on the support when its point is this high above it [m] (default 0.004)."""
    core_m: float = 0.015
    """classical: pixels this close to the object's previous points seed its next mask [m] (default 0.015)."""
    foreground_m: float = 0.015
    """classical: the interactor is nearer than the static world by more than this (+1 % of depth) [m]
    (default 0.015)."""
    flow_max_side_px: int = 640
    """flow: frames are processed at this long side [px] (default 640)."""
    sam2_ids: str = ""
    """sam2: object ids as "Name=id,Name=id" (default: the objects of rose.toml in order, ids 1, 2, ...)."""
    sam2_interactor_id: int = 0
    """sam2: the id SAM 2 gave the hand, 0 if it was not prompted (the interactor is then the static-world residual)."""
