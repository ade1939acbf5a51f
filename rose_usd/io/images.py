"""Images on disk: RGB frames, depth maps and masks, with errors that name the file."""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np

from rose_usd.errors import InputError

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")
DEPTH_SUFFIXES = (".png", ".npy", ".exr")


_DECODED: set[tuple] = set()
"""Files (path, inode, size, mtime, ctime) Pillow decoded in this process: each is checked once,
not at every read (the stages read a frame several times)."""


def check_decodes(path: str | os.PathLike, what: str = "image") -> None:
    """InputError naming ``path`` unless its pixels decode. Decoded with Pillow first because a broken
    PNG or JPEG handed to OpenCV prints libpng/libjpeg messages on stderr besides our one line."""
    from PIL import Image, UnidentifiedImageError

    try:
        st = os.stat(path)
        key = (os.fspath(path), st.st_ino, st.st_size, st.st_mtime_ns, st.st_ctime_ns)
        if key in _DECODED:
            return
        with Image.open(path) as im:
            im.load()
    except (OSError, ValueError, SyntaxError, UnidentifiedImageError, Image.DecompressionBombError):
        raise InputError(
            f"cannot read this {what} (missing, truncated or not an image)",
            path=path,
            hint="replace or remove the file",
        ) from None
    _DECODED.add(key)


def read_rgb(path: str | os.PathLike) -> np.ndarray:
    """8-bit RGB image (H, W, 3)."""
    if Path(path).suffix.lower() in IMAGE_SUFFIXES:
        check_decodes(path)
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        raise InputError(
            "cannot read this image (missing, truncated or not an image)", path=path, hint="replace or remove the file"
        )
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


def write_rgb(path: str | os.PathLike, rgb: np.ndarray) -> None:
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), cv2.cvtColor(np.asarray(rgb, dtype=np.uint8), cv2.COLOR_RGB2BGR)):
        raise InputError("cannot write the image", path=path, hint="check disk space and permissions")


def read_mask(path: str | os.PathLike) -> np.ndarray:
    """Boolean mask (H, W): nonzero pixels of an 8-bit or paletted PNG."""
    check_decodes(path, "mask")
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise InputError(
            "cannot read this mask (missing, truncated or not an image)", path=path, hint="replace or remove the file"
        )
    if img.ndim == 3:
        img = img.max(axis=2)
    return img > 0


def write_mask(path: str | os.PathLike, mask: np.ndarray) -> None:
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), np.where(mask, 255, 0).astype(np.uint8))


def read_depth_m(path: str | os.PathLike) -> np.ndarray:
    """Metric depth [m], float32 (H, W), invalid pixels (0, NaN, inf, negative) set to 0.

    uint16 PNG in millimeters (0 and 65535, a sensor's saturation, invalid), .npy or .exr in meters.
    Raises InputError when a uint16 PNG looks like it holds meters (all values tiny)."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".npy":
        try:
            depth = np.load(path).astype(np.float32)
        except (OSError, ValueError) as exc:
            raise InputError(
                f"cannot read this depth array ({exc})", path=path, hint="write float meters with numpy.save"
            ) from None
    elif suffix == ".exr":
        os.environ.setdefault("OPENCV_IO_ENABLE_OPENEXR", "1")
        depth = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if depth is None:
            raise InputError("cannot read this EXR depth", path=path, hint="write single-channel float meters")
        depth = depth.astype(np.float32)
        if depth.ndim == 3:
            depth = depth[..., 0]
    else:
        check_decodes(path, "depth image")
        raw = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if raw is None:
            raise InputError(
                "cannot read this depth image (missing, truncated or not an image)",
                path=path,
                hint="replace or remove the file",
            )
        if raw.dtype != np.uint16 or raw.ndim != 2:
            raise InputError(
                f"depth PNG is {raw.dtype} with {1 if raw.ndim == 2 else raw.shape[2]} channel(s), "
                "expected 16-bit single channel in millimeters",
                path=path,
                hint="save depth as uint16 PNG in millimeters, or as .npy float meters",
            )
        valid = raw[(raw > 0) & (raw < 65535)]
        if valid.size and np.percentile(valid, 99) < 20:
            raise InputError(
                f"uint16 depth values are all below {int(valid.max()) + 1}: they look like meters, not millimeters",
                path=path,
                hint="save depth PNGs in millimeters (meters x 1000), or as .npy float meters",
            )
        depth = np.where(raw == 65535, 0, raw).astype(np.float32) / 1000.0
    if depth.ndim != 2:
        raise InputError(f"depth has shape {depth.shape}, expected (H, W)", path=path, hint="store one depth channel")
    depth = np.where(np.isfinite(depth) & (depth > 0), depth, 0.0).astype(np.float32)
    return depth


def write_depth_mm(path: str | os.PathLike, depth_m: np.ndarray) -> None:
    """Write metric depth as uint16 PNG in millimeters (0 = invalid, clipped at 65.535 m)."""
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    mm = np.round(np.nan_to_num(depth_m, nan=0.0, posinf=0.0) * 1000.0)
    cv2.imwrite(str(path), np.clip(mm, 0, 65535).astype(np.uint16))


def image_size(path: str | os.PathLike) -> tuple[int, int]:
    """(width, height) from the file header, without decoding the pixels."""
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as im:
            return im.size
    except (OSError, ValueError, SyntaxError, UnidentifiedImageError, Image.DecompressionBombError):
        raise InputError(
            "cannot read this image's header (truncated or not an image)", path=path, hint="replace or remove the file"
        ) from None
