"""segment: per-frame object and interactor masks -> layers/masks.usda + masks/."""

from rose_usd.segment.config import SegmentConfig
from rose_usd.stage_api import StageDef

STAGE = StageDef(
    name="segment",
    layer="masks",
    needs=("capture",),
    config=SegmentConfig,
    backends={
        "classical": "rose_usd.segment.classical:run",
        "sam2": "rose_usd.segment.sam2:run",
        "flow": "rose_usd.segment.flow:run",
        "oracle": "rose_usd.segment.oracle:run",
    },
    summary="object and interactor masks per frame -> layers/masks.usda + masks/",
    side_dirs=("masks",),
    needs_by_backend={"flow": ()},
    requires={
        "classical": ("metric-depth",),
        "sam2": ("sam2-masks", "metric-depth"),
        "oracle": ("gt",),
    },  # 2D: RGB and prompts only, for videos without depth
)
