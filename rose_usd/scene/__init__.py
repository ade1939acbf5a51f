"""scene: the static, collidable, colored scene mesh (and its lighting) -> layers/scene.usda."""

from rose_usd.scene.config import SceneConfig
from rose_usd.stage_api import StageDef

STAGE = StageDef(
    name="scene",
    layer="scene",
    needs=("capture", "segment"),
    config=SceneConfig,
    backends={
        "tsdf": "rose_usd.scene.tsdf:run",
        "stereo": "rose_usd.scene.stereo:run",
        "plane": "rose_usd.scene.plane:run",
        "oracle": "rose_usd.scene.oracle:run",
    },
    summary="static collidable colored scene mesh and lights -> layers/scene.usda",
    side_dirs=("textures",),
    requires={"tsdf": ("metric-depth",), "oracle": ("gt",)},
)
