"""Importing Newton and Warp quietly, with a word to the user when kernels must be compiled."""

from __future__ import annotations

import functools
import os
from pathlib import Path

from rose_usd.progress import say


@functools.cache
def newton():
    """The ``newton`` module with Warp initialized (quiet unless ROSE_USD_VERBOSE is set)."""
    import warp as wp

    verbose = os.environ.get("ROSE_USD_VERBOSE", "") not in ("", "0")
    if not verbose:
        # Warp 1.19 logs through config.log_level (older releases through config.quiet); on a
        # machine without a GPU its missing-driver warning is expected noise
        if hasattr(wp, "LOG_ERROR"):
            wp.config.log_level = wp.LOG_ERROR
        wp.config.quiet = True
    cache = Path(os.environ.get("WARP_CACHE_PATH") or Path.home() / ".cache" / "warp") / wp.config.version
    if not cache.is_dir() or not any(cache.iterdir()):
        say(f"newton: first use compiles Warp kernels into {cache} (about a minute on a CPU, once)")
    wp.init()
    import newton as newton_module

    return newton_module
