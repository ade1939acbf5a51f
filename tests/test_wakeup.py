"""The stall watcher on a real lost wake-up: a thread asleep in FUTEX_WAIT on a word that another
thread changed without FUTEX_WAKE stays asleep until the watcher (a process of its own) signals
it, even while this process's main thread holds the GIL; threads that wait on words that did not
change are never signalled."""

import ctypes
import os
import platform
import signal
import threading
import time

import pytest

from rose_usd.core import wakeup

SYS_FUTEX = {"x86_64": 202, "aarch64": 98}
FUTEX_WAIT_PRIVATE, FUTEX_WAKE_PRIVATE = 128, 129

pytestmark = pytest.mark.skipif(not wakeup.supported(), reason="Linux on x86-64 or AArch64 only")


def _futex(word: ctypes.c_uint32, op: int, value: int) -> None:
    nr = SYS_FUTEX[platform.machine()]
    ctypes.CDLL(None, use_errno=True).syscall(ctypes.c_long(nr), ctypes.byref(word), op, value, None, None, 0)


def _asleep_on_futex(tid: int) -> bool:
    call = open(f"/proc/self/task/{tid}/syscall").read().split()
    return call[0] == str(SYS_FUTEX[platform.machine()])


def _sleeper(word: ctypes.c_uint32, done: threading.Event) -> int:
    """A thread that waits, the way a thread pool parks, until ``word`` is non-zero; its thread
    id once it is asleep."""
    tid = []

    def run():
        tid.append(threading.get_native_id())
        while word.value == 0:
            _futex(word, FUTEX_WAIT_PRIVATE, 0)
        done.set()

    threading.Thread(target=run, daemon=True).start()
    for _ in range(500):
        if tid and _asleep_on_futex(tid[0]):
            return tid[0]
        time.sleep(0.01)
    raise AssertionError("the sleeper never reached its futex wait")


@pytest.fixture
def watcher(tmp_path):
    """Start a fast watcher of this process (period 0.05 s, confirm 0.3 s); yields its log."""
    assert wakeup.install_handler()  # pytest runs tests on the main thread
    log = tmp_path / "stalls.log"
    pids = []
    yield lambda: pids.append(wakeup.start_watcher(period_s=0.05, confirm_s=0.3, log=str(log))) or log
    for pid in pids:
        os.kill(pid, signal.SIGKILL)
        os.waitpid(pid, 0)


def test_a_lost_wake_up_is_ended_even_while_this_process_holds_the_gil(watcher):
    word, done = ctypes.c_uint32(0), threading.Event()
    tid = _sleeper(word, done)
    word.value = 1  # the waker's store, without its FUTEX_WAKE: the wake-up is lost
    # (0.5 s: under the 2 s a watcher of this whole process, started by an earlier test's render, waits)
    assert not done.wait(0.5), "asleep on a changed word, it should not have noticed on its own"

    log = watcher()
    ctypes.PyDLL(None).usleep(2_000_000)  # holds the GIL: no thread of this process runs Python meanwhile
    text = log.read_text() if log.exists() else ""
    assert f"thread {tid} " in text and "waiting for 0 while the word held 1" in text  # signalled meanwhile
    assert done.wait(5.0), "the watcher did not wake the sleeper"


def test_threads_waiting_on_unchanged_words_are_never_signalled(watcher):
    word, done = ctypes.c_uint32(0), threading.Event()
    tid = _sleeper(word, done)
    lock, stop = threading.Lock(), threading.Event()
    lock.acquire()
    threading.Thread(target=lock.acquire, daemon=True).start()  # blocked on a held lock
    threading.Thread(target=lambda: [stop.wait(0.01) for _ in iter(stop.is_set, True)], daemon=True).start()
    log = watcher()
    time.sleep(1.5)  # five confirm periods
    stop.set()
    assert not log.exists() or log.read_text() == ""
    assert _asleep_on_futex(tid) and not done.is_set()
    word.value = 1
    _futex(word, FUTEX_WAKE_PRIVATE, 1)
    assert done.wait(5.0)
    lock.release()


def test_the_watcher_ends_with_the_process_it_watches():
    """Its period 60 s: only PR_SET_PDEATHSIG can end it within 2 s. The process ends once the
    watcher holds its memory open (in its loop)."""
    import subprocess
    import sys

    code = (
        "import os, time\nfrom rose_usd.core import wakeup\nwakeup.install_handler()\n"
        "w = wakeup.start_watcher(period_s=60.0)\nprint(w, flush=True)\n"
        "def holds_mem():\n"
        "    for fd in os.listdir(f'/proc/{w}/fd'):\n"
        "        try:\n"
        "            if os.readlink(f'/proc/{w}/fd/{fd}').endswith('/mem'):\n"
        "                return True\n"
        "        except FileNotFoundError:  # closed meanwhile (the watcher closes what it inherited)\n"
        "            pass\n"
        "    return False\n"
        "for _ in range(1000):\n"
        "    if holds_mem():\n"
        "        break\n"
        "    time.sleep(0.01)\n"
        "else:\n"
        "    raise SystemExit('the watcher never opened the memory')\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    pid = int(proc.stdout.strip())

    def alive() -> bool:  # a zombie (no init reaping it in a container) counts as ended
        try:
            return open(f"/proc/{pid}/stat").read().rsplit(")", 1)[1].split()[0] != "Z"
        except FileNotFoundError:
            return False

    deadline = time.monotonic() + 2.0
    while time.monotonic() < deadline and alive():
        time.sleep(0.02)
    assert not alive()
