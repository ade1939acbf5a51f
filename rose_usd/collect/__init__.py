"""collect: robot demonstrations in Newton that follow the reconstructed trajectory -> layers/robot.usda + dataset/."""

from rose_usd.collect.config import CollectConfig
from rose_usd.stage_api import StageDef

STAGE = StageDef(
    name="collect",
    layer="robot",
    needs=("capture", "scene", "object", "trajectory", "gate"),
    config=CollectConfig,
    backends={"newton": "rose_usd.collect.newton_backend:run"},
    summary="where the gate passed, a Franka Panda grasps the object and follows its path in Newton"
    " -> layers/robot.usda + dataset/",
    side_dirs=("dataset",),
)
