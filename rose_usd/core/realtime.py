"""Threads left at real-time priority by a library, put back.

SVT-AV1 run as root makes the thread that opens its encoder, and the threads it starts,
``SCHED_FIFO`` priority 99, and every process started from that thread afterwards inherits it. On
two cores, a real-time thread that spins waiting for a lock (Dr.Jit's, nanothread's workers) keeps
the real-time holder of that lock off its core until the other core frees up: Mitsuba calls stood
still for 12-14 minutes in CI that way (``io.video`` calls ``undo_realtime`` after the encoder)."""

from __future__ import annotations

import os

REALTIME = {getattr(os, "SCHED_FIFO", -1), getattr(os, "SCHED_RR", -1)}
"""The real-time scheduling policies."""


def scheduling() -> tuple[int, int] | None:
    """The calling thread's scheduling policy and priority; None where they cannot be read."""
    if not hasattr(os, "sched_getscheduler"):
        return None
    return os.sched_getscheduler(0), os.sched_getparam(0).sched_priority


def undo_realtime(original: tuple[int, int] | None) -> list[int]:
    """Every thread of this process that runs real-time where ``original`` (a thread's scheduling
    from before, ``scheduling()``) is not: back to ``original``. Returns those threads' ids. A
    process started real-time on purpose (``chrt``) is left as it is."""
    if original is None or original[0] in REALTIME:
        return []
    try:
        threads = [int(name) for name in os.listdir("/proc/self/task")]
    except OSError:
        return []
    put_back = []
    for tid in threads:
        try:
            if os.sched_getscheduler(tid) in REALTIME:
                os.sched_setscheduler(tid, original[0], os.sched_param(original[1]))
                put_back.append(tid)
        except OSError:  # the thread has ended
            pass
    return put_back
