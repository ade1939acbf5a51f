"""``rose.toml``: per-case settings (every key optional; command-line flags override it).

fps = 30
[[objects]]
name = "Mug"                      # prim name under /World/Objects
category = "mug"                  # picks the physics prior
prompt = { frame = 0, box = [212, 140, 300, 232] }   # pixels, x0 y0 x1 y1
# (no [[objects]]: one object named "Object"; objects = [] instead: a static scene)
[backends]
object = "fusion"
[capture]                         # a stage's settings (`rose-usd stages` lists them)
depth_max_m = 2.5
[object.fusion]                   # settings of one backend of the stage
revolution_tolerance = 0.04
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from rose_usd.errors import ConfigError
from rose_usd.usd.paths import check_name

CASE_CONFIG_FILE = "rose.toml"
_TOP_KEYS = {"fps", "objects", "backends"}
_OBJECT_KEYS = {
    "name",
    "category",
    "prompt",
    "mass_kg",
    "density_kg_m3",
    "friction",
    "restitution",
    "hollow",
    "size_m",
    "mesh",
    "mesh_up",
}


@dataclass(frozen=True)
class Prompt:
    """Where the user points at an object: a box or a point on one frame [px]."""

    frame: int = 0
    box: tuple[float, float, float, float] | None = None
    point: tuple[float, float] | None = None


@dataclass(frozen=True)
class ObjectPrompt:
    """A prompt given for one object by name ("" when the case has one object)."""

    name: str
    prompt: Prompt

    def __str__(self) -> str:
        p = self.prompt
        coords = ",".join(f"{v:g}" for v in (p.box if p.box is not None else p.point))
        return f"{self.name + '=' if self.name else ''}{p.frame}:{coords}"


def parse_object_prompts(value) -> tuple[ObjectPrompt, ...]:
    """Prompts from ``"[Name=]frame:x0,y0,x1,y1"`` (a box) or ``"[Name=]frame:x,y"`` (a point)
    items [px], given as one ";"-separated string or a list; ObjectPrompts pass through."""
    items = value.split(";") if isinstance(value, str) else list(value)
    out = []
    for item in items:
        if isinstance(item, ObjectPrompt):
            out.append(item)
            continue
        if not isinstance(item, str):
            raise TypeError(f"prompt {item!r} is not text")
        if not item.strip():
            continue
        name, _, rest = item.strip().rpartition("=")
        frame, sep, coords = rest.partition(":")
        try:
            values = tuple(float(v) for v in coords.split(","))
            frame_i = int(frame)
        except ValueError:
            values, frame_i = (), -1
        if not sep or len(values) not in (2, 4) or frame_i < 0 or not all(math.isfinite(v) for v in values):
            raise ValueError(f"prompt {item.strip()!r} is not [Name=]frame:x0,y0,x1,y1 or [Name=]frame:x,y")
        box, point = (values, None) if len(values) == 4 else (None, values)
        out.append(ObjectPrompt(name.strip(), Prompt(frame=frame_i, box=box, point=point)))
    return tuple(out)


@dataclass(frozen=True)
class ObjectSpec:
    name: str
    category: str = "generic"
    prompt: Prompt | None = None
    overrides: dict = field(default_factory=dict)
    """Values the user fixed: physics (mass_kg, density_kg_m3, friction, restitution, hollow) and
    size_m, the object's largest dimension [m] (a metric scale prior); mesh, the object's mesh file
    (relative to the case) and mesh_up, its up axis ("x", "y", "z", "-x", ... or "auto": each is tried),
    for the imported object backend."""


@dataclass(frozen=True)
class CaseConfig:
    fps: float | None = None
    objects: tuple[ObjectSpec, ...] = (ObjectSpec(name="Object"),)
    backends: dict = field(default_factory=dict)
    """stage name -> backend name."""
    stage_overrides: dict = field(default_factory=dict)
    """stage name -> {config field: value}."""


def load_case_config(case_root: Path, stage_names: tuple[str, ...]) -> CaseConfig:
    """Parse ``<case>/rose.toml`` if present; unknown keys are errors (they are usually typos)."""
    path = Path(case_root) / CASE_CONFIG_FILE
    if not path.is_file():
        return CaseConfig()
    try:
        data = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"not valid TOML ({exc})", path=path, hint="fix the syntax") from None
    unknown = set(data) - _TOP_KEYS - set(stage_names)
    if unknown:
        raise ConfigError(
            f"unknown key(s) {sorted(unknown)}",
            path=path,
            hint=f"allowed: {sorted(_TOP_KEYS)} and stage sections {list(stage_names)}",
        )
    fps = data.get("fps")
    if fps is not None and not (isinstance(fps, (int, float)) and 0 < fps <= 1000):
        raise ConfigError(f"fps = {fps!r} is not a positive frame rate", path=path, hint="write e.g. fps = 30")
    objects = []
    for i, obj in enumerate(data.get("objects", [])):
        if not isinstance(obj, dict) or "name" not in obj:
            raise ConfigError(f"[[objects]] entry {i} has no name", path=path, hint='write name = "Mug"')
        bad = set(obj) - _OBJECT_KEYS
        if bad:
            raise ConfigError(
                f"object {obj['name']!r} has unknown key(s) {sorted(bad)}",
                path=path,
                hint=f"allowed: {sorted(_OBJECT_KEYS)}",
            )
        try:
            check_name(obj["name"])
        except ConfigError as exc:
            raise ConfigError(exc.message, path=path, hint=exc.hint) from None
        prompt = None
        if "prompt" in obj:
            p = obj["prompt"]
            box = tuple(float(v) for v in p["box"]) if "box" in p else None
            point = tuple(float(v) for v in p["point"]) if "point" in p else None
            if (
                (box is None) == (point is None)
                or (box is not None and len(box) != 4)
                or (point is not None and len(point) != 2)
            ):
                raise ConfigError(
                    f"object {obj['name']!r}: prompt needs box = [x0, y0, x1, y1] or point = [x, y]",
                    path=path,
                    hint="give one of them in pixels",
                )
            prompt = Prompt(frame=int(p.get("frame", 0)), box=box, point=point)
        overrides = {k: obj[k] for k in _OBJECT_KEYS - {"name", "category", "prompt"} if k in obj}
        objects.append(
            ObjectSpec(
                name=obj["name"], category=str(obj.get("category", "generic")), prompt=prompt, overrides=overrides
            )
        )
    names = [o.name for o in objects]
    if len(set(names)) != len(names):
        raise ConfigError(f"object names repeat: {names}", path=path, hint="give each object a unique name")
    backends = data.get("backends", {})
    if not isinstance(backends, dict):
        raise ConfigError("[backends] must be a table of stage = backend", path=path, hint='write capture = "oracle"')
    for stage in backends:
        if stage not in stage_names:
            raise ConfigError(
                f"[backends] names unknown stage {stage!r}", path=path, hint=f"stages: {list(stage_names)}"
            )
    overrides = {name: dict(data[name]) for name in stage_names if name in data}
    return CaseConfig(
        fps=float(fps) if fps is not None else None,
        # no [[objects]] at all: one object named "Object"; an explicit ``objects = []``: a static
        # scene (segment finds only the interactor, scene fuses everything else)
        objects=tuple(objects) if "objects" in data else CaseConfig().objects,
        backends=dict(backends),
        stage_overrides=overrides,
    )
