"""Waking threads that sleep on a futex whose wake-up was lost.

What was seen: on two cores with two test workers, processes stalled for 12 minutes and more
inside Mitsuba calls (``mi.set_variant``, ``SceneParameters.update``), one of them using a core
throughout, and went on within a minute after a profiler attached to them. Attaching (ptrace)
interrupts every thread's blocking system call; the kernel restarts a futex wait by comparing
the futex word again, and a waiter whose word has already changed returns at once. That is what a
lost wake-up needs to end: a waker changed the word but its ``FUTEX_WAKE`` reached no one, and
whatever waits for the sleeper waits too (spinning, if it waits on a spin lock the sleeper holds:
Dr.Jit's state lock is one, and its thread pool parks threads on futexes).

The guard does what the profiler did, to the threads that need it only: a daemon thread reads
``/proc/self/task`` every ``period_s``; a thread asleep in a futex wait that has not been on a
CPU once (its schedstat run count unchanged) for ``stall_s`` gets a signal whose handler does
nothing (``SA_RESTART``). A waiter whose word changed leaves its wait; one whose word did not goes
back to sleep (a spurious wake-up, which every futex loop allows), to be signalled again after
another ``stall_s``. A thread that runs is never signalled. A signalled thread that then runs for
``RAN_S`` of CPU before it sleeps again was most likely stuck, and one line on stderr (and in
the file ``$ROSE_USD_STALL_LOG`` names) says so.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import platform
import signal
import sys
import threading
import time
from dataclasses import dataclass, field

WAKE_SIGNAL = signal.SIGURG
"""Ignored by default; the guard installs a do-nothing handler for it (only where none is set)."""
LOG_ENV = "ROSE_USD_STALL_LOG"
"""Where set, the file each report is appended to as well (CI prints it: stderr of a passing test is
not shown)."""
RAN_S = 0.2
"""CPU a thread uses after its wake-up, before it sleeps again, for the guard to report it as stuck."""

_TGKILL = {"x86_64": 234, "aarch64": 131}.get(platform.machine())
_guard: StallGuard | None = None
_lock = threading.Lock()


def _noop(signum, frame) -> None:
    pass


def _read(path: str) -> str | None:
    try:
        with open(path) as f:
            return f.read()
    except OSError:  # the thread ended meanwhile
        return None


@dataclass(frozen=True)
class ThreadSample:
    tid: int
    name: str
    state: str
    """``R`` running, ``S`` asleep (interruptibly), ...: ``/proc/.../stat``'s third field."""
    wchan: str
    """The kernel function it sleeps in (``futex_wait_queue`` and the like)."""
    cpu_ns: int
    runs: int
    """How many times it has been put on a CPU (``/proc/.../schedstat``)."""

    @property
    def in_futex_wait(self) -> bool:
        return self.state == "S" and "futex" in self.wchan


def threads() -> list[ThreadSample]:
    """This process's threads now (those that end while being read are left out)."""
    out = []
    for name in os.listdir("/proc/self/task"):
        base = f"/proc/self/task/{name}"
        stat, wchan, sched = _read(f"{base}/stat"), _read(f"{base}/wchan"), _read(f"{base}/schedstat")
        if not (stat and wchan is not None and sched):
            continue
        comm = stat[stat.index("(") + 1 : stat.rindex(")")]  # the name may hold spaces and ")"
        state = stat[stat.rindex(")") + 2 :].split()[0]
        cpu_ns, _, runs = (int(v) for v in sched.split()[:3])
        out.append(ThreadSample(int(name), comm, state, wchan.strip(), cpu_ns, runs))
    return out


def futex_sleepers() -> list[int]:
    """Thread ids of this process that sleep in a futex wait now."""
    return [t.tid for t in threads() if t.in_futex_wait]


@dataclass
class StallGuard:
    """The daemon thread described in the module's docstring."""

    stall_s: float = 30.0
    period_s: float = 5.0
    signalled: list[int] = field(default_factory=list)
    """The thread ids it sent a signal to, once per signal."""
    stuck: list[str] = field(default_factory=list)
    """The threads it reported as stuck (went on running after their wake-up)."""
    _stop: threading.Event = field(default_factory=threading.Event)

    def start(self) -> StallGuard:
        threading.Thread(target=self._run, name="rose-usd-stall-guard", daemon=True).start()
        return self

    def stop(self) -> None:
        self._stop.set()

    def _run(self) -> None:
        me = threading.get_native_id()
        asleep: dict[int, tuple[int, float]] = {}  # tid -> (run count, since when it has not changed)
        woken: dict[int, int] = {}  # tid -> CPU ns at its wake-up, until it reports or sleeps again
        while not self._stop.wait(self.period_s):
            now, seen, samples = time.monotonic(), {}, [t for t in threads() if t.tid != me]
            for t in samples:
                if t.tid in woken and t.cpu_ns - woken[t.tid] >= RAN_S * 1e9:
                    self._report(t)
                    del woken[t.tid]
                if not t.in_futex_wait:
                    continue
                woken.pop(t.tid, None)  # asleep again: its wake-up was a spurious one
                runs, since = asleep.get(t.tid, (t.runs, now))
                if runs != t.runs:
                    since = now
                if now - since >= self.stall_s:
                    _tgkill(t.tid)
                    self.signalled.append(t.tid)
                    woken[t.tid], since = t.cpu_ns, now
                seen[t.tid] = (t.runs, since)
            alive = {t.tid for t in samples}
            asleep, woken = seen, {tid: ns for tid, ns in woken.items() if tid in alive}

    def _report(self, t: ThreadSample) -> None:
        self.stuck.append(t.name)
        line = (
            f"rose_usd: thread {t.tid} ({t.name}) of process {os.getpid()} had slept {self.stall_s:.0f} s on a"
            " futex; woken by a signal, it went on running (a lost wake-up: see rose_usd/core/wakeup.py)"
        )
        print(line, file=sys.stderr, flush=True)
        log = os.environ.get(LOG_ENV)
        if log:
            with contextlib.suppress(OSError), open(log, "a") as f:
                f.write(f"{time.strftime('%H:%M:%S')} {' '.join(sys.argv[:3])[:200]}: {line}\n")


def _tgkill(tid: int) -> None:
    libc = ctypes.CDLL(None, use_errno=True)
    libc.syscall(ctypes.c_long(_TGKILL), ctypes.c_int(os.getpid()), ctypes.c_int(tid), ctypes.c_int(WAKE_SIGNAL))


def supported() -> bool:
    """Linux on x86-64 or AArch64 (``/proc`` with schedstat, and ``tgkill``)."""
    return sys.platform == "linux" and _TGKILL is not None and os.path.exists("/proc/self/schedstat")


def install_handler() -> bool:
    """Set the do-nothing handler for ``WAKE_SIGNAL`` (``SA_RESTART``: other blocking calls
    resume). False where it cannot be: not ``supported()``, off the main thread (Python sets
    handlers there only) or the signal already has another handler."""
    if not supported():
        return False
    handler = signal.getsignal(WAKE_SIGNAL)
    if handler is _noop:
        return True
    if handler != signal.SIG_DFL or threading.current_thread() is not threading.main_thread():
        return False
    signal.signal(WAKE_SIGNAL, _noop)
    signal.siginterrupt(WAKE_SIGNAL, False)
    return True


def ensure_stall_guard() -> StallGuard | None:
    """Start this process's guard once (later calls return it); None where ``install_handler``
    cannot set its handler."""
    global _guard
    with _lock:
        if _guard is None and install_handler():
            _guard = StallGuard().start()
        return _guard
