from __future__ import annotations

import enum
from dataclasses import dataclass, field

from rose_usd.stage_config import limits


class SceneBackend(enum.Enum):
    AUTO = "auto"  # chosen from what the case holds (rose_usd.plan)
    TSDF = "tsdf"  # fuse static pixels (TSDF), CGAL alpha wrap, 3-NN vertex colors, xatlas texture from the frames
    STEREO = "stereo"  # RGB only: plane-sweep stereo of a moving camera, fused and wrapped as tsdf; else plane
    PLANE = "plane"  # RGB only: the support plane as a textured slab, the rest a textured backdrop (visual only)
    ORACLE = "oracle"  # ground-truth scene parts, materials and lights from gt/ (benchmark cases)


@dataclass(frozen=True, kw_only=True)
class TsdfConfig:
    """Settings of the tsdf backend."""

    voxel_m: float = 0.008
    """TSDF voxel size [m] (default 0.008)."""
    frame_stride: int = 2
    """Fuse every n-th frame (default 2)."""
    mask_margin_px: int = field(default=6, metadata=limits(0))
    """Object and interactor masks are dilated by this many pixels before fusion (default 6)."""
    carve_m: float = field(default=0.01, metadata=limits(0.0))
    """Fused surface above the support this near to points of the object masks is removed [m] (default 0.01)."""
    depth_max_m: float = 5.0
    """Depth beyond this is not fused [m] (default 5: all a Kinect-class sensor gives)."""
    pad_margin_m: float = 0.03
    """Under each object resting on the surface before it is touched, the collider is a flat
    pad at the surface's height around it, over its seen footprint grown by this much [m]; 0: no
    pads (default 0.03: a footprint seen through noisy depth can miss an edge of the object by more
    than a centimetre, and an object whose edge overhangs its pad tips in simulation)."""
    alpha_m: float = 0.03
    """Alpha wrapping's alpha, the largest gap it bridges [m] (default 0.03)."""
    offset_m: float = field(default=0.002, metadata=limits(0.0))
    """Alpha wrapping's offset from the fused surface [m] (default 0.002)."""
    thickness_m: float = 0.02
    """The collider is solidified this far below the fused surface [m] (default 0.02)."""
    max_triangles: int = 60000
    """Triangle budget of the scene mesh (default 60000)."""
    texture_size: int = 2048
    """Baked texture width and height [px] (default 2048)."""
    texture_frames: int = field(default=24, metadata=limits(0))
    """Texels take the median color of their projections into this many frames spread over
    the video; 0: the fused points' 3-NN colors (default 24)."""


@dataclass(frozen=True, kw_only=True)
class PlaneConfig:
    """Settings of the plane backend (RGB only)."""

    backdrop_reach: float = 2.5
    """The support plane reaches this many times the camera's horizontal distance to the world
    origin (0.3-5 m); beyond it the backdrop stands (default 2.5)."""
    object_reach: float = 1.5
    """... and at least this many times the horizontal distance to the farthest foot of an object
    masked in the reference frame (its far side stands on the plane too; default 1.5)."""
    grid_px: float = 16.0
    """Vertex spacing of the support and backdrop grid over the reference image [px] (default 16)."""
    texture_size: int = 2048
    """Long side of the texture [px] (default 2048)."""
    texture_frames: int = 48
    """Texels take the median color over this many frames spread over the video (default 48)."""
    mask_margin_px: int = 6
    """Object and interactor masks are grown by this many pixels before the texture takes a color (default 6)."""
    thickness_m: float = 0.02
    """The support's collider is a slab this thick [m] (default 0.02)."""


@dataclass(frozen=True, kw_only=True)
class StereoConfig:
    """Settings of the stereo backend (RGB only, a moving camera; fusion, wrap and texture take
    scene.tsdf's)."""

    keyframes: int = field(default=24, metadata=limits(2))
    """Reference frames whose depth stereo finds, spread over the video (default 24)."""
    sources: int = field(default=4, metadata=limits(2))
    """Source frames compared with each reference (default 4)."""
    min_baseline: float = field(default=0.05, metadata=limits(0.0))
    """A source camera stands at least this many times the reference camera's distance to the
    world origin from it (the next one twice that) [-] (default 0.05: about 3 deg of parallax)."""
    max_turn_deg: float = field(default=30.0, metadata=limits(0.0, 90.0))
    """... and looks within this many degrees of the reference's direction (default 30)."""
    max_side_px: int = field(default=320, metadata=limits(64))
    """Stereo works on frames downscaled to this long side [px] (default 320)."""
    planes: int = field(default=128, metadata=limits(8))
    """Depth planes swept, even in inverse depth (default 128)."""
    window_px: int = field(default=7, metadata=limits(3))
    """Side of the window compared by ZNCC [px] (default 7)."""
    min_zncc: float = field(default=0.5, metadata=limits(-1.0, 1.0))
    """A depth is kept where its match's ZNCC is at least this (default 0.5)."""
    near: float = field(default=0.2, metadata=limits(0.01))
    """The nearest plane, in times the reference camera's distance to the world origin (default 0.2)."""
    far: float = field(default=4.0, metadata=limits(0.1))
    """The farthest plane, likewise (default 4); beyond ``near``."""
    agree_rel: float = field(default=0.01, metadata=limits(0.0))
    """A depth is kept where a neighbouring reference's depth map agrees within this fraction of
    it (default 0.01)."""
    support_band_m: float = field(default=0.02, metadata=limits(0.0))
    """Stereo's surface more than this above the support as stereo sees it stands on it (the rest
    is the support) [m] (default 0.02: stereo put 95 % of a table 0.6-1 m away within 15 mm)."""
    standing_rel: float = field(default=0.03, metadata=limits(0.0))
    """... and more than this fraction of its distance to the nearest reference camera (default
    0.03: the 90th percentile of stereo's depth error on the realistic suite's tables, 3-5 %)."""
    min_standing_points: int = field(default=30, metadata=limits(1))
    """What stands on the support is stereo's surface in clusters of at least this many fused
    points (voxels); smaller ones are stray matches (default 30)."""
    min_rise_m: float = field(default=0.01, metadata=limits(0.0))
    """... whose highest point rises at least this much over that band [m]: stereo's noise over a
    plain stretch of table makes low sheets (default 0.01)."""
    through_rel: float = field(default=0.05, metadata=limits(0.0))
    """A reference pixel whose depth lies beyond the support plane by more than this fraction of
    the plane's depth sees through it (default 0.05)."""
    support_cell_m: float = field(default=0.02, metadata=limits(0.001))
    """The support is modeled in cells this wide [m] (default 0.02)."""

    def problems(self) -> list[tuple[str, str, str]]:
        """Settings that contradict each other: (setting, what is wrong, the fix)."""
        if self.far <= self.near:
            return [("far", f"= {self.far:g} is not beyond near = {self.near:g}", "give a far above near")]
        return []


@dataclass(frozen=True, kw_only=True)
class SceneConfig:
    backend: SceneBackend = SceneBackend.AUTO
    """Which backend reconstructs the scene (default auto: tsdf with depth, else stereo)."""
    tsdf: TsdfConfig = field(default_factory=TsdfConfig)
    stereo: StereoConfig = field(default_factory=StereoConfig)
    plane: PlaneConfig = field(default_factory=PlaneConfig)
