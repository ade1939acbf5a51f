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


def after_interrupt(signum, frame) -> None:
    """SIGINT's handler once an interrupt is being handled: a further one does nothing (the rollback
    runs to its end). Not ``SIG_IGN``: an interrupt ``_thread.interrupt_main`` delivers (one
    ``redeliver_lost_interrupts`` raises again) that finds ``SIG_IGN`` is raised as "OSError: Signal 2
    ignored due to race condition" wherever the main thread is, and its traceback reached the user
    (seen once in a Ctrl-C test of the gate stage)."""


def _raise_once(signum, frame) -> None:
    """SIGINT's handler for an interrupt raised again (``_thread.interrupt_main``): it raises, once."""
    import signal

    signal.signal(signal.SIGINT, after_interrupt)
    raise KeyboardInterrupt


def interrupt_noted() -> bool:
    """Whether ``note_interrupt`` was called in this process."""
    return _interrupted


def redeliver_lost_interrupts() -> None:
    """Once ``note_interrupt`` was called, a KeyboardInterrupt that Python cannot propagate (the
    SIGINT handler ran inside a weakref callback, a finalizer or a callback from C, which print it
    as "Exception ignored" and go on) is not printed but raised again in the main thread, a moment
    later, from outside that callback: a stage interrupted there still ends promptly, and the user
    sees no traceback. Other unraisable errors go to the hook that was installed before."""
    import _thread
    import signal
    import threading

    before = sys.unraisablehook

    def hook(info) -> None:
        lost = _interrupted and isinstance(info.exc_value, KeyboardInterrupt)
        if not lost or threading.current_thread() is not threading.main_thread():
            before(info)
            return
        signal.signal(signal.SIGINT, _raise_once)
        # not from here: the handler would run before this hook returns, where it is lost again
        threading.Timer(0.01, _thread.interrupt_main, (signal.SIGINT,)).start()

    sys.unraisablehook = hook


def _importing(frame) -> bool:
    """Whether ``frame``'s stack runs an import (importlib's bootstrap frames in it)."""
    while frame is not None:
        if frame.f_code.co_filename.startswith("<frozen importlib"):
            return True
        frame = frame.f_back
    return False


def raise_after_import(frame) -> bool:
    """For a SIGINT handler interrupting ``frame`` (the main thread's): where an import runs there,
    arrange the KeyboardInterrupt for when it is over and return True (the handler returns without
    raising); else False. Raised inside an import it may unwind through a native module's init
    (Mitsuba's nanobind enums), which turns it into std::terminate: the gate's process aborted
    (exit -6) instead of rolling back, in a fresh clone's Ctrl-C test. A thread watches the main
    thread's stack and interrupts it again (``_thread.interrupt_main``) once no import runs."""
    import _thread
    import signal
    import threading
    import time

    if not _importing(frame):
        return False
    main = threading.main_thread().ident

    def watch() -> None:
        while _importing(sys._current_frames().get(main)):
            time.sleep(0.02)
        _thread.interrupt_main(signal.SIGINT)

    signal.signal(signal.SIGINT, _raise_once)
    threading.Thread(target=watch, name="interrupt-after-import", daemon=True).start()
    return True
