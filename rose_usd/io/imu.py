"""``imu/gravity.txt``: one gravity (down) vector per frame in OpenCV camera axes, or one line for
all frames (any unit: only the direction is used)."""

from __future__ import annotations

import os
import warnings
from pathlib import Path

import numpy as np

from rose_usd.errors import InputError

HINT = "write gx gy gz per frame (or one line), in OpenCV camera axes"


def read_gravity(path: str | os.PathLike, n_frames: int) -> np.ndarray:
    """The file's gravity vectors as (n_frames, 3), each finite and non-zero; InputError naming the
    file otherwise."""
    path = Path(path)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # an empty file: the shape check below says so
            g = np.loadtxt(path, dtype=float, ndmin=2)
    except (OSError, ValueError, UnicodeDecodeError) as exc:
        raise InputError(f"not numeric ({str(exc).splitlines()[0]})", path=path, hint=HINT) from None
    if g.ndim != 2 or g.shape[1] != 3 or len(g) not in (1, n_frames):
        raise InputError(f"has shape {g.shape}, expected 1 or {n_frames} rows of 3", path=path, hint=HINT)
    if not np.all(np.isfinite(g)):
        raise InputError("has NaN or infinite gravity vectors", path=path, hint=HINT)
    with np.errstate(over="ignore", invalid="ignore"):
        norms = np.linalg.norm(g, axis=1)
    if np.any(norms < 1e-6) or np.any(norms > 1e6):
        raise InputError("has zero or absurd gravity vectors", path=path, hint=HINT)
    return np.broadcast_to(g, (n_frames, 3)).copy()
