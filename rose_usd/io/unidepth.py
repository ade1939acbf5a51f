"""UniDepth per-frame outputs (formats.md): ``.npz`` with ``depth`` float32 [H,W] in meters,
``fov`` in degrees (horizontal), optional ``intrinsics`` 3x3 and ``confidence`` [H,W]."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rose_usd.errors import InputError
from rose_usd.io.npz import load_npz


@dataclass
class UniDepthFrame:
    depth_m: np.ndarray
    fov_deg: float
    intrinsics: np.ndarray | None = None
    confidence: np.ndarray | None = None


def read_unidepth(path: str | os.PathLike) -> UniDepthFrame:
    path = Path(path)
    hint = "give UniDepth's per-frame npz (depth [H,W] meters, fov degrees)"
    data = load_npz(path, ("depth", "fov"), tool="UniDepth", hint=hint)
    depth = np.asarray(data["depth"], dtype=np.float32)
    if depth.ndim != 2:
        raise InputError(f"depth has shape {depth.shape}, expected [H, W]", path=path, hint=hint)
    if not np.all(np.isfinite(depth)) and not np.any(np.isfinite(depth) & (depth > 0)):
        raise InputError("depth holds no finite value", path=path, hint=hint)
    try:
        fov = float(np.asarray(data["fov"], dtype=float).reshape(-1)[0])
    except (TypeError, ValueError, IndexError):
        raise InputError("fov is not a number", path=path, hint=hint) from None
    if not 1.0 < fov < 179.0:
        raise InputError(f"fov {fov:g} is not a field of view in degrees", path=path, hint=hint)
    intr = np.asarray(data["intrinsics"], dtype=float).reshape(3, 3) if "intrinsics" in data.files else None
    conf = np.asarray(data["confidence"], dtype=np.float32) if "confidence" in data.files else None
    return UniDepthFrame(depth, fov, intr, conf)


def write_unidepth(path: str | os.PathLike, frame: UniDepthFrame) -> None:
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    extra = {}
    if frame.intrinsics is not None:
        extra["intrinsics"] = np.asarray(frame.intrinsics, dtype=np.float32)
    if frame.confidence is not None:
        extra["confidence"] = np.asarray(frame.confidence, dtype=np.float32)
    np.savez(path, depth=np.asarray(frame.depth_m, dtype=np.float32), fov=np.float32(frame.fov_deg), **extra)
