"""Stage configs: built from settings (rose.toml, ``--set``, the Python API), type-checked, and
hashed for staleness.

A stage config is a frozen dataclass with a ``backend`` enum, the fields every backend of the stage
reads, and one nested frozen dataclass per backend that has settings of its own, in a field named
after the backend (``ObjectConfig.fusion``). A setting is addressed ``field`` or
``backend.field`` (``--set object.fusion.voxel_m=0.003``, ``[object.fusion]`` in rose.toml). The
staleness hash and the layer's provenance cover the shared fields and the running backend's
nested config only: a setting of another backend never makes a layer stale.

Values are converted to the field's type only where nothing is lost: ``"3"`` and ``3.0`` make an
int 3, ``2.9`` is an error; a field may name its own parser in ``metadata["parse"]``. Numbers are
range-checked: an int must be at least 1 and a float above 0 unless the field's metadata says
otherwise (``min``/``max`` inclusive, ``below`` exclusive), so ``track_width = 0`` or
``depth_max_m = -1`` is a one-line error, not a crash or a silent nonsense run. Settings that must
agree with each other (a nearest depth below the farthest) are checked by the config class's own
``problems()``.
"""

from __future__ import annotations

import dataclasses
import difflib
import enum
import functools
import hashlib
import json
import math
import typing
from collections.abc import Mapping
from typing import Any

from rose_usd.errors import ConfigError


def backend_configs(cls: type) -> dict[str, type]:
    """Field name -> nested config class, for each backend that has one."""
    hints = _hints(cls)
    return {
        f.name: hints[f.name]
        for f in dataclasses.fields(cls)
        if isinstance(hints[f.name], type) and dataclasses.is_dataclass(hints[f.name])
    }


@functools.cache
def _hints(cls: type) -> dict[str, Any]:
    return typing.get_type_hints(cls)


def _plain(value: Any) -> Any:
    """JSON-ready: enums by value, dataclasses as dicts, tuples as lists."""
    if isinstance(value, enum.Enum):
        return value.value
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: _plain(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    if isinstance(value, Mapping):
        return {str(k): _plain(v) for k, v in value.items()}
    return value


def config_to_dict(config: Any, *, running_only: bool = True) -> dict[str, Any]:
    """The config as plain values; with ``running_only``, of the nested backend configs only the
    running backend's (what the staleness hash and the provenance cover)."""
    nested = backend_configs(type(config))
    backend = getattr(config, "backend", None)
    backend = backend.value if isinstance(backend, enum.Enum) else backend
    out = {}
    for f in dataclasses.fields(config):
        if f.name in nested and running_only and f.name != backend:
            continue
        out[f.name] = _plain(getattr(config, f.name))
    return out


def config_hash(config: Any) -> str:
    text = json.dumps(config_to_dict(config), sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def setting_names(cls: type) -> list[str]:
    """Every setting of a stage config: ``field`` and ``backend.field``."""
    nested = backend_configs(cls)
    out = []
    for f in dataclasses.fields(cls):
        if f.name in nested:
            out += [f"{f.name}.{g.name}" for g in dataclasses.fields(nested[f.name])]
        else:
            out.append(f.name)
    return out


def setting_docs(cls: type) -> dict[str, str]:
    """Every setting of a stage config (``setting_names``) -> the docstring under its field in
    the source, whitespace collapsed ("" where there is none)."""
    nested = backend_configs(cls)
    docs = _field_docs(cls)
    out = {}
    for name in setting_names(cls):
        owner, _, field_name = name.rpartition(".")
        out[name] = (_field_docs(nested[owner]) if owner else docs).get(field_name, "")
    return out


@functools.cache
def _field_docs(cls: type) -> dict[str, str]:
    import ast
    import inspect
    import textwrap

    try:
        tree = ast.parse(textwrap.dedent(inspect.getsource(cls)))
    except (OSError, TypeError):  # no source (a frozen install)
        return {}
    body = tree.body[0].body if tree.body and isinstance(tree.body[0], ast.ClassDef) else []
    out = {}
    for node, after in zip(body, body[1:]):
        if isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
            if (
                isinstance(after, ast.Expr)
                and isinstance(after.value, ast.Constant)
                and isinstance(after.value.value, str)
            ):
                out[node.target.id] = " ".join(after.value.value.split())
    return out


def flatten(overrides: Mapping[str, Any], names: list[str] | None = None, prefix: str = "") -> dict[str, Any]:
    """{"fusion": {"voxel_m": 1}} and {"fusion.voxel_m": 1} alike as {"fusion.voxel_m": 1}; a
    table given for a setting of ``names`` (a mapping-valued setting) stays whole."""
    out = {}
    for key, value in overrides.items():
        name = f"{prefix}{str(key).strip().replace('-', '_')}"
        if isinstance(value, Mapping) and not (names and name in names):
            out.update(flatten(value, names, name + "."))
        else:
            out[name] = value
    return out


def build_config(
    stage: str, cls: type, overrides: Mapping[str, Any], *, source: str | None, strict: bool = False
) -> Any:
    """``cls`` with ``overrides`` (setting -> value, see :func:`flatten`) applied and type-checked;
    with ``strict`` (values from TOML, which has types) text is not read as a number or a boolean."""
    nested = backend_configs(cls)
    names = setting_names(cls)
    shared: dict[str, Any] = {}
    per_backend: dict[str, dict[str, Any]] = {}
    for key, value in flatten(overrides, names).items():
        if key not in names:
            raise ConfigError(
                f"stage {stage!r} has no setting {key!r}", path=source, hint=_setting_hint(key, names, stage)
            )
        owner, _, name = key.rpartition(".")
        target_cls = nested[owner] if owner else cls
        field = next(f for f in dataclasses.fields(target_cls) if f.name == name)
        kind = _hints(target_cls)[name]
        if strict and isinstance(value, str) and kind in (bool, int, float):
            raise ConfigError(
                f"{stage}.{key} = {value!r} is text, not a {'boolean' if kind is bool else 'number'}",
                path=source,
                hint=f"write it without quotes (the default is {_plain(_default(field))!r})",
            )
        converted = coerce(f"{stage}.{key}", value, kind, field, source)
        (per_backend.setdefault(owner, {}) if owner else shared)[name] = converted
    for owner, values in per_backend.items():
        shared[owner] = nested[owner](**values)
    return _consistent(stage, cls(**shared), source)


def _consistent(stage: str, config: Any, source: str | None) -> Any:
    """``config``, or a ConfigError for the first setting that contradicts another: a config class
    (or a backend's nested one) may list them in ``problems()``, as (setting, message, hint)."""
    nested = backend_configs(type(config))
    for owner, value in [("", config)] + [(f"{name}.", getattr(config, name)) for name in nested]:
        for name, message, hint in getattr(value, "problems", lambda: [])():
            raise ConfigError(f"{stage}.{owner}{name} {message}", path=source, hint=hint)
    return config


def _setting_hint(key: str, names: list[str], stage: str) -> str:
    """What to say of an unknown setting: the known one it is a near miss of (a moved one: the same
    last part under another backend; a typo), else every setting of the stage."""
    moved = [n for n in names if n.rpartition(".")[2] == key.rpartition(".")[2]]
    if moved:
        return f"did you mean {' or '.join(f'{stage}.{n}' for n in moved)}?"
    close = difflib.get_close_matches(key, names, n=1, cutoff=0.6)  # rose.toml's keys' cutoff: spx -> spp
    if close:
        return f"did you mean {stage}.{close[0]}?"
    return f"settings: {', '.join(names)}"


def limits(minimum: float | None = None, maximum: float | None = None, below: float | None = None) -> dict:
    """Field metadata for a number's range when the default (int >= 1, float > 0) does not fit."""
    out = {}
    if minimum is not None:
        out["min"] = minimum
    if maximum is not None:
        out["max"] = maximum
    if below is not None:
        out["below"] = below
    return out


def _check_range(value: Any, kind: Any, field: dataclasses.Field) -> None:
    if kind not in (int, float) or isinstance(value, bool):
        return
    meta = field.metadata
    if "min" in meta:
        if value < meta["min"]:
            raise ValueError(f"below {meta['min']:g}")
    elif kind is int and value < 1:
        raise ValueError("must be 1 or more")
    elif kind is float and value <= 0:
        raise ValueError("must be above 0")
    if "max" in meta and value > meta["max"]:
        raise ValueError(f"above {meta['max']:g}")
    if "below" in meta and value >= meta["below"]:
        raise ValueError(f"must be below {meta['below']:g}")


def check_config(stage: str, config: Any, *, source: str | None) -> Any:
    """Type- and range-check every field of a config instance (and its backends' nested
    configs), as :func:`build_config` does for the values it is given; returns ``config``."""
    nested = backend_configs(type(config))
    hints = _hints(type(config))
    for f in dataclasses.fields(config):
        value = getattr(config, f.name)
        if f.name in nested:
            if not isinstance(value, nested[f.name]):
                raise ConfigError(
                    f"{stage}.{f.name} is a {type(value).__name__}, not a {nested[f.name].__name__}",
                    path=source,
                    hint=f"give a {nested[f.name].__name__}",
                )
            check_config(f"{stage}.{f.name}", value, source=source)
        elif f.metadata.get("parse") is None:
            coerce(f"{stage}.{f.name}", value, hints[f.name], f, source)
    return _consistent(stage, config, source) if "." not in stage else config


def _default(field: dataclasses.Field) -> Any:
    if field.default is not dataclasses.MISSING:
        return field.default
    if field.default_factory is not dataclasses.MISSING:
        return field.default_factory()
    return None


def coerce(where: str, value: Any, kind: Any, field: dataclasses.Field, source: str | None) -> Any:
    """``value`` as type ``kind``, or a ConfigError naming ``where``; never a lossy conversion,
    never a number out of the field's range."""
    try:
        parse = field.metadata.get("parse")
        if parse is not None:
            return parse(value)
        converted = _convert(value, kind)
        _check_range(converted, kind, field)
        return converted
    except (ValueError, TypeError) as exc:
        allowed = ""
        if isinstance(kind, type) and issubclass(kind, enum.Enum):
            allowed = f" (one of {', '.join(m.value for m in kind)})"
        default = _default(field)
        detail = f": {exc}" if str(exc) and not allowed else ""
        shown = _plain(value) if isinstance(value, enum.Enum) else value
        raise ConfigError(
            f"{where} = {shown!r} is not valid{allowed}{detail}",
            path=source,
            hint=f"the default is {_plain(default)!r}",
        ) from None


def _number(value: Any, what: str) -> float:
    """``value`` (a number, or text holding one) as a float; ValueError(``what``) otherwise."""
    try:
        return float(value.strip()) if isinstance(value, str) else float(value)
    except (TypeError, ValueError):
        raise ValueError(what) from None


def _convert(value: Any, kind: Any) -> Any:
    if isinstance(kind, type) and issubclass(kind, enum.Enum):
        return kind(value.value if isinstance(value, enum.Enum) else value)
    if kind is bool:
        if isinstance(value, bool):
            return value
        if isinstance(value, str) and value.strip().lower() in ("true", "false", "1", "0", "yes", "no"):
            return value.strip().lower() in ("true", "1", "yes")
        raise ValueError("not true or false")
    if kind is int:
        if isinstance(value, bool):
            raise TypeError("not an integer")
        number = _number(value, "not an integer")
        if not number.is_integer():
            raise ValueError("not an integer")
        return int(number)
    if kind is float:
        if isinstance(value, bool):
            raise TypeError("not a number")
        number = _number(value, "not a number")
        if not math.isfinite(number):
            raise ValueError("not finite")
        return number
    if kind is str:
        if not isinstance(value, str):
            raise TypeError("not text")
        return value
    raise TypeError(f"settings of type {kind} need a parser")
