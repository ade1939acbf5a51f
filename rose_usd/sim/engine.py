"""Importing Newton and Warp quietly, with a word to the user when kernels must be compiled."""

from __future__ import annotations

import contextlib
import functools
import os
import threading
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from rose_usd.progress import say


@contextlib.contextmanager
def _native_stderr_silenced():
    """Send file descriptor 2 to /dev/null (C++ prints bypass sys.stderr), then restore it."""
    import sys

    sys.stderr.flush()
    saved = os.dup(2)
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)
        os.close(devnull)


def _verbose() -> bool:
    return os.environ.get("ROSE_USD_VERBOSE", "") not in ("", "0")


_STARTING = threading.Lock()
"""Held while Warp starts: ``functools.cache`` alone lets two threads run the start at
once, and two ``wp.init()`` side by side build two runtimes, the second marking every kernel
module modified under another thread's load (Warp's ``KeyError`` in ``Module.load``)."""


def warp():
    """The ``warp`` module, initialized once per process, from whichever thread asks first
    (quiet unless ROSE_USD_VERBOSE is set)."""
    with _STARTING:
        return _start_warp()


@functools.cache
def _start_warp():
    import warp as wp

    verbose = _verbose()
    if not verbose:
        # Warp 1.19 logs through config.log_level (older releases through config.quiet); on a
        # machine without a GPU its missing-driver warning is expected noise
        if hasattr(wp, "LOG_ERROR"):
            wp.config.log_level = wp.LOG_ERROR
        wp.config.quiet = True
    cache = Path(os.environ.get("WARP_CACHE_PATH") or Path.home() / ".cache" / "warp") / wp.config.version
    if not cache.is_dir() or not any(cache.iterdir()):
        say(f"warp: first use compiles its kernels into {cache} (about a minute on a CPU, once)")
    if verbose:
        wp.init()
    else:
        with _native_stderr_silenced():  # Warp's driver probe prints a warning from C++ on CPU-only machines
            wp.init()
    return wp


def in_chunks(n: int, chunk: int, device, run) -> None:
    """``run(a, b)`` on every chunk [a, b) of ``n`` items. A CPU launch runs serially with the GIL
    released: one thread a core runs chunks side by side (each item is its own, so the result
    does not depend on the split); a GPU takes them one after another."""
    starts = range(0, n, chunk)
    workers = len(os.sched_getaffinity(0)) if device.is_cpu and hasattr(os, "sched_getaffinity") else 1
    with ThreadPoolExecutor(max_workers=max(1, min(workers, len(starts)))) as pool:
        list(pool.map(lambda a: run(a, min(a + chunk, n)), starts))


@functools.cache
def newton():
    """The ``newton`` module with Warp initialized (quiet unless ROSE_USD_VERBOSE is set), its convex
    decompositions kept in rose_usd's cache."""
    warp()
    import newton as newton_module

    from rose_usd.core.cache import cache_dir

    # CoACD's parts of a convexDecomposition collider, made once (seconds each) for every load
    newton_module.config.cache_dir_meshes = str(cache_dir("coacd"))

    if not _verbose():
        try:  # Newton runs CoACD for convexDecomposition colliders; its info log floods stdout
            import coacd

            coacd.set_log_level("error")
        except (ImportError, AttributeError):
            pass
    return newton_module
