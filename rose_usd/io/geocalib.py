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


def read_geocalib(path: str | os.PathLike) -> GeoCalib:
    path = Path(path)
    hint = 'write {"gravity": [x, y, z] (unit up, OpenCV camera axes), "rp": [roll, pitch]}'
    try:
        data = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise InputError(f"cannot read geocalib.json ({exc})", path=path, hint=hint) from None
    if "gravity" not in data:
        raise InputError("geocalib.json has no 'gravity'", path=path, hint=hint)
    up = np.asarray(data["gravity"], dtype=float)
    if up.shape != (3,) or not np.all(np.isfinite(up)) or abs(np.linalg.norm(up) - 1.0) > 1e-3:
        raise InputError(f"'gravity' {up.tolist()} is not a unit 3-vector", path=path, hint=hint)
    roll, pitch = data["rp"] if "rp" in data else rp_from_up(up)
    if "rp" in data and np.degrees(np.arccos(np.clip(up @ up_from_rp(roll, pitch), -1, 1))) > 0.5:
        raise InputError(
            "'gravity' and 'rp' disagree (is 'gravity' the UP vector in OpenCV axes?)", path=path, hint=hint
        )
    return GeoCalib(
        up_cam=up,
        roll=float(roll),
        pitch=float(pitch),
        frame=int(data.get("frame", 0)),
        K=np.asarray(data["K"], dtype=float) if "K" in data else None,
        vfov=float(data["vfov"]) if "vfov" in data else None,
        roll_uncertainty=float(data["roll_uncertainty"]) if "roll_uncertainty" in data else None,
        pitch_uncertainty=float(data["pitch_uncertainty"]) if "pitch_uncertainty" in data else None,
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
