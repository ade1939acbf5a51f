"""SAM 2 video masks (formats.md): a DAVIS-style paletted PNG per frame (``<frame>.png``, mode P,
pixel value = object id, 0 = background), or per object ``<obj_id>/<frame>.png``. Frame names are
integer indices (DAVIS pads them to five digits)."""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np
from PIL import Image

from rose_usd.errors import InputError


def davis_palette() -> list[int]:
    """The DAVIS / PASCAL VOC color map: 256 RGB triplets, flattened."""
    palette = []
    for i in range(256):
        r = g = b = 0
        c = i
        for j in range(8):
            r |= ((c >> 0) & 1) << (7 - j)
            g |= ((c >> 1) & 1) << (7 - j)
            b |= ((c >> 2) & 1) << (7 - j)
            c >>= 3
        palette += [r, g, b]
    return palette


def write_id_mask(path: str | os.PathLike, ids: np.ndarray) -> None:
    """Write one frame of object ids as a paletted PNG."""
    img = Image.fromarray(np.asarray(ids, dtype=np.uint8), mode="P")
    img.putpalette(davis_palette())
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    img.save(path)


def _frame_index(path: Path) -> int:
    if not re.fullmatch(r"\d+", path.stem):
        raise InputError(
            "SAM 2 mask names must be integer frame indices", path=path, hint="name masks 00000.png, 00001.png, ..."
        )
    return int(path.stem)


def read_masks(folder: str | os.PathLike) -> dict[int, dict[int, Path]]:
    """Index a SAM 2 mask folder: {frame index: {object id (0 = all ids in one file): png}}.

    Either paletted frames directly in ``folder`` or one subfolder per object id."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError("SAM 2 mask folder not found", path=folder, hint="put SAM 2's PNG masks there")
    frames: dict[int, dict[int, Path]] = {}
    subdirs = [p for p in folder.iterdir() if p.is_dir() and re.fullmatch(r"\d+", p.name)]
    if subdirs:
        for sub in subdirs:
            for png in sub.glob("*.png"):
                frames.setdefault(_frame_index(png), {})[int(sub.name)] = png
    else:
        for png in folder.glob("*.png"):
            frames.setdefault(_frame_index(png), {})[0] = png
    if not frames:
        raise InputError("no PNG masks in the SAM 2 folder", path=folder, hint="put SAM 2's PNG masks there")
    return frames


def _open(path: Path) -> Image.Image:
    try:
        img = Image.open(path)
        img.load()
    except (OSError, ValueError, SyntaxError, Image.DecompressionBombError) as exc:  # SyntaxError: broken PNG chunk
        raise InputError(
            f"cannot read this mask ({type(exc).__name__})", path=path, hint="save SAM 2 masks as PNG images"
        ) from None
    return img


def check_mask_file(path: Path, *, paletted: bool) -> tuple[int, int]:
    """Open one SAM 2 mask (fully decoded) and return its (width, height); InputError naming it when
    it is not an image, or not a paletted/grey PNG of object ids where ``paletted``."""
    with _open(path) as img:
        if paletted and img.mode not in ("P", "L"):
            raise InputError(
                f"mask is mode {img.mode}, expected a paletted (P) PNG of object ids",
                path=path,
                hint="save SAM 2 masks as DAVIS paletted PNGs",
            )
        return img.size


def read_object_mask(entries: dict[int, Path], object_id: int) -> np.ndarray:
    """Boolean mask of ``object_id`` in one frame's entries from :func:`read_masks`."""
    if 0 in entries:
        check_mask_file(entries[0], paletted=True)
        with _open(entries[0]) as img:
            return np.asarray(img) == object_id
    if object_id not in entries:
        return None
    with _open(entries[object_id]) as img:
        return np.asarray(img.convert("L")) > 0
