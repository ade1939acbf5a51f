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
    _decoded(path, what, None)


PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
PLAIN_RGB = (8, 2)
"""A PNG's (bit depth, colour type) whose pixels Pillow and OpenCV read alike: 8-bit truecolour ..."""
PLAIN_GRAY = (8, 0)
"""... 8-bit gray ..."""
PLAIN_DEPTH = (16, 0)
"""... and 16-bit gray."""


def _png_kind(path: str | os.PathLike) -> tuple[int, int] | None:
    """A PNG's (bit depth, colour type) from its header; None for any other file."""
    try:
        with open(path, "rb") as f:
            head = f.read(26)
    except OSError:
        return None
    if len(head) < 26 or head[:8] != PNG_SIGNATURE or head[12:16] != b"IHDR":
        return None
    return head[24], head[25]


def _decoded(path: str | os.PathLike, what: str, plain: tuple[int, int] | None) -> np.ndarray | None:
    """``check_decodes``, and at a file's first read in this process the pixels Pillow decoded
    where it is a PNG of kind ``plain`` without EXIF (lossless, no palette, alpha or orientation
    to apply: exactly what OpenCV would read, which then is not asked, so the first read decodes
    once, not twice); None otherwise (OpenCV reads it, as at every later read)."""
    from PIL import Image, UnidentifiedImageError

    try:
        st = os.stat(path)
        key = (os.fspath(path), st.st_ino, st.st_size, st.st_mtime_ns, st.st_ctime_ns)
        if key in _DECODED:
            return None
        wanted = plain is not None and _png_kind(path) == plain
        with Image.open(path) as im:
            im.load()
            pixels = np.array(im) if wanted and "exif" not in im.info else None
    except (OSError, ValueError, SyntaxError, UnidentifiedImageError, Image.DecompressionBombError):
        raise InputError(
            f"cannot read this {what} (missing, truncated or not an image)",
            path=path,
            hint="replace or remove the file",
        ) from None
    _DECODED.add(key)
    if pixels is not None and plain == PLAIN_DEPTH:
        pixels = pixels.astype(np.uint16)  # Pillow's 16-bit gray may come as int32 or big-endian
    return pixels


def read_rgb(path: str | os.PathLike) -> np.ndarray:
    """8-bit RGB image (H, W, 3)."""
    if Path(path).suffix.lower() in IMAGE_SUFFIXES:
        pixels = _decoded(path, "image", PLAIN_RGB)
        if pixels is not None:
            return pixels
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
    pixels = _decoded(path, "mask", PLAIN_GRAY)
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED) if pixels is None else pixels
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
        pixels = _decoded(path, "depth image", PLAIN_DEPTH)
        raw = cv2.imread(str(path), cv2.IMREAD_UNCHANGED) if pixels is None else pixels
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


def check_complete(path: str | os.PathLike) -> None:
    """InputError naming ``path`` when it is a PNG or JPEG cut short (a copy or download that
    stopped) and its pixels do not decode. Reads the file's last bytes: a PNG ends with its IEND
    chunk, a JPEG's end-of-image marker lies near its end; only a file without them is decoded
    (``check_decodes``), so a complete one costs no decode and an odd but readable one passes."""
    try:
        with open(path, "rb") as f:
            head = f.read(8)
            f.seek(0, os.SEEK_END)
            f.seek(max(0, f.tell() - 4096))
            tail = f.read()
    except OSError:
        tail, head = b"", b""
    if head.startswith(PNG_SIGNATURE):
        ended = tail.endswith(b"IEND\xaeB`\x82")
    elif head.startswith(b"\xff\xd8"):
        ended = b"\xff\xd9" in tail  # after it, cameras may append a trailer
    else:
        return
    if not ended:
        check_decodes(path)


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
