from __future__ import annotations

import enum
from dataclasses import dataclass, field

from rose_usd.case.config import ObjectPrompt, parse_object_prompts
from rose_usd.stage_config import limits


class CaptureBackend(enum.Enum):
    AUTO = "auto"  # chosen from what the case holds (rose_usd.plan)
    RGBD = "rgbd"  # depth sensor video: keyframe RGB-D tracking + pose graph
    MEGASAM = "megasam"  # import MegaSaM's cameras and depth, metric by a robust alpha/beta fit
    SFM = "sfm"  # RGB only: static, near-static (plane PnP) or structure from motion (COLMAP); scale from priors
    ORACLE = "oracle"  # ground-truth cameras and gravity from gt/ (benchmark cases)


class GravityMethod(enum.Enum):
    AUTO = "auto"  # imu/gravity.txt, else perception/geocalib.json, else the support plane
    PLANE = "plane"
    GEOCALIB = "geocalib"
    IMU = "imu"


class ScaleSource(enum.Enum):
    AUTO = "auto"  # sensor depth, else UniDepth, else an object size prior
    SENSOR = "sensor"
    UNIDEPTH = "unidepth"
    SIZE_PRIOR = "size-prior"


@dataclass(frozen=True, kw_only=True)
class RgbdConfig:
    """Settings of the rgbd backend."""

    track_width: int = 320
    """Images are downscaled by an integer factor to about this width for tracking [px] (default 320)."""
    keyframe_every: int = 8
    """A new keyframe after at most this many frames (default 8)."""
    static_fraction: float = 0.3
    """The camera is static (identity poses, no tracking; capture.static) when at least this
    fraction of the first frame's corners stay within 0.5 px; above 1 never (default 0.3)."""
    depth_shift: bool = True
    """With a static camera, find where the depth lines up with the colour (the moving hand and
    object overlaid) and shift the depth there when it is 2 px or more off; false: take depth/ as
    registered (default true)."""
    repeatable: bool = True
    """Track in a separate process bound to one CPU, so that runs repeat bit for bit (Open3D's
    parallel odometry sums in an order that varies); false: in this process on every CPU, about
    a third faster, not repeatable (default true; Linux only, elsewhere always false)."""


@dataclass(frozen=True, kw_only=True)
class MegasamConfig:
    """Settings of the megasam backend."""

    scale_source: ScaleSource = ScaleSource.AUTO
    """The absolute depth the alpha/beta fit uses (default auto: sensor, UniDepth, size prior)."""


@dataclass(frozen=True, kw_only=True)
class SfmConfig:
    """Settings of the sfm backend (RGB only)."""

    static_fraction: float = 0.3
    """The camera is static when at least this fraction of the first frame's corners stay within
    0.5 px (capture.static) (default 0.3)."""
    near_static_motion: float = 0.08
    """A camera whose view moves by less than this fraction of the image width over the video (the
    lower quartile of its reference frame's corners' displacements) is tracked against its
    support plane, not by structure from motion [-] (default 0.08)."""
    keyframes: int = 60
    """Structure from motion runs over at most this many keyframes; the frames between them are
    interpolated (default 60: 7-Scenes' 200 frames in about a minute on 2 CPU cores)."""
    max_side: int = 640
    """Keyframes are downscaled to this long side for structure from motion [px] (default 640)."""
    level_by_object: bool = True
    """Gravity from one image (vanishing points, or the upright guess) is refined by the tilt of the
    support that lets the prompted object's primitive stand in its silhouette best (default true)."""


@dataclass(frozen=True, kw_only=True)
class CaptureConfig:
    backend: CaptureBackend = CaptureBackend.AUTO
    """Which backend recovers the cameras (default auto: rgbd with depth/, megasam with MegaSaM's output, else sfm)."""
    gravity: GravityMethod = GravityMethod.AUTO
    """Where gravity comes from (default auto: imu, then geocalib, then the support plane)."""
    fov_guess_deg: float = field(default=60.0, metadata=limits(below=180.0))
    """Horizontal field of view assumed when no intrinsics are given [deg] (default 60; a warning is recorded)."""
    depth_max_m: float = 3.0
    """Depth beyond this is ignored for tracking and gravity [m] (default 3)."""
    prompts: tuple[ObjectPrompt, ...] = field(default=(), metadata={"parse": parse_object_prompts})
    """Prompts overriding rose.toml's, as segment.prompts (the command line's --prompt sets both): the
    world's origin is under the prompted object; sfm also takes its metric scale from the object's
    silhouette (default: rose.toml's)."""
    rgbd: RgbdConfig = field(default_factory=RgbdConfig)
    megasam: MegasamConfig = field(default_factory=MegasamConfig)
    sfm: SfmConfig = field(default_factory=SfmConfig)
