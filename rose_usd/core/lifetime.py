"""A helper process's lifetime tied to the process that started it."""

from __future__ import annotations

import os
import sys


def die_with_parent(parent: int) -> None:
    """Linux: SIGKILL this process when its parent dies (``PR_SET_PDEATHSIG``; elsewhere
    nothing), and end at once if ``parent`` (the pid that started it) is already gone: it may have
    died while this process started, before the request took effect."""
    import ctypes
    import signal

    if sys.platform.startswith("linux"):
        try:
            ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, int(signal.SIGKILL))  # PR_SET_PDEATHSIG
        except OSError:
            pass
    if os.getppid() != parent:
        os._exit(1)
