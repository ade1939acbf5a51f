"""FoundationPose outputs (formats.md): ``ob_in_cam/<frame_id>.txt``, one 4x4 T_cam<-object per
frame (np.savetxt), meters, OpenCV camera axes, in the ORIGINAL mesh frame (the mesh given to
FoundationPose). Frame ids are the stems of the RGB files."""

from __future__ import annotations

import os
import warnings
from pathlib import Path

import numpy as np

from rose_usd.core import se3
from rose_usd.errors import InputError

MAX_DISTANCE_M = 100.0
"""An object farther from the camera than this is a broken pose, not a hand-held video [m]."""


def write_pose(path: str | os.PathLike, cam_from_object: np.ndarray) -> None:
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    np.savetxt(path, np.asarray(cam_from_object, dtype=float))


def read_pose(path: str | os.PathLike) -> np.ndarray:
    """One T_cam<-object (4, 4); InputError if it is not a rigid transform."""
    path = Path(path)
    hint = "write the 4x4 T_cam<-object with numpy.savetxt (rotation, translation in meters)"
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # an empty file: the shape check below says so
            pose = np.loadtxt(path, dtype=float, ndmin=2)
    except (OSError, ValueError) as exc:
        raise InputError(f"cannot read this pose ({str(exc).splitlines()[0]})", path=path, hint=hint) from None
    if pose.shape != (4, 4):
        raise InputError(f"pose has shape {pose.shape}, expected 4x4", path=path, hint=hint)
    if not np.all(np.isfinite(pose)):
        raise InputError("pose holds NaN or infinite values", path=path, hint=hint)
    distance = float(np.abs(pose[:3, 3]).max())
    if distance > MAX_DISTANCE_M:
        raise InputError(
            f"the object is {distance:.3g} m from the camera (more than {MAX_DISTANCE_M:g} m)", path=path, hint=hint
        )
    if not np.allclose(pose[3], [0, 0, 0, 1], atol=1e-6):
        raise InputError(f"last row is {pose[3].tolist()}, expected 0 0 0 1", path=path, hint=hint)
    with np.errstate(over="ignore", invalid="ignore"):  # 1e300 entries: the check says so, numpy need not
        se3.check_rotation(pose[:3, :3], tol=1e-3, what="pose rotation", path=path)
    return pose


def read_track(folder: str | os.PathLike, frame_ids: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """Poses of the listed frames: (N, 4, 4) and a boolean (N,) of which frames had a file."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError("ob_in_cam folder not found", path=folder, hint="point to FoundationPose's ob_in_cam/")
    poses = np.tile(np.eye(4), (len(frame_ids), 1, 1))
    present = np.zeros(len(frame_ids), dtype=bool)
    for i, fid in enumerate(frame_ids):
        path = folder / f"{fid}.txt"
        if path.is_file():
            poses[i] = read_pose(path)
            present[i] = True
    return poses, present
