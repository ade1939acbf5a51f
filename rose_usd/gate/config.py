from __future__ import annotations

import enum
from dataclasses import dataclass, field

from rose_usd.stage_config import limits


class GateBackend(enum.Enum):
    AUTO = "auto"  # chosen from what the case holds (rose_usd.plan)
    MITSUBA_NEWTON = "mitsuba-newton"  # re-render with Mitsuba, simulate with Newton


@dataclass(frozen=True, kw_only=True)
class GateConfig:
    backend: GateBackend = GateBackend.AUTO
    """How the stage is checked (default auto)."""
    ssim_threshold: float = field(default=0.75, metadata=limits(0.0, 1.0))
    """Mean SSIM needed to pass [-] (default 0.75; the paper's real videos score 0.71-0.80)."""
    spp: int = 4
    """Samples per pixel of the re-render: anti-aliasing only, shading is noise-free; 8 moves
    the SSIM by under 0.001 and takes 55 % longer a frame (default 4)."""
    frame_stride: int = 1
    """Re-render every k-th frame (default 1: all frames)."""
    exclude_interactor: bool = True
    """Leave the interactor's pixels (hand, arm) out of the SSIM mean: it is not reconstructed (default true)."""
    interactor_dilate_px: int = field(default=3, metadata=limits(0))
    """Grow the interactor mask by this many pixels before excluding it (default 3)."""
    physics: bool = True
    """Run the Newton rest check (default true)."""
    physics_duration_s: float = 1.0
    """Simulated time of the rest check [s] (default 1); it stops earlier once every object has
    settled or creeps steadily (``sim.rest.SETTLE_AFTER_S``)."""
    physics_dt_s: float = 1.0 / 600.0
    """Time step of the rest check [s] (default 1/600)."""
    physics_iterations: int = 30
    """XPBD solver iterations per step (default 30; 10 lets a box on a 0.3 deg incline creep ~5 deg in 1 s)."""
    physics_threshold_m: float = 0.005
    """Largest displacement an object at rest may show [m] (default 0.005)."""
    track: bool = True
    """Compare each object's re-rendered pixels with its masks (the track check) (default true)."""
    track_iou_threshold: float = field(default=0.5, metadata=limits(0.0, 1.0))
    """Mean IoU of each object's re-rendered pixels with its masks needed to pass [-] (default 0.5)."""
    track_window_s: float = 1.0
    """The track check's window [s] (default 1): see ``track_window_iou``."""
    track_window_iou: float = field(default=0.3, metadata=limits(0.0, 1.0))
    """Mean IoU of each object's re-rendered pixels with its masks needed over every window of
    ``track_window_s`` holding 3 rendered frames or more [-] (default 0.3): a stretch where the
    trajectory has left the object fails, whatever the mean (sam2-cups: a cup lying 15 cm over
    the table from frame 225 on, its masks upright on it: 0.24 over frames 244-273, mean 0.67)."""
    track_min_pixels: int = field(default=50, metadata=limits(1))
    """Frames where an object's mask has fewer pixels do not count in its IoU (default 50)."""
    save_frames: bool = False
    """Also write every re-rendered frame to report/frames/ (default false)."""
