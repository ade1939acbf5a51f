"""object: metric object meshes with physics priors as rigid bodies -> layers/object.usda."""

from rose_usd.object.config import ObjectConfig
from rose_usd.stage_api import StageDef

STAGE = StageDef(
    name="object",
    layer="object",
    needs=("capture", "segment", "scene"),  # objects are rested on the scene's collider
    config=ObjectConfig,
    backends={
        "fusion": "rose_usd.object.fusion:run",
        "imported": "rose_usd.object.imported:run",
        "silhouette": "rose_usd.object.silhouette:run",
        "oracle": "rose_usd.object.oracle:run",
    },
    summary="object meshes, mass priors, colliders, frame-0 poses -> layers/object.usda",
    side_dirs=("object_textures",),
    requires={"fusion": ("metric-depth",), "imported": ("meshes", "metric-depth"), "oracle": ("gt",)},
)
