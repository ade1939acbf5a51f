"""capture: per-frame cameras (K_t, G_t), metric scale and the gravity-aligned world -> layers/world.usda."""

from rose_usd.capture.config import CaptureConfig
from rose_usd.stage_api import StageDef

STAGE = StageDef(
    name="capture",
    layer="world",
    needs=(),
    config=CaptureConfig,
    backends={
        "rgbd": "rose_usd.capture.rgbd:run",
        "megasam": "rose_usd.capture.megasam:run",
        "sfm": "rose_usd.capture.sfm:run",
        "oracle": "rose_usd.capture.oracle:run",
    },
    requires={"rgbd": ("sensor-depth",), "megasam": ("megasam",), "oracle": ("gt",)},
    summary="cameras, intrinsics, metric scale and gravity -> layers/world.usda",
)
