"""Progress for long work, on stderr: a tqdm bar on a terminal; elsewhere (a log file, a pipe) a
plain line when the work starts, one every ``LOG_EVERY_S`` and one when it ends, so that a log
holds lines, not carriage returns. ``ROSE_USD_QUIET=1`` silences it (tests do)."""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Iterable, Iterator
from typing import TypeVar

T = TypeVar("T")

LOG_EVERY_S = 30.0
"""Off a terminal, a progress line at most this often [s]."""


def quiet() -> bool:
    return os.environ.get("ROSE_USD_QUIET", "") not in ("", "0")


def progress(items: Iterable[T], desc: str, total: int | None = None, unit: str = "frame") -> Iterator[T]:
    """Iterate with a progress bar named ``desc``."""
    if quiet():
        yield from items
        return
    if not sys.stderr.isatty():
        yield from _logged(items, desc, total, unit)
        return
    from tqdm import tqdm

    yield from tqdm(
        items, desc=desc, total=total, unit=unit, file=sys.stderr, mininterval=0.5, dynamic_ncols=True, leave=False
    )


def _logged(items: Iterable[T], desc: str, total: int | None, unit: str) -> Iterator[T]:
    """``progress`` off a terminal: "desc: 0/N unit" at the start, then every LOG_EVERY_S, and the
    count and seconds at the end; where the loop stops early, "desc: stopped at k/N units after"
    the seconds (an interrupted collect's "2/8 rollouts in 9.6 s" read as finished)."""
    of = f"/{total}" if total is not None else ""
    start = last = time.perf_counter()
    print(f"{desc}: 0{of} {unit}s", file=sys.stderr, flush=True)
    done = 0
    try:
        for item in items:
            done += 1  # handed out: a loop left during an item counts it
            yield item
            now = time.perf_counter()
            if now - last >= LOG_EVERY_S and done != total:  # the last item's line is the end's
                print(f"{desc}: {done}{of} {unit}s, {now - start:.0f} s", file=sys.stderr, flush=True)
                last = now
    finally:  # also when left early (a rest check that settled, an error, Ctrl-C): said so
        took = time.perf_counter() - start
        end = f"stopped at {done}{of} {unit}s after" if total is not None and done < total else f"{done}{of} {unit}s in"
        print(f"{desc}: {end} {took:.1f} s", file=sys.stderr, flush=True)


def say(message: str) -> None:
    """One line of status on stderr."""
    if not quiet():
        print(message, file=sys.stderr, flush=True)
