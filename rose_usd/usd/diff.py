"""``rose-usd diff``: compare the contents of two stages (or their dumps) with tolerances."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any

from rose_usd.errors import InputError
from rose_usd.usd.inspect import dump, normalize


def load_dump(path: str | os.PathLike) -> dict[str, Any]:
    """A normalized dump of a stage file (.usd/.usda/.usdc) or of a saved dump (.json)."""
    path = Path(path)
    hint = "give a stage file or the output of `rose-usd inspect --json`"
    if path.suffix.lower() == ".json":
        try:
            data = json.loads(path.read_bytes().decode("utf-8"))
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise InputError(f"not a JSON dump ({exc})", path=path, hint=hint) from None
        missing = [k for k in DUMP_KEYS if not isinstance(data, dict) or k not in data]
        if missing or not isinstance(data.get("prims"), dict) or not isinstance(data.get("layers"), list):
            raise InputError(
                "not a dump of a stage (it lacks " + ", ".join(repr(k) for k in missing or ["prims", "layers"]) + ")",
                path=path,
                hint=hint,
            )
        return normalize(data)
    return normalize(dump(path))


DUMP_KEYS = ("metadata", "layers", "prims")
"""What every ``rose-usd inspect --json`` dump holds."""


def _flatten(data: Any, prefix: str = "") -> dict[str, Any]:
    if isinstance(data, dict):
        out = {}
        for k, v in data.items():
            out.update(_flatten(v, f"{prefix}/{k}" if prefix else str(k)))
        return out
    if isinstance(data, list) and data and all(isinstance(v, (dict, list)) for v in data):
        out = {f"{prefix}#len": len(data)}
        for i, v in enumerate(data):
            out.update(_flatten(v, f"{prefix}[{i}]"))
        return out
    return {prefix: data}


def _close(a: Any, b: Any, rtol: float, atol: float) -> bool:
    if isinstance(a, bool) or isinstance(b, bool):
        return a == b
    if isinstance(a, (int, float)) and isinstance(b, (int, float)):
        if isinstance(a, float) and isinstance(b, float) and (math.isnan(a) or math.isnan(b)):
            return math.isnan(a) and math.isnan(b)
        return abs(a - b) <= atol + rtol * abs(b)
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(_close(x, y, rtol, atol) for x, y in zip(a, b))
    return a == b


def _tolerance(
    key: str, tolerances: dict[str, tuple[float, float]] | None, rtol: float, atol: float
) -> tuple[float, float]:
    for pattern, tol in (tolerances or {}).items():
        if pattern in key:
            return tol
    return rtol, atol


def compare(
    a: dict[str, Any],
    b: dict[str, Any],
    *,
    rtol: float = 1e-4,
    atol: float = 1e-6,
    ignore: tuple[str, ...] = (),
    tolerances: dict[str, tuple[float, float]] | None = None,
) -> list[str]:
    """Differences between two normalized dumps, one line each (empty when equal within tolerance).

    Args:
        rtol, atol: numbers match when |a - b| <= atol + rtol * |b|.
        ignore: key-path substrings to skip (e.g. ``"/config/"``).
        tolerances: key-path substring -> (rtol, atol) for keys that need their own (first match wins).
    """
    fa, fb = _flatten(a), _flatten(b)
    lines = []
    for key in sorted(set(fa) | set(fb)):
        if any(pattern in key for pattern in ignore):
            continue
        if key not in fb:
            lines.append(f"- {key}: {fa[key]!r}")
        elif key not in fa:
            lines.append(f"+ {key}: {fb[key]!r}")
        elif not _close(fa[key], fb[key], *_tolerance(key, tolerances, rtol, atol)):
            lines.append(f"~ {key}: {fa[key]!r} -> {fb[key]!r}")
    return lines
