"""The stall guard on a real lost wake-up: a thread asleep in FUTEX_WAIT on a word that another
thread changed without FUTEX_WAKE stays asleep until the guard signals it."""

import ctypes
import platform
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


def _sleeper(word: ctypes.c_uint32, done: threading.Event, then_run_s: float = 0.0) -> int:
    """A thread that waits, the way a thread pool parks, until ``word`` is non-zero, then runs
    ``then_run_s`` of CPU; its thread id once it is asleep."""
    tid = []

    def run():
        tid.append(threading.get_native_id())
        while word.value == 0:
            _futex(word, FUTEX_WAIT_PRIVATE, 0)
        start = time.thread_time()
        while time.thread_time() - start < then_run_s:
            pass
        done.set()

    threading.Thread(target=run, daemon=True).start()
    for _ in range(500):
        if tid and tid[0] in wakeup.futex_sleepers():
            return tid[0]
        time.sleep(0.01)
    raise AssertionError("the sleeper never reached its futex wait")


def test_a_lost_wake_up_stalls_until_the_guard_wakes_the_sleeper(capfd, tmp_path, monkeypatch):
    monkeypatch.setenv(wakeup.LOG_ENV, str(tmp_path / "stalls.log"))
    assert wakeup.install_handler()  # pytest runs tests on the main thread
    word, done = ctypes.c_uint32(0), threading.Event()
    tid = _sleeper(word, done, then_run_s=0.5)
    word.value = 1  # the waker's store, without its FUTEX_WAKE: the wake-up is lost
    assert not done.wait(1.0), "asleep on a changed word, it should not have noticed on its own"
    assert tid in wakeup.futex_sleepers()

    guard = wakeup.StallGuard(stall_s=0.3, period_s=0.1).start()
    try:
        assert done.wait(10.0), "the guard did not wake the sleeper"
        assert tid in guard.signalled
        deadline = time.monotonic() + 5.0
        while not guard.stuck and time.monotonic() < deadline:
            time.sleep(0.05)
        assert len(guard.stuck) == 1  # it ran on after its wake-up: reported
    finally:
        guard.stop()
    assert f"thread {tid} " in capfd.readouterr().err
    assert f"thread {tid} " in (tmp_path / "stalls.log").read_text()


def test_a_sleeper_whose_word_did_not_change_goes_back_to_sleep():
    assert wakeup.install_handler()
    word, done = ctypes.c_uint32(0), threading.Event()
    tid = _sleeper(word, done)
    guard = wakeup.StallGuard(stall_s=0.2, period_s=0.05).start()
    try:
        deadline = time.monotonic() + 10.0
        while guard.signalled.count(tid) < 2 and time.monotonic() < deadline:
            time.sleep(0.05)
        assert guard.signalled.count(tid) >= 2  # signalled, and asleep again each time
        assert not done.is_set() and tid in wakeup.futex_sleepers() and not guard.stuck
    finally:
        guard.stop()
        word.value = 1
        _futex(word, FUTEX_WAKE_PRIVATE, 1)
    assert done.wait(5.0)


def test_a_running_thread_is_not_signalled():
    assert wakeup.install_handler()
    guard = wakeup.StallGuard(stall_s=0.2, period_s=0.05).start()
    try:
        end = time.monotonic() + 1.5
        while time.monotonic() < end:  # this thread runs throughout
            sum(range(1000))
        assert threading.get_native_id() not in guard.signalled
    finally:
        guard.stop()
