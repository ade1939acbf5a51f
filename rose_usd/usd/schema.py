"""rose's codeless USD schemas: where they live, their registration, their names.

The source of truth is ``schemas/schema.usda`` (package data); ``generatedSchema.usda`` and
``plugInfo.json`` beside it are produced from it by usdGenSchema (shipped with usd-core) through :func:`regenerate`.
Run ``python -m rose_usd.usd.schema --regenerate`` after editing the schema.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile
import warnings
from pathlib import Path

from rose_usd.errors import EnvironmentProblem

# Applied API schema identifiers (schemas/schema.usda). Stage code names them only through these.
WORLD_API = "RoseWorldAPI"
CAMERA_API = "RoseCameraAPI"
PHYSICS_PRIOR_API = "RosePhysicsPriorAPI"
TRAJECTORY_API = "RoseTrajectoryAPI"
MASK_API = "RoseMaskAPI"
GATE_API = "RoseGateAPI"
SUPPORT_API = "RoseSupportAPI"
COLLECT_API = "RoseCollectAPI"
SHAPE_API = "RoseShapeAPI"
ALL_APIS = (
    WORLD_API,
    CAMERA_API,
    PHYSICS_PRIOR_API,
    TRAJECTORY_API,
    MASK_API,
    GATE_API,
    SUPPORT_API,
    COLLECT_API,
    SHAPE_API,
)

_GENERATED = ("generatedSchema.usda", "plugInfo.json")
_registered = False


def schema_dir() -> Path:
    """The folder holding schema.usda, generatedSchema.usda and plugInfo.json (package data:
    ``rose_usd/schemas``, which in a checkout links to the top-level ``schemas/``)."""
    folder = Path(__file__).resolve().parents[1] / "schemas"
    if not (folder / "schema.usda").is_file():
        raise EnvironmentProblem(
            "rose's USD schema files (schemas/schema.usda) are missing from the installed package",
            path=folder,
            hint="reinstall rose_usd (pip install .) from a full checkout or its wheel",
        )
    return folder


def register_schemas() -> None:
    """Register rose's schemas with OpenUSD's plugin registry (idempotent)."""
    global _registered
    if _registered:
        return
    from pxr import Plug

    if not (schema_dir() / "plugInfo.json").is_file():
        # only while bootstrapping the generated files; stages written now would fail validation
        warnings.warn(
            f"{schema_dir()}/plugInfo.json is missing: run python -m rose_usd.usd.schema --regenerate", stacklevel=2
        )
        return

    Plug.Registry().RegisterPlugins([schema_dir().as_posix()])
    _registered = True


def regenerate(out_dir: Path | None = None) -> Path:
    """Run usdGenSchema on schemas/schema.usda and write the generated files into ``out_dir``.

    Args:
        out_dir: where to write generatedSchema.usda and plugInfo.json; the schema folder if None.

    Returns:
        The folder written.
    """
    src = schema_dir()
    out_dir = Path(out_dir) if out_dir is not None else src
    with tempfile.TemporaryDirectory() as tmp:
        # usdGenSchema must not see our already-registered plugin while it regenerates it
        env = dict(os.environ, PXR_PLUGINPATH_NAME="")
        proc = subprocess.run(
            [sys.executable, "-m", "pxr.Usd.usdGenSchema", "--quiet", str(src / "schema.usda"), tmp],
            capture_output=True,
            text=True,
            env=env,
            cwd=src,
        )
        if proc.returncode != 0:
            raise EnvironmentProblem(
                "usdGenSchema failed: "
                + (proc.stderr.strip().splitlines()[-1] if proc.stderr.strip() else str(proc.returncode)),
                path=src / "schema.usda",
                hint="fix the schema file",
            )
        plug = json.loads(_strip_comments((Path(tmp) / "plugInfo.json").read_text()))
        for plugin in plug["Plugins"]:
            # a resource-only plugin: no library, resources beside plugInfo.json
            plugin.update({"LibraryPath": "", "ResourcePath": ".", "Root": "."})
        out_dir.mkdir(parents=True, exist_ok=True)
        (out_dir / "plugInfo.json").write_text(json.dumps(plug, indent=4, sort_keys=True) + "\n")
        shutil.copyfile(Path(tmp) / "generatedSchema.usda", out_dir / "generatedSchema.usda")
    return out_dir


def _strip_comments(text: str) -> str:
    return "\n".join(line for line in text.splitlines() if not line.lstrip().startswith("#"))


if __name__ == "__main__":  # pragma: no cover - developer tool
    if "--regenerate" not in sys.argv:
        print("usage: python -m rose_usd.usd.schema --regenerate")
        sys.exit(2)
    print(f"wrote {regenerate()}")
