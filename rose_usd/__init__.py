"""rose_usd: a casual video of a person moving an object -> a simulator-ready OpenUSD bundle.

::

    import rose_usd
    result = rose_usd.reconstruct("my-case", "out")    # every stage, auto backends
    print(result.plan, result.gate.summary())
    stage = result.stage                               # the composed Usd.Stage

Importing the package registers rose's codeless USD schemas with OpenUSD and nothing heavier:
mitsuba, drjit, warp, newton and open3d are imported only where they are used. The public names
below load on first use.
"""

import os

# FFmpeg (under OpenCV's video reader) prints its own complaints about a damaged file ("moov atom not
# found", "Invalid NAL unit size") to the terminal before rose's one-line error; quiet unless the
# user asked for them.
os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")

from rose_usd.errors import (  # noqa: E402 (the FFmpeg setting must precede any import of cv2)
    ConfigError,
    EnvironmentProblem,
    InputError,
    MeshError,
    RoseError,
    StageError,
    ValidationError,
)
from rose_usd.usd.schema import register_schemas

__version__ = "0.1.0"

_LAZY = {
    "reconstruct": "rose_usd.api:reconstruct",
    "batch": "rose_usd.batch:batch",
    "Reconstruction": "rose_usd.api:Reconstruction",
    "StageOutcome": "rose_usd.pipeline:StageOutcome",
    "GateResult": "rose_usd.layers.gate:GateResult",
    "STAGES": "rose_usd.registry:STAGES",
    "StageDef": "rose_usd.stage_api:StageDef",
    "open_stage": "rose_usd.usd.stage:open_stage",
    "validate": "rose_usd.usd.validate:validate",
    "ValidationReport": "rose_usd.usd.validate:ValidationReport",
    "inspect": "rose_usd.usd.inspect:dump",
}

__all__ = [
    *_LAZY,
    "RoseError",
    "InputError",
    "ConfigError",
    "StageError",
    "ValidationError",
    "EnvironmentProblem",
    "MeshError",
    "__version__",
]


def __getattr__(name: str):
    if name in _LAZY:
        import importlib

        module, attr = _LAZY[name].split(":")
        value = getattr(importlib.import_module(module), attr)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'rose_usd' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))


register_schemas()
