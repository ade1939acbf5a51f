"""Frame indices: runs of consecutive True frames in a per-frame mask, frames spread over a video."""

from __future__ import annotations

import numpy as np


def true_runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """(first, last) index of each run of consecutive True values of ``mask`` (1-D), in order."""
    padded = np.concatenate([[False], np.asarray(mask, bool), [False]])
    edges = np.flatnonzero(np.diff(padded.astype(np.int8)))
    return [(int(a), int(b) - 1) for a, b in zip(edges[::2], edges[1::2])]


def spread_frames(n: int, count: int) -> list[int]:
    """``count`` frames (at most n) spread evenly over n, first and last included."""
    return np.unique(np.linspace(0, n - 1, min(count, n)).round().astype(int)).tolist()
