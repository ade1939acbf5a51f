"""Loading a tool's ``.npz`` with one clear error for an unreadable file or missing keys."""

from __future__ import annotations

import os
import zipfile
from pathlib import Path

import numpy as np

from rose_usd.errors import InputError


def load_npz(path: str | os.PathLike, required: tuple[str, ...], *, tool: str, hint: str):
    """``np.load`` of ``path`` (no pickles); InputError if unreadable or lacking ``required`` keys."""
    path = Path(path)
    try:
        data = np.load(path, allow_pickle=False)
    except (OSError, ValueError, zipfile.BadZipFile) as exc:
        raise InputError(f"cannot read this npz ({exc})", path=path, hint=hint) from None
    missing = [k for k in required if k not in data.files]
    if missing:
        raise InputError(f"{tool} npz lacks key(s) {missing} (has {sorted(data.files)})", path=path, hint=hint)
    return data
