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


_interrupted = False


def note_interrupt() -> None:
    """Record that Ctrl-C reached this process (a SIGINT handler calls it before it raises
    KeyboardInterrupt): a layer does not commit afterwards (``usd.stage.LayerWriter``), even where
    the KeyboardInterrupt was lost on its way out (raised inside a callback from C code, which
    prints it and goes on)."""
    global _interrupted
    _interrupted = True


def interrupt_noted() -> bool:
    """Whether ``note_interrupt`` was called in this process."""
    return _interrupted
