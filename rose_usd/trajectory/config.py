from __future__ import annotations

import enum
from dataclasses import dataclass, field

from rose_usd.stage_config import limits


class TrajectoryBackend(enum.Enum):
    AUTO = "auto"  # chosen from what the case holds (rose_usd.plan)
    FOUNDATIONPOSE = "foundationpose"  # FoundationPose's ob_in_cam/ (T_cam<-mesh per frame) through the cameras
    TRACKER = "tracker"  # the object mesh registered to its masked metric depth frame by frame
    SILHOUETTE = "silhouette"  # RGB only: the object mesh tracked against its masks by render and compare
    ORACLE = "oracle"  # ground-truth object poses from gt/ (benchmark cases)


@dataclass(frozen=True, kw_only=True)
class TrackerConfig:
    """Settings of the tracker backend."""

    model_points: int = 3000
    """Points sampled on the object mesh to register against (default 3000)."""
    max_points: int = 1500
    """At most this many masked depth points per frame (default 1500)."""
    erode_px: int = field(default=2, metadata=limits(0))
    """The object's mask is eroded by this many pixels (mixed depth at its border) [px] (default 2)."""
    min_points: int = 60
    """A frame with fewer masked depth points is lost (default 60)."""
    min_fitness: float = field(default=0.3, metadata=limits(0.0, 1.0))
    """A fit with fewer observed points within 5 mm of the mesh is lost [-] (default 0.3)."""
    prior_weight: float = field(default=0.001, metadata=limits(0.0))
    """Pull toward the constant-velocity prediction, a fraction of the depth's mean stiffness
    (trace of the ICP Hessian / 6) [-] (default 0.001)."""
    flow_weight: float = field(default=10.0, metadata=limits(0.0))
    """Each coordinate of a corner of the object's texture followed from the previous frame
    (Lucas-Kanade) weighs as much as this many masked depth points in the registration; 0 turns
    it off. Not used for categories that are solids of revolution (can, cup, bottle, ...) [-]
    (default 10)."""
    smooth_window: int = 5
    """Frames in the centered SE(3) smoothing window; below 3 no smoothing (default 5)."""
    release_frames: int = field(default=10, metadata=limits(0))
    """An object may move for this many frames after the interactor last touched it (it
    settles) (default 10)."""
    max_turn_deg_s: float = field(default=360.0, metadata=limits(0.0))
    """A re-acquired pose is turned from the last tracked one by at most this rate times the time
    the object was hidden: a hand seldom turns an object faster [deg/s] (default 360)."""
    slide_span_m: float = field(default=0.03, metadata=limits(0.0))
    """Where depth leaves a direction free (a can seen only by its wall), slide the pose
    along it up to this far to where fitness plus silhouette IoU is best; 0 turns it off and
    tracks 2-3 times faster [m] (default 0.03)."""


@dataclass(frozen=True, kw_only=True)
class SilhouetteConfig:
    """Settings of the silhouette backend (RGB only)."""

    color_weight: float = 0.7
    """The silhouette is compared with this much of the color posterior P(object | color) (object
    and surroundings' color histograms from the first frame) plus the rest of the mask, by soft
    IoU; 0: the mask alone (default 0.7: the posterior follows an object the masks lose)."""
    edge_weight: float = field(default=1.0, metadata=limits(0.0))
    """Each refit is refined with this times how far its outline lies from the frame's image
    edges of its direction (``geometry.silhouette.fit_edges``, 0-1) added to 1 - IoU: the
    outline put on the object's contour where the mask's is a pixel or two off. A given mesh's
    only: a category proxy is the object's shape only roughly [-] (default 1; 0: off)."""
    hold_drop: float = 0.04
    """The pose holds while its silhouette IoU with the frame's target is within this fraction of
    the first frame's IoU of where it was when set [-] (default 0.04)."""
    min_iou: float = 0.5
    """A fit under this fraction of the first frame's IoU is lost: the pose holds, confidence 0
    [-] (default 0.5)."""
    min_pixels: int = 50
    """A mask with fewer pixels is lost (default 50)."""
    maxfev: int = 160
    """Cost evaluations of each 6-DoF fit, per start (default 160)."""
    turn_search_below: float = 0.9
    """A fit under this fraction of the last IoU is tried again from turned starts [-] (default 0.9)."""
    turn_search_deg: float = 25.0
    """... the best pose turned by this much both ways about each camera axis [deg] (default 25)."""
    max_speed_m_s: float = field(default=3.0, metadata=limits(0.0))
    """A fit that moves the object faster than this since its last tracked frame is lost: a hand
    seldom carries an object faster, and a silhouette grown by a mask that took the hand is fitted
    by moving the object toward the camera [m/s] (default 3)."""
    max_side_px: int = 320
    """Each frame's view is cropped around the mask and downscaled to this long side [px] (default 320)."""
    max_faces: int = 1000
    """The mesh is decimated to this many triangles for its silhouettes (default 1000)."""
    settle_frames: int = 8
    """An object still for this many frames near the support is set down on it (default 8)."""
    settle_m: float = 0.02
    """... when its lowest point is within this of the support [m] (default 0.02)."""
    start_gain: float = 0.03
    """Where the default pose holds the object ``settle_m`` clear of the support and of any object
    under it (in the hand at the start), the first frame's pose is fitted free from it and taken
    when its IoU is higher by this much [-] (default 0.03)."""


@dataclass(frozen=True, kw_only=True)
class TrajectoryConfig:
    backend: TrajectoryBackend = TrajectoryBackend.AUTO
    """Which backend tracks the object(s) (default auto)."""
    tracker: TrackerConfig = field(default_factory=TrackerConfig)
    silhouette: SilhouetteConfig = field(default_factory=SilhouetteConfig)
