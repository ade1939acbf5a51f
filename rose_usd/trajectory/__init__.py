"""trajectory: each object's time-aligned 6-DoF pose in the world -> layers/trajectory.usda + trajectory/*.tum."""

from rose_usd.stage_api import StageDef
from rose_usd.trajectory.config import TrajectoryConfig

STAGE = StageDef(
    name="trajectory",
    layer="trajectory",
    needs=("capture", "segment", "object"),
    config=TrajectoryConfig,
    backends={
        "foundationpose": "rose_usd.trajectory.foundationpose:run",
        "tracker": "rose_usd.trajectory.tracker:run",
        "silhouette": "rose_usd.trajectory.silhouette:run",
        "oracle": "rose_usd.trajectory.oracle:run",
    },
    summary="object poses per frame (time samples) and TUM export -> layers/trajectory.usda",
    side_dirs=("trajectory",),
    requires={"tracker": ("metric-depth",), "foundationpose": ("poses",), "oracle": ("gt",)},
)
