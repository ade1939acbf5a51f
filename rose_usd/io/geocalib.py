"""``geocalib.json`` (formats.md): GeoCalib's single-image calibration of one frame.

``gravity`` is the unit UP vector in OpenCV camera axes (world gravity is its negative); ``rp`` =
[roll, pitch] in radians, GeoCalib's convention: up = (-sin r cos p, -cos r cos p, sin p). Optional:
``K`` 3x3, ``vfov`` [rad], ``roll_uncertainty``/``pitch_uncertainty`` [rad], ``frame`` (default 0).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rose_usd.errors import InputError


def up_from_rp(roll: float, pitch: float) -> np.ndarray:
    """GeoCalib's up vector in OpenCV camera axes from roll and pitch [rad]."""
    return np.array([-np.sin(roll) * np.cos(pitch), -np.cos(roll) * np.cos(pitch), np.sin(pitch)])


def rp_from_up(up: np.ndarray) -> tuple[float, float]:
    """Roll and pitch [rad] of an up vector in OpenCV camera axes (GeoCalib's inverse)."""
    x, y, z = np.asarray(up, dtype=float) / np.linalg.norm(up)
    pitch = float(np.arcsin(np.clip(z, -1.0, 1.0)))
    roll = float(np.arctan2(-x, -y))
    return roll, pitch


@dataclass
class GeoCalib:
    up_cam: np.ndarray
    """Unit up vector in OpenCV camera axes of ``frame``."""
    roll: float
    pitch: float
    frame: int = 0
    K: np.ndarray | None = None
    vfov: float | None = None
    roll_uncertainty: float | None = None
    pitch_uncertainty: float | None = None


def _vector(data: dict, key: str, size: int, path: Path, hint: str) -> np.ndarray:
    value = data[key]
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        arr = None
    if arr is None or arr.shape != (size,) or not np.all(np.isfinite(arr)):
        raise InputError(f"{key!r} is {json.dumps(value)[:60]}, not {size} finite numbers", path=path, hint=hint)
    return arr


def _scalar(data: dict, key: str, path: Path, hint: str, low: float, high: float) -> float | None:
    if key not in data:
        return None
    value = data[key]
    if isinstance(value, bool) or not isinstance(value, int | float) or not low <= value <= high:
        raise InputError(
            f"{key!r} is {json.dumps(value)[:60]}, not a number in [{low:g}, {high:g}]", path=path, hint=hint
        )
    return float(value)


def read_geocalib(path: str | os.PathLike) -> GeoCalib:
    """Read and check ``geocalib.json``: every value of its type and in its range, else one
    InputError naming the file."""
    path = Path(path)
    hint = 'write {"gravity": [x, y, z] (unit up, OpenCV camera axes), "rp": [roll, pitch]}'
    try:
        data = json.loads(path.read_bytes().decode("utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"cannot read geocalib.json ({exc})", path=path, hint=hint) from None
    if not isinstance(data, dict):
        raise InputError("geocalib.json is not a JSON object", path=path, hint=hint)
    if "gravity" not in data:
        raise InputError("geocalib.json has no 'gravity'", path=path, hint=hint)
    up = _vector(data, "gravity", 3, path, hint)
    with np.errstate(over="ignore"):
        norm = float(np.linalg.norm(up))
    if abs(norm - 1.0) > 1e-3:
        raise InputError(f"'gravity' {up.tolist()} is not a unit 3-vector", path=path, hint=hint)
    roll, pitch = _vector(data, "rp", 2, path, hint) if "rp" in data else rp_from_up(up)
    if "rp" in data and np.degrees(np.arccos(np.clip(up @ up_from_rp(roll, pitch), -1, 1))) > 0.5:
        raise InputError(
            "'gravity' and 'rp' disagree (is 'gravity' the UP vector in OpenCV axes?)", path=path, hint=hint
        )
    frame = data.get("frame", 0)
    if isinstance(frame, bool) or not isinstance(frame, int) or frame < 0:
        raise InputError(f"'frame' is {json.dumps(frame)[:40]}, not a frame index", path=path, hint=hint)
    K = None
    if "K" in data:
        K = _vector({"K": np.asarray(data["K"], dtype=object).reshape(-1).tolist()}, "K", 9, path, hint)
        K = K.reshape(3, 3)
        if K[0, 0] <= 0 or K[1, 1] <= 0:
            raise InputError("'K' has a focal length that is not positive", path=path, hint=hint)
    return GeoCalib(
        up_cam=up,
        roll=float(roll),
        pitch=float(pitch),
        frame=frame,
        K=K,
        vfov=_scalar(data, "vfov", path, hint, 1e-3, np.pi - 1e-3),
        roll_uncertainty=_scalar(data, "roll_uncertainty", path, hint, 0.0, np.pi),
        pitch_uncertainty=_scalar(data, "pitch_uncertainty", path, hint, 0.0, np.pi),
    )


def write_geocalib(path: str | os.PathLike, calib: GeoCalib) -> None:
    data = {"gravity": [float(v) for v in calib.up_cam], "rp": [calib.roll, calib.pitch], "frame": calib.frame}
    if calib.K is not None:
        data["K"] = np.asarray(calib.K, dtype=float).tolist()
    if calib.vfov is not None:
        data["vfov"] = calib.vfov
    if calib.roll_uncertainty is not None:
        data["roll_uncertainty"] = calib.roll_uncertainty
    if calib.pitch_uncertainty is not None:
        data["pitch_uncertainty"] = calib.pitch_uncertainty
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    Path(path).write_text(json.dumps(data, indent=2) + "\n")
