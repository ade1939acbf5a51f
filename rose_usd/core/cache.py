"""Where rose_usd keeps what it can make again (decoded video frames, convex decompositions, the
hand model bundle): ``$ROSE_USD_CACHE``, else ``$XDG_CACHE_HOME/rose_usd``, else
``~/.cache/rose_usd``."""

from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path

import numpy as np


def cache_dir(*parts: str) -> Path:
    """The cache folder, or a folder ``parts`` under it (not made here)."""
    if os.environ.get("ROSE_USD_CACHE"):
        base = Path(os.environ["ROSE_USD_CACHE"])
    elif os.environ.get("XDG_CACHE_HOME"):
        base = Path(os.environ["XDG_CACHE_HOME"]) / "rose_usd"
    else:
        base = Path.home() / ".cache" / "rose_usd"
    return base.joinpath(*parts)


def load_arrays(path: Path) -> list[np.ndarray] | None:
    """The arrays ``save_arrays`` wrote to ``path``, in order; None where it is missing or unreadable."""
    try:
        with np.load(path, allow_pickle=False) as data:
            return [data[f"a{i}"] for i in range(int(data["count"]))]
    except (OSError, ValueError, KeyError, EOFError):
        return None


def save_arrays(path: Path, arrays: list[np.ndarray]) -> None:
    """Write ``arrays`` to ``path`` whole or not at all (another process may be reading or writing
    the same entry); a cache that cannot be written is left as it is."""
    tmp = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=path.parent, prefix=path.name + ".", suffix=".tmp", delete=False) as f:
            tmp = Path(f.name)
            np.savez(f, count=np.int64(len(arrays)), **{f"a{i}": a for i, a in enumerate(arrays)})
        os.replace(tmp, path)
        tmp = None
    except OSError:
        pass
    finally:
        if tmp is not None:
            with contextlib.suppress(OSError):
                tmp.unlink()
