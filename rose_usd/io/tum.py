"""TUM trajectory files: ``timestamp tx ty tz qx qy qz qw`` per line, ``#`` comments, seconds,
world-from-sensor poses, quaternion scalar LAST (formats.md)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from rose_usd.core import se3
from rose_usd.errors import InputError


def read_tum(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """Read a TUM trajectory.

    Returns:
        timestamps_s: shape (N,) [s]; world_from_sensor: shape (N, 4, 4) [m].
    """
    path = Path(path)
    if not path.is_file():
        raise InputError("trajectory file not found", path=path, hint="write it in TUM format (formats.md)")
    rows = []
    for lineno, line in enumerate(path.read_text().splitlines(), start=1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        fields = line.replace(",", " ").split()
        if len(fields) != 8:
            raise InputError(
                f"line {lineno} has {len(fields)} fields, expected 8 (timestamp tx ty tz qx qy qz qw)",
                path=path,
                hint="write one pose per line in TUM format",
            )
        try:
            rows.append([float(f) for f in fields])
        except ValueError:
            raise InputError(
                f"line {lineno} is not numeric", path=path, hint="write one pose per line in TUM format"
            ) from None
    if not rows:
        raise InputError("trajectory file has no poses", path=path, hint="write one pose per line in TUM format")
    data = np.asarray(rows)
    if not np.all(np.isfinite(data)):
        raise InputError("trajectory contains NaN or infinite values", path=path, hint="remove or fix those lines")
    if np.abs(data[:, 1:4]).max() > 1e4:
        raise InputError(
            "a position lies more than 10 km away", path=path, hint="positions are in meters; fix or remove those lines"
        )
    with np.errstate(over="ignore"):
        norms = np.linalg.norm(data[:, 4:8], axis=1)
    if np.any(np.abs(norms - 1.0) > 1e-3):
        bad = int(np.argmax(np.abs(norms - 1.0)))
        raise InputError(
            f"quaternion on pose {bad} has norm {norms[bad]:.4f}, not 1",
            path=path,
            hint="TUM quaternions are unit quaternions qx qy qz qw (scalar last)",
        )
    if np.any(np.diff(data[:, 0]) <= 0):
        raise InputError("timestamps are not strictly increasing", path=path, hint="sort the poses by time")
    poses = se3.make_pose(se3.matrix_from_quat_xyzw(data[:, 4:8]), data[:, 1:4])
    return data[:, 0].copy(), poses


def write_tum(
    path: str | os.PathLike, timestamps_s: np.ndarray, world_from_sensor: np.ndarray, *, header: str = ""
) -> None:
    """Write a TUM trajectory (timestamps [s], poses (N, 4, 4) world-from-sensor [m])."""
    timestamps_s = np.asarray(timestamps_s, dtype=float)
    poses = np.asarray(world_from_sensor, dtype=float)
    if poses.shape != (len(timestamps_s), 4, 4):
        raise ValueError(f"write_tum: poses shape {poses.shape} does not match {len(timestamps_s)} timestamps")
    quat = se3.quat_xyzw_from_matrix(poses[:, :3, :3])
    lines = [f"# {line}" for line in header.splitlines()] if header else []
    lines.append("# timestamp tx ty tz qx qy qz qw")
    for t, p, q in zip(timestamps_s, poses[:, :3, 3], quat):
        lines.append(f"{t:.6f} {p[0]:.9f} {p[1]:.9f} {p[2]:.9f} {q[0]:.9f} {q[1]:.9f} {q[2]:.9f} {q[3]:.9f}")
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    Path(path).write_text("\n".join(lines) + "\n")
