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

import difflib
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from rose_usd.errors import ConfigError
from rose_usd.usd.paths import check_object_name

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
    "mesh_units",
}
_SPEC_KEYS = {"name", "category", "prompt"}


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
    (relative to the case), mesh_up, its up axis ("x", "y", "z", "-x", ... or "auto": each is tried),
    and mesh_units, its file's unit ("m", "cm", "mm", "in" or "auto": meters when plausible, else
    guessed from its size), for the backends that use a mesh file."""


@dataclass(frozen=True)
class CaseConfig:
    fps: float | None = None
    objects: tuple[ObjectSpec, ...] = (ObjectSpec(name="Object"),)
    backends: dict = field(default_factory=dict)
    """stage name -> backend name."""
    stage_overrides: dict = field(default_factory=dict)
    """stage name -> {config field: value}."""
    path: Path | None = None
    """The rose.toml these values came from (None: no rose.toml)."""


def _fail(path: Path, message: str, hint: str) -> ConfigError:
    return ConfigError(message, path=path, hint=hint)


def _did_you_mean(unknown, known) -> str:
    """The start of a hint naming the known key each unknown one is a near miss of (a typo), or ""."""
    pairs = [(k, difflib.get_close_matches(k, sorted(known), n=1, cutoff=0.6)) for k in sorted(unknown)]
    close = [f"{m[0]!r} for {k!r}" if len(pairs) > 1 else repr(m[0]) for k, m in pairs if m]
    return f"did you mean {', '.join(close)}? " if close else ""


def _number(value, where: str, path: Path, *, hint: str) -> float:
    """A finite TOML number (int or float, never a boolean or text)."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise _fail(path, f"{where} = {_show(value)} is not a number", hint)
    if not math.isfinite(value):
        raise _fail(path, f"{where} = {_show(value)} is not finite", hint)
    return float(value)


def _integer(value, where: str, path: Path, *, hint: str) -> int:
    """A TOML integer (1.5, true and "1" are refused; 2.0 is 2)."""
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise _fail(path, f"{where} = {_show(value)} is not a whole number", hint)
    if isinstance(value, float) and not value.is_integer():
        raise _fail(path, f"{where} = {_show(value)} is not a whole number", hint)
    return int(value)


def _show(value) -> str:
    """A value as the user wrote it in TOML (true, "text", 1.5, nan)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)
    if isinstance(value, str):
        return '"' + value[:40] + ('..."' if len(value) > 40 else '"')
    if isinstance(value, dict):
        return "a table"
    if isinstance(value, list):
        if len(value) <= 8 and not any(isinstance(v, (list, dict)) for v in value):
            return "[" + ", ".join(_show(v) for v in value) + "]"
        return f"a list of {len(value)} items"
    return repr(value)


def _check_physics(name: str, key: str, value, path: Path) -> object:
    """One physics or shape override of an [[objects]] entry, typed and range-checked."""
    where = f"object {name!r}: {key}"
    rule = _PHYSICS_RULES.get(key)
    if rule is not None:
        low, high, low_open, hint = rule
        number = _number(value, where, path, hint=hint)
        if key == "size_m" and number > high:
            raise _fail(
                path,
                f"{where} = {_show(value)} is more than an object a hand moves ({high:g} m)",
                f"size_m is in meters: {number:g} cm is size_m = {number / 100:g}",
            )
        if (number <= low if low_open else number < low) or number > high:
            raise _fail(path, f"{where} = {_show(value)} is out of range", hint)
        return number
    if key == "hollow":
        if not isinstance(value, bool):
            raise _fail(
                path, f"{where} = {_show(value)} is not a boolean", hint="write hollow = true or hollow = false"
            )
        return value
    if key == "mesh":
        if not isinstance(value, str) or not value.strip():
            raise _fail(path, f"{where} = {_show(value)} is not a file name", hint='write mesh = "perception/Mug.glb"')
        return value
    if key == "mesh_up":
        text = value.strip().lower() if isinstance(value, str) else None
        if text is None or (text != "auto" and text.lstrip("+-") not in ("x", "y", "z")) or text.count("-") > 1:
            raise _fail(
                path,
                f"{where} = {_show(value)} is not an axis",
                hint='write mesh_up = "x", "y", "z", "-x", "-y", "-z" or "auto"',
            )
        return text
    if key == "mesh_units":
        text = value.strip().lower() if isinstance(value, str) else None
        if text not in ("m", "cm", "mm", "in", "auto"):
            raise _fail(
                path,
                f"{where} = {_show(value)} is not a unit",
                hint='write mesh_units = "m", "cm", "mm", "in" or "auto"',
            )
        return text
    raise AssertionError(key)


_PHYSICS_RULES = {
    # key: (lowest, highest, lowest excluded, hint)
    "mass_kg": (0.0, 1e4, True, "write the object's mass in kilograms, e.g. mass_kg = 0.25"),
    "density_kg_m3": (0.0, 1e5, True, "write a density in kg/m^3, e.g. density_kg_m3 = 700"),
    "friction": (0.0, 10.0, False, "write a friction coefficient of 0 or more, e.g. friction = 0.5"),
    "restitution": (0.0, 1.0, False, "write a restitution between 0 and 1, e.g. restitution = 0.2"),
    "size_m": (0.0, 2.0, True, "write the object's largest dimension in meters, e.g. size_m = 0.06"),
}


def _prompt(name: str, p, path: Path) -> Prompt:
    hint = "write prompt = { frame = 0, box = [x0, y0, x1, y1] } or { frame = 0, point = [x, y] } in pixels"
    if not isinstance(p, dict):
        raise _fail(path, f"object {name!r}: prompt = {_show(p)} is not a table", hint)
    bad = set(p) - {"frame", "box", "point"}
    if bad:
        raise _fail(path, f"object {name!r}: prompt has unknown key(s) {sorted(bad)}", hint)
    frame = _integer(p.get("frame", 0), f"object {name!r}: prompt frame", path, hint=hint)
    if frame < 0:
        raise _fail(path, f"object {name!r}: prompt frame = {frame} is negative", hint)
    coords = {}
    for key, size in (("box", 4), ("point", 2)):
        if key not in p:
            continue
        values = p[key]
        if not isinstance(values, list) or len(values) != size:
            raise _fail(path, f"object {name!r}: prompt {key} = {_show(values)} is not a list of {size} numbers", hint)
        coords[key] = tuple(_number(v, f"object {name!r}: prompt {key}", path, hint=hint) for v in values)
        if any(v < 0 for v in coords[key]):
            raise _fail(path, f"object {name!r}: prompt {key} {list(coords[key])} has a negative pixel", hint)
    if len(coords) != 1:
        raise _fail(path, f"object {name!r}: prompt needs box = [x0, y0, x1, y1] or point = [x, y]", hint)
    box = coords.get("box")
    if box is not None and not (box[0] < box[2] and box[1] < box[3]):
        raise _fail(path, f"object {name!r}: prompt box {list(box)} is empty (x0 < x1 and y0 < y1)", hint)
    return Prompt(frame=frame, box=box, point=coords.get("point"))


def _object(i: int, obj, path: Path) -> ObjectSpec:
    if not isinstance(obj, dict):
        raise _fail(
            path,
            f"objects entry {i} is {_show(obj)}, not a table",
            hint='write each object as [[objects]] with name = "Mug"',
        )
    name = obj.get("name")
    if not isinstance(name, str) or not name:
        raise _fail(
            path,
            f"[[objects]] entry {i} has {'no name' if name is None else f'name = {_show(name)}'}",
            hint='write name = "Mug" (letters, digits, underscores)',
        )
    bad = set(obj) - _OBJECT_KEYS
    if bad:
        raise _fail(
            path,
            f"object {name!r} has unknown key(s) {sorted(bad)}",
            hint=f"{_did_you_mean(bad, _OBJECT_KEYS)}allowed: {sorted(_OBJECT_KEYS)}",
        )
    try:
        check_object_name(name)
    except ConfigError as exc:
        raise ConfigError(exc.message, path=path, hint=exc.hint) from None
    category = obj.get("category", "generic")
    if not isinstance(category, str) or not category.strip():
        raise _fail(path, f"object {name!r}: category = {_show(category)} is not text", hint='write category = "mug"')
    prompt = _prompt(name, obj["prompt"], path) if "prompt" in obj else None
    overrides = {k: _check_physics(name, k, obj[k], path) for k in sorted(_OBJECT_KEYS - _SPEC_KEYS) if k in obj}
    return ObjectSpec(name=name, category=category.strip(), prompt=prompt, overrides=overrides)


def _read_toml(path: Path) -> dict:
    try:
        text = path.read_bytes().decode("utf-8")
    except UnicodeDecodeError as exc:
        raise _fail(
            path, f"not UTF-8 text (byte 0x{exc.object[exc.start]:02x} at offset {exc.start})", "save it as UTF-8"
        ) from None
    except OSError as exc:
        raise _fail(path, f"cannot read it ({exc.strerror})", "check the file's permissions") from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise _fail(path, f"not valid TOML ({exc})", "fix the syntax") from None


def load_case_config(case_root: Path, stage_names: tuple[str, ...], file: Path | None = None) -> CaseConfig:
    """Parse ``<case>/rose.toml`` (or ``file``) if present, against its schema: every key known
    (unknown keys are usually typos), every value of its type and in its range; one ConfigError
    naming the file and the fix otherwise. Stage settings are type-checked by the pipeline (their
    dataclasses)."""
    path = Path(file) if file is not None else Path(case_root) / CASE_CONFIG_FILE
    if not path.is_file():
        return CaseConfig()
    data = _read_toml(path)
    unknown = set(data) - _TOP_KEYS - set(stage_names)
    if unknown:
        raise _fail(
            path,
            f"unknown key(s) {sorted(unknown)}",
            hint=f"{_did_you_mean(unknown, _TOP_KEYS | set(stage_names))}allowed: {sorted(_TOP_KEYS)}"
            f" and stage sections {list(stage_names)}",
        )
    for stage in stage_names:
        if stage in data and not isinstance(data[stage], dict):
            raise _fail(
                path,
                f"{stage} = {_show(data[stage])} at the top level sets nothing",
                hint=f'a backend goes in [backends] ({stage} = "..."), settings in a [{stage}] table',
            )
    fps = data.get("fps")
    if fps is not None:
        fps = _number(fps, "fps", path, hint="write e.g. fps = 30")
        if not 0 < fps <= 1000:
            raise _fail(path, f"fps = {fps:g} is not a frame rate", hint="write e.g. fps = 30")
    raw_objects = data.get("objects", [])
    if isinstance(raw_objects, dict):
        raise _fail(
            path,
            "[objects] is a single table",
            hint='write [[objects]] (double brackets) before each object, e.g. [[objects]] name = "Mug"',
        )
    if not isinstance(raw_objects, list):
        raise _fail(
            path, f"objects = {_show(raw_objects)} is not a list of objects", hint='write [[objects]] name = "Mug"'
        )
    objects = [_object(i, obj, path) for i, obj in enumerate(raw_objects)]
    names = [o.name.lower() for o in objects]
    if len(set(names)) != len(names):
        raise _fail(
            path,
            f"object names repeat: {[o.name for o in objects]}",
            hint="give each object a unique name (names that differ only in case count as one)",
        )
    backends = data.get("backends", {})
    if not isinstance(backends, dict):
        raise _fail(path, "[backends] must be a table of stage = backend", hint='write capture = "oracle"')
    for stage, backend in backends.items():
        if stage not in stage_names:
            raise _fail(path, f"[backends] names unknown stage {stage!r}", hint=f"stages: {list(stage_names)}")
        if not isinstance(backend, str):
            raise _fail(
                path, f"[backends] {stage} = {_show(backend)} is not a backend name", hint=f'write {stage} = "auto"'
            )
    overrides = {name: dict(data[name]) for name in stage_names if name in data}
    return CaseConfig(
        fps=fps,
        # no [[objects]] at all: one object named "Object"; an explicit ``objects = []``: a static
        # scene (segment finds only the interactor, scene fuses everything else)
        objects=tuple(objects) if "objects" in data else CaseConfig().objects,
        backends=dict(backends),
        stage_overrides=overrides,
        path=path,
    )
