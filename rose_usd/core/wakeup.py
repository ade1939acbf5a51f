"""Ending stalls on lost futex wake-ups.

What was seen: on two cores with two test workers, processes stalled for 12 minutes and more
inside Mitsuba calls (``mi.set_variant``, ``SceneParameters.update``), one of them using a core
throughout, and went on within a minute after a profiler attached to them. Attaching (ptrace)
interrupts every thread's blocking system call; the kernel restarts a futex wait by comparing
the futex word again, and a waiter whose word has already changed returns at once. That is what a
lost wake-up needs to end: a waker changed the word but its ``FUTEX_WAKE`` reached no one, and
whatever waits for the sleeper waits too (spinning, if it waits on a spin lock the sleeper holds:
Dr.Jit's state lock is one, and its thread pool parks threads on futexes).

A process that loads Mitsuba starts a watcher (``ensure_stall_guard``): this file run as a
script, in a process of its own, because a thread of the watched process cannot run while
another spins holding the GIL. Every ``PERIOD_S`` the watcher reads each thread's system call
(``/proc/PID/task/TID/syscall``) and, for one asleep in ``FUTEX_WAIT``, the futex word
(``/proc/PID/mem``). The kernel lets a thread sleep only while the word holds the value it waits
for, and whoever changes the word must wake it: a thread still asleep, not run once (its
schedstat run count unchanged), ``CONFIRM_S`` after its word changed, lost its wake-up. The
watcher signals that thread every ``CONFIRM_S`` while it sleeps so (``WAKE_SIGNAL``, for which
the watched process set a do-nothing handler with ``SA_RESTART``): its wait returns (the kernel
restarts it against the changed word, or a timed one ends with EINTR) and the thread goes on. No
other thread is signalled. Each such wait is one line, once, in the file ``$ROSE_USD_STALL_LOG``
names, if set (CI prints it), and on the watched process's stderr where that is a pipe or a
terminal.
"""

from __future__ import annotations

import ctypes
import os
import platform
import signal
import sys
import threading
import time

WAKE_SIGNAL = signal.SIGURG
"""Ignored by default; the watched process sets a do-nothing handler for it (only where none is set)."""
PERIOD_S = 1.0
CONFIRM_S = 2.0
LOG_ENV = "ROSE_USD_STALL_LOG"

_FUTEX_NR, _TGKILL_NR = {"x86_64": (202, 234), "aarch64": (98, 131)}.get(platform.machine(), (None, None))
_FUTEX_WAIT_CMDS = (0, 9)  # FUTEX_WAIT, FUTEX_WAIT_BITSET (op & FUTEX_CMD_MASK)
_PR_SET_PDEATHSIG, _PR_SET_PTRACER = 1, 0x59616D61
_started_for: int | None = None  # the pid whose watcher was started (a forked child starts its own)
_lock = threading.Lock()


def _noop(signum, frame) -> None:
    pass


def supported() -> bool:
    """Linux on x86-64 or AArch64 (``/proc`` with schedstat, ``tgkill``, ``posix_spawn``)."""
    return (
        sys.platform == "linux"
        and _FUTEX_NR is not None
        and os.path.exists("/proc/self/schedstat")
        and hasattr(os, "posix_spawn")
    )


def install_handler() -> bool:
    """Set the do-nothing handler for ``WAKE_SIGNAL`` (``SA_RESTART``). False where it cannot be:
    not ``supported()``, off the main thread (Python sets handlers there only) or the signal
    already has another handler."""
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


def start_watcher(*, period_s: float = PERIOD_S, confirm_s: float = CONFIRM_S, log: str | None = None) -> int:
    """Start a watcher of this process; its pid. It ends when this process does (or is killed).
    It reads only; its standard streams are /dev/null (it writes its reports to this process's
    stderr), so it holds no pipe of this process's open."""
    devnull = [(os.POSIX_SPAWN_OPEN, fd, os.devnull, os.O_RDWR, 0) for fd in (0, 1, 2)]
    argv = [sys.executable, "-I", "-S", os.path.abspath(__file__), str(os.getpid()), str(period_s), str(confirm_s)]
    pid = os.posix_spawn(sys.executable, argv + ([log] if log else []), dict(os.environ), file_actions=devnull)
    try:  # where Yama restricts ptrace to ancestors, let the watcher read this process's memory
        ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_PTRACER, ctypes.c_ulong(pid), 0, 0, 0)
    except (OSError, AttributeError):
        pass
    return pid


def ensure_stall_guard() -> bool:
    """Install the handler and start this process's watcher, once; whether it runs."""
    global _started_for
    with _lock:
        if _started_for != os.getpid() and install_handler():
            try:
                start_watcher(log=os.environ.get(LOG_ENV) or None)
            except (OSError, ValueError):  # no interpreter to start (an embedded Python): no watcher
                return False
            _started_for = os.getpid()
        return _started_for == os.getpid()


# ---------------------------------------------------------------------------------------- watcher
def _read(path: str) -> str | None:
    """The file's text; None where its thread ended meanwhile (lost access is raised)."""
    try:
        with open(path, errors="replace") as f:
            return f.read()
    except (FileNotFoundError, ProcessLookupError):
        return None


def lost_wait(pid: int, tid: int, mem: int) -> tuple[int, int, int] | None:
    """(futex address, value waited for, word now) where thread ``tid`` sleeps in a futex wait
    whose word no longer holds the value it waits for; else None."""
    stat = _read(f"/proc/{pid}/task/{tid}/stat")
    if not stat or stat[stat.rindex(")") + 2 :].split()[0] != "S":  # stopped (T) or running: not asleep
        return None
    call = _read(f"/proc/{pid}/task/{tid}/syscall")
    fields = call.split() if call else []
    if len(fields) < 4 or fields[0] != str(_FUTEX_NR):
        return None
    addr, op, value = int(fields[1], 16), int(fields[2], 16), int(fields[3], 16) & 0xFFFFFFFF
    if op & 127 not in _FUTEX_WAIT_CMDS:
        return None
    try:
        data = os.pread(mem, 4, addr)
    except OSError:
        return None
    word = int.from_bytes(data, sys.byteorder)
    return (addr, value, word) if len(data) == 4 and word != value else None


def _runs(pid: int, tid: int) -> int | None:
    sched = _read(f"/proc/{pid}/task/{tid}/schedstat")
    return int(sched.split()[2]) if sched else None


def _report(pid: int, line: str, log: str | None) -> None:
    """``line`` to the watched process's stderr where it is a pipe or a terminal (a file it writes
    at its own offset would overwrite the line), and to ``log``."""
    import stat

    paths = [log] if log else []
    try:
        if not stat.S_ISREG(os.stat(f"/proc/{pid}/fd/2").st_mode):
            paths.insert(0, f"/proc/{pid}/fd/2")
    except OSError:
        pass
    for path in paths:
        try:
            with open(path, "a") as f:
                f.write(line + "\n")
        except OSError:
            pass


def _open_mem(pid: int, wait_s: float = 5.0) -> int:
    """/proc/PID/mem, retried for ``wait_s``: under Yama the watched process allows this one to
    read it (``PR_SET_PTRACER``) only after the spawn has returned."""
    deadline = time.monotonic() + wait_s
    while True:
        try:
            return os.open(f"/proc/{pid}/mem", os.O_RDONLY)
        except PermissionError:
            if time.monotonic() > deadline or os.getppid() != pid:
                raise
            time.sleep(0.05)


def watch(pid: int, period_s: float, confirm_s: float, log: str | None) -> None:
    """The watcher's loop (see the module's docstring); returns when process ``pid`` ends."""
    libc = ctypes.CDLL(None, use_errno=True)
    mem = _open_mem(pid)
    seen: dict[int, tuple[tuple, float]] = {}  # tid -> ((addr, value, runs), since when)
    reported: set[tuple] = set()  # (tid, addr, value): a wait the signal did not end is said once
    while os.getppid() == pid:
        now = time.monotonic()
        for name in os.listdir(f"/proc/{pid}/task"):
            tid = int(name)
            try:
                lost = lost_wait(pid, tid, mem)
                runs = _runs(pid, tid) if lost else None
            except ValueError:  # a file cut short as the thread ended
                lost = runs = None
            if lost is None or runs is None:
                seen.pop(tid, None)
                continue
            addr, value, word = lost
            key = (addr, value, runs)  # the word may change again meanwhile: still lost while it differs
            if tid not in seen or seen[tid][0] != key:
                seen[tid] = (key, now)
                continue
            if now - seen[tid][1] < confirm_s:
                continue
            libc.syscall(ctypes.c_long(_TGKILL_NR), ctypes.c_int(pid), ctypes.c_int(tid), ctypes.c_int(WAKE_SIGNAL))
            if (tid, addr, value) not in reported:
                reported.add((tid, addr, value))
                comm = (_read(f"/proc/{pid}/task/{tid}/comm") or "?").strip()
                line = (
                    f"rose_usd: thread {tid} ({comm}) of process {pid} slept {now - seen[tid][1]:.1f} s on futex"
                    f" {addr:#x} waiting for {value} while the word held {word}: a lost wake-up; signalled it"
                    " (rose_usd/core/wakeup.py)"
                )
                _report(pid, line, log)
            seen[tid] = (key, now)  # signalled again after another confirm_s if it sleeps on
        time.sleep(period_s)


def _main(argv: list[str]) -> None:
    os.closerange(3, 1 << 16)  # any descriptor the watched process let it inherit (a pipe held open)
    pid, period_s, confirm_s = int(argv[0]), float(argv[1]), float(argv[2])
    log = argv[3] if len(argv) > 3 else None
    # core.lifetime.die_with_parent does this, but this script runs without the package (-I -S:
    # importing rose_usd would load USD into every watcher)
    try:  # end with the watched process (its thread that started this one, the main thread)
        ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)
    except (OSError, AttributeError):
        pass
    if os.getppid() != pid:
        return
    try:
        watch(pid, period_s, confirm_s, log)
    except PermissionError as exc:
        _report(pid, f"rose_usd: no stall watcher for process {pid}: {exc}", log)
    except (FileNotFoundError, ProcessLookupError):  # the watched process ended
        pass
    except Exception as exc:  # noqa: BLE001 - said where the watched process's errors go, then ended
        _report(pid, f"rose_usd: the stall watcher of process {pid} stopped: {exc!r}", log)


if __name__ == "__main__":
    _main(sys.argv[1:])
