"""Stages run each in a child process of its own (``Options.isolate``, the CLI's default): the same
layer as in the caller's process, errors that cross back whole, and no child left running when
the run is killed."""

from __future__ import annotations

import os
import pickle
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from conftest import oracle_options

from rose_usd import registry
from rose_usd.errors import InputError, MeshError
from rose_usd.pipeline import Options, Pipeline
from rose_usd.usd.stage import layer_file


def test_errors_cross_processes_whole():
    err = InputError("nothing stands on the support", path="/x/rose.toml", hint="draw the box around it")
    err.finished_stages = {"capture": 1.0}
    back = pickle.loads(pickle.dumps(err))
    assert type(back) is InputError
    assert (back.message, back.path, back.hint) == (err.message, err.path, err.hint)
    assert back.one_line() == err.one_line() and str(back) == str(err)
    assert back.finished_stages == {"capture": 1.0}
    assert pickle.loads(pickle.dumps(MeshError("empty"))).one_line() == "empty."


def test_a_stage_that_ended_early_says_how():
    """A stage's process that ended without its outcome: Ctrl-C is an interrupt, SIGTERM a stop,
    SIGKILL (the out-of-memory killer's) says memory; none speaks of memory otherwise."""
    from rose_usd.pipeline import _ended_early

    assert isinstance(_ended_early("gate", -signal.SIGINT, Path("/o")), KeyboardInterrupt)
    assert isinstance(_ended_early("gate", 130, Path("/o")), KeyboardInterrupt)
    assert "stopped (SIGTERM)" in _ended_early("gate", -signal.SIGTERM, Path("/o")).one_line()
    killed = _ended_early("gate", -signal.SIGKILL, Path("/o")).one_line()
    assert "killed" in killed and "memory" in killed and "the same command goes on" in killed
    other = _ended_early("gate", 3, Path("/o")).one_line()
    assert "exit code 3" in other and "memory" not in other


def test_isolated_stage_writes_the_layer_the_caller_would(tmp_path, oracle_out, sample_case):
    layers = {}
    for isolate in (False, True):
        out = tmp_path / f"isolate-{isolate}"
        shutil.copytree(oracle_out, out)
        options = oracle_options()
        pipe = Pipeline(sample_case, out, Options(backends=options.backends, force=True, isolate=isolate))
        outcome = pipe.run_stage(registry.get("object"))
        assert outcome.status == "ran" and outcome.backend == "oracle"
        layers[isolate] = layer_file(out, "object").read_text()
    strip = lambda text: "\n".join(line for line in text.splitlines() if "wall_time_s" not in line)  # noqa: E731
    assert strip(layers[True]) == strip(layers[False])


def _children(pid: int) -> list[int]:
    path = Path(f"/proc/{pid}/task/{pid}/children")
    return [int(v) for v in path.read_text().split()] if path.exists() else []


def _alive(pid: int) -> bool:
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except FileNotFoundError:
        return False
    return stat.rsplit(")", 1)[1].split()[0] != "Z"


def _catches_sigint(pid: int) -> bool:
    """Whether process ``pid`` has a handler for SIGINT (``SigCgt`` in its /proc status)."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except FileNotFoundError:
        return False
    caught = next(line.split()[1] for line in status.splitlines() if line.startswith("SigCgt:"))
    return bool(int(caught, 16) >> (signal.SIGINT - 1) & 1)


def _stage_children(proc: subprocess.Popen, wait_s: float = 120.0) -> list[int]:
    """The spawned stage process(es) of ``proc``, once there is one."""
    deadline = time.monotonic() + wait_s
    children: list[int] = []
    while time.monotonic() < deadline and not children:
        time.sleep(0.2)
        children = [c for c in _children(proc.pid) if "spawn_main" in Path(f"/proc/{c}/cmdline").read_text()]
    assert children, "the stage never started in a child process"
    return children


def test_a_killed_run_leaves_no_stage_running(tmp_path, oracle_out, sample_case):
    if not sys.platform.startswith("linux"):
        return
    out = tmp_path / "out"
    shutil.copytree(oracle_out, out)
    cmd = [sys.executable, "-m", "rose_usd.cli", "run", "gate", str(sample_case), "-o", str(out), "--force"]
    cmd += ["--backend", "all=oracle"]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=dict(os.environ))
    children = _stage_children(proc)
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=30)
    deadline = time.monotonic() + 5  # the gate alone takes longer: a child that outlived it fails
    while time.monotonic() < deadline and any(_alive(c) for c in children):
        time.sleep(0.2)
    assert not any(_alive(c) for c in children)


def _parent(pid: int) -> int:
    stat = Path(f"/proc/{pid}/stat").read_text()
    return int(stat[stat.rindex(")") + 2 :].split()[1])


def _processes_running(module: str, root: int) -> list[int]:
    """Live processes running ``module`` that descend from ``root`` (the run the test started):
    another rose run on the machine is not the test's."""
    found = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                pid = int(entry.name)
                if module not in (entry / "cmdline").read_text() or not _alive(pid):
                    continue
                ancestor = _parent(pid)
                while ancestor not in (0, 1, root):
                    ancestor = _parent(ancestor)
                if ancestor == root:
                    found.append(pid)
            except (OSError, ValueError):
                pass
    return found


@pytest.mark.parametrize(
    "stage, backend, target",
    [
        ("gate", "all=oracle", "group"),
        ("gate", "all=oracle", "parent"),
        ("gate", "all=oracle", "group, parent ignoring it"),
        ("capture", "capture=rgbd", "group"),
    ],
)
def test_ctrl_c_says_interrupted_and_keeps_the_layer(tmp_path, oracle_out, sample_case, stage, backend, target):
    """Ctrl-C during an isolated stage, from a terminal (SIGINT to the process group) or sent to
    the parent alone, or to the group of a parent that ignores it (a script's background job):
    exit 130 with "interrupted" and no traceback, no process left running (the capture's one-CPU
    tracker included), and the stage's previous layer as it was."""
    if not sys.platform.startswith("linux"):
        return
    handler = "signal.SIG_IGN" if "ignoring" in target else "signal.default_int_handler"
    start = f"import signal, sys; signal.signal(signal.SIGINT, {handler}); "
    start += "from rose_usd.cli import main; sys.exit(main(sys.argv[1:]))"
    out = tmp_path / "out"
    shutil.copytree(oracle_out, out)
    layer = "world" if stage == "capture" else stage
    before = layer_file(out, layer).read_bytes()
    cmd = [sys.executable, "-c", start, "run", stage, str(sample_case), "-o", str(out), "--force"]
    cmd += ["--backend", backend]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, start_new_session=True)
    children = _stage_children(proc)
    deadline = time.monotonic() + 60
    if stage == "capture":  # until its tracker runs
        trackers: list[int] = []
        while time.monotonic() < deadline and not trackers:
            trackers = _processes_running("rose_usd.capture.tracking", proc.pid)
            time.sleep(0.1)
        assert trackers, "the capture's tracker never ran"
        children += trackers
    else:  # into the stage's work: its child catches SIGINT (it starts ignoring it, as the parent does meanwhile)
        while time.monotonic() < deadline + 60 and all(_alive(c) for c in children):
            if all(_catches_sigint(c) for c in children):
                break
            time.sleep(0.1)
        assert all(_catches_sigint(c) for c in children), "the stage's child never caught SIGINT"
        time.sleep(1.0)
    if target.startswith("group"):
        os.killpg(proc.pid, signal.SIGINT)
    else:
        proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    assert err.strip().splitlines()[-1] == "interrupted" and "Traceback" not in err, err
    time.sleep(0.5)
    assert not any(_alive(c) for c in children)  # the tracker's too, which runs in a session of its own
    assert layer_file(out, layer).read_bytes() == before


def test_a_tracker_whose_parent_sent_nothing_leaves_quietly():
    """The capture's one-CPU tracker started, then its parent was interrupted before it sent the
    work (its stdin closed empty): exit 1 and nothing on stderr, not an EOFError traceback under
    the parent's "interrupted" (seen once in a fresh clone's test run)."""
    proc = subprocess.run(
        [sys.executable, "-m", "rose_usd.capture.tracking"], input=b"", capture_output=True, timeout=120
    )
    assert proc.returncode == 1
    assert proc.stderr.decode().strip() == ""


def test_an_interrupt_after_the_first_is_nothing_when_a_library_restored_the_handler():
    """A Ctrl-C test of the gate stage printed "OSError: Signal 2 ignored due to race condition"
    with a traceback: the stage's SIGINT handler had set SIG_IGN, and Mitsuba's render, which saves
    and restores the process's C-level SIGINT handler around itself, put Python's back, so a later
    SIGINT was caught at C level and found SIG_IGN at Python's. Emulated with libc.signal: with
    ``lifetime.after_interrupt`` as the handler after the first interrupt, nothing is printed."""
    code = """
import ctypes, os, signal, sys, time
from rose_usd.core.lifetime import after_interrupt
libc = ctypes.CDLL(None)
libc.signal.restype = ctypes.c_void_p
libc.signal.argtypes = [ctypes.c_int, ctypes.c_void_p]
signal.signal(signal.SIGINT, lambda *a: None)
python_handler = libc.signal(signal.SIGINT, 1)  # what a library saves (1: SIG_IGN, put back at once)
libc.signal(signal.SIGINT, python_handler)
signal.signal(signal.SIGINT, signal.SIG_IGN if sys.argv[1] == "ign" else after_interrupt)
libc.signal(signal.SIGINT, python_handler)  # and restores, after the stage's handler changed it
os.kill(os.getpid(), signal.SIGINT)
time.sleep(0.1)
"""
    errs = {
        mode: subprocess.run([sys.executable, "-c", code, mode], capture_output=True, text=True, timeout=60).stderr
        for mode in ("ign", "after")
    }
    assert "Signal 2 ignored due to race condition" in errs["ign"], errs
    assert errs["after"] == "", errs


def test_an_interrupt_during_an_import_is_raised_once_the_import_is_over(tmp_path):
    """A fresh clone's Ctrl-C test of the gate saw its stage's process abort (exit -6,
    "terminate called after throwing an instance of 'nanobind::python_error'"): the
    KeyboardInterrupt was raised inside Mitsuba's import, through a native module's init. A SIGINT
    that finds an import running is raised once it is over: the module is whole, then it stops."""
    (tmp_path / "slow_module.py").write_text(
        "import os, signal, time\nos.kill(os.getpid(), signal.SIGINT)\ntime.sleep(0.5)\nDONE = True\n"
    )
    script = (
        "import signal, sys\n"
        "from rose_usd.core.lifetime import raise_after_import\n"
        "def on_sigint(signum, frame):\n"
        "    if raise_after_import(frame):\n"
        "        return\n"
        "    raise KeyboardInterrupt\n"
        "signal.signal(signal.SIGINT, on_sigint)\n"
        "try:\n"
        "    import slow_module\n"
        "    print('imported', slow_module.DONE, flush=True)\n"
        "    import time; time.sleep(5)\n"
        "    print('not interrupted', flush=True)\n"
        "except KeyboardInterrupt:\n"
        "    print('interrupted after', 'slow_module' in sys.modules, flush=True)\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", script], cwd=tmp_path, capture_output=True, text=True, timeout=60,
        env=dict(os.environ, PYTHONPATH=os.pathsep.join([str(tmp_path), *sys.path])),
    )  # fmt: skip
    assert done.stdout.split("\n")[:2] == ["imported True", "interrupted after True"], done.stdout + done.stderr
