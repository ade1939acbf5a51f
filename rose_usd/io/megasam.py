"""MegaSaM's final output ``<scene>_sgd_cvd_hr.npz`` (formats.md).

Keys: ``images`` uint8 [N,H,W,3] RGB; ``depths`` float16 [N,H,W], 1/disparity clipped to
[1e-3, 1e2]; ``intrinsic`` 3x3 [px of those images]; ``cam_c2w`` [N,4,4] camera-to-world, OpenCV
camera axes. Depth and translation are NOT metric: metric = alpha * depth + beta for an unknown
per-video alpha, beta. The tracking step's ``<scene>_droid.npz`` has the same keys, float32 depths.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from rose_usd.core import se3
from rose_usd.errors import InputError
from rose_usd.io.npz import load_npz

KEYS = ("images", "depths", "intrinsic", "cam_c2w")
MAX_TRANSLATION = 1e4
"""MegaSaM's translations are up to scale, but not this far."""
DEPTH_CLIP = (1e-3, 1e2)
FAR_CLIP = 99.0  # MegaSaM clips 1/disparity at 1e2: treat the clip as "no depth"


@dataclass
class MegaSamOutput:
    images: np.ndarray
    """RGB frames as MegaSaM processed them, uint8 (N, H, W, 3)."""
    depths: np.ndarray
    """Up-to-scale depth (1/disparity), (N, H, W)."""
    intrinsic: np.ndarray
    """3x3 intrinsics in pixels of ``images``."""
    cam_c2w: np.ndarray
    """Camera-to-world poses, OpenCV axes, up-to-scale translation, (N, 4, 4)."""


def read_megasam(path: str | os.PathLike) -> MegaSamOutput:
    """Read and check a MegaSaM npz; InputError naming the problem otherwise."""
    path = Path(path)
    hint = "give MegaSaM's <scene>_sgd_cvd_hr.npz (keys images, depths, intrinsic, cam_c2w)"
    data = load_npz(path, KEYS, tool="MegaSaM", hint=hint)
    out = MegaSamOutput(*(data[k] for k in KEYS))
    n = len(out.cam_c2w)
    if out.images.ndim != 4 or out.images.shape[-1] != 3 or out.images.dtype != np.uint8:
        raise InputError(
            f"images are {out.images.dtype} {out.images.shape}, expected uint8 [N,H,W,3]", path=path, hint=hint
        )
    if out.depths.shape != out.images.shape[:3]:
        raise InputError(f"depths {out.depths.shape} do not match images {out.images.shape[:3]}", path=path, hint=hint)
    if out.intrinsic.shape != (3, 3) or out.cam_c2w.shape != (n, 4, 4) or len(out.images) != n:
        raise InputError(
            f"intrinsic {out.intrinsic.shape} / cam_c2w {out.cam_c2w.shape} / {len(out.images)} images disagree",
            path=path,
            hint=hint,
        )
    if not (np.all(np.isfinite(out.cam_c2w)) and np.all(np.isfinite(out.intrinsic))):
        raise InputError("poses or intrinsics contain NaN", path=path, hint=hint)
    if n == 0:
        raise InputError("the npz holds no frames", path=path, hint=hint)
    far = float(np.abs(out.cam_c2w[:, :3, 3]).max())
    if far > MAX_TRANSLATION:
        raise InputError(f"a camera lies {far:.3g} units away (more than {MAX_TRANSLATION:g})", path=path, hint=hint)
    with np.errstate(over="ignore", invalid="ignore"):
        for t in range(n):
            se3.check_rotation(out.cam_c2w[t, :3, :3].astype(float), tol=1e-2, what=f"cam_c2w[{t}]", path=path)
    h, w = out.images.shape[1:3]
    fx, fy, cx, cy = (float(out.intrinsic[i, j]) for i, j in ((0, 0), (1, 1), (0, 2), (1, 2)))
    if not (fx > 0 and fy > 0 and 0 < cx < w and 0 < cy < h):
        raise InputError(
            f"intrinsic fx={fx:g} fy={fy:g} cx={cx:g} cy={cy:g} does not fit its {w}x{h} images", path=path, hint=hint
        )
    for t in range(n):
        d = out.depths[t].astype(np.float32)
        if np.count_nonzero(np.isfinite(d) & (d > 0) & (d < FAR_CLIP)) < 0.01 * d.size:
            raise InputError(f"depth of frame {t} holds no valid value (NaN, zero or clipped)", path=path, hint=hint)
    return out


def write_megasam(path: str | os.PathLike, out: MegaSamOutput, *, depth_dtype=np.float16) -> None:
    """Write the npz exactly as MegaSaM does (np.savez, depths clipped and cast)."""
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    np.savez(
        path,
        images=np.asarray(out.images, dtype=np.uint8),
        depths=np.clip(out.depths, *DEPTH_CLIP).astype(depth_dtype),
        intrinsic=np.asarray(out.intrinsic, dtype=np.float32),
        cam_c2w=np.asarray(out.cam_c2w, dtype=np.float32),
    )


def metric_from_megasam(relative: np.ndarray, alpha: float, beta: float, width: int, height: int) -> np.ndarray:
    """One MegaSaM depth map made metric (alpha * depth + beta) at the video's size [m], 0 where
    MegaSaM has no depth (non-positive or at its far clip)."""
    rel = relative.astype(np.float32)
    d = np.where((rel > 0) & (rel < FAR_CLIP), alpha * rel + beta, 0.0).astype(np.float32)
    return cv2.resize(d, (width, height), interpolation=cv2.INTER_NEAREST)
