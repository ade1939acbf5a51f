"""gate: re-render SSIM against the video, physical and geometric checks -> layers/gate.usda + report/."""

from rose_usd.gate.config import GateConfig
from rose_usd.stage_api import StageDef

STAGE = StageDef(
    name="gate",
    layer="gate",
    needs=("capture", "segment", "scene", "object", "trajectory"),
    config=GateConfig,
    backends={"mitsuba-newton": "rose_usd.gate.run:run"},
    summary="Mitsuba re-render SSIM, track check, Newton rest check, collider check -> layers/gate.usda + report/",
    side_dirs=("report",),
)
