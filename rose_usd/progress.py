"""Progress for long work, on stderr (tqdm). ``ROSE_USD_QUIET=1`` silences it (tests do)."""

from __future__ import annotations

import os
import sys
from collections.abc import Iterable, Iterator
from typing import TypeVar

T = TypeVar("T")


def quiet() -> bool:
    return os.environ.get("ROSE_USD_QUIET", "") not in ("", "0")


def progress(items: Iterable[T], desc: str, total: int | None = None, unit: str = "frame") -> Iterator[T]:
    """Iterate with a progress bar named ``desc``."""
    if quiet():
        yield from items
        return
    from tqdm import tqdm

    yield from tqdm(
        items, desc=desc, total=total, unit=unit, file=sys.stderr, mininterval=0.5, dynamic_ncols=True, leave=False
    )


def say(message: str) -> None:
    """One line of status on stderr."""
    if not quiet():
        print(message, file=sys.stderr, flush=True)
