"""SIGKILL at any point of a stage, its commit included, never leaves a mixed output folder: after
the kill and the recovery every writer runs first, the folder is the old result or the new one,
with no litter; a re-run then completes it.

The stage is ``run segment --force`` with every oracle backend on the sample's oracle output and
one shared segment setting changed that the oracle does not read: its commit replaces ``masks/``
and ``layers/masks.usda`` and removes the four layers it makes stale with their side folders.
(Without the setting the new layer differs from the old only by its wall time, and when the two
runs' wall times round to the same millisecond, nothing is stale: CI saw that once.) Kills land
at the k-th file operation (rename, unlink, rmtree, mkdir, fsync) of the process, which walks the
commit step by step, or after a random delay.
"""

from __future__ import annotations

import hashlib
import os
import random
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from rose_usd.usd.stage import consistency_problems, recover

WRAPPER = r"""
import os, shutil, signal, sys
k = int(os.environ.get("KILL_AT_CALL", "0"))
count = [0]
def counted(fn):
    def inner(*args, **kwargs):
        count[0] += 1
        if count[0] == k:
            os.kill(os.getpid(), signal.SIGKILL)
        return fn(*args, **kwargs)
    return inner
from rose_usd.cli import main
os.replace, os.unlink, os.mkdir, os.fsync = map(counted, (os.replace, os.unlink, os.mkdir, os.fsync))
shutil.rmtree = counted(shutil.rmtree)
code = main(sys.argv[1:])
sys.stderr.write(f"\nfile operations: {count[0]}\n")
sys.exit(code)
"""


def tree(root: Path) -> dict[str, str]:
    return {
        str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(root.rglob("*"))
        if p.is_file()
    }


def litter(root: Path) -> list[str]:
    return [str(p.relative_to(root)) for p in root.rglob(".*")]


def command(tmp: Path, case: Path, out: Path) -> list[str]:
    script = tmp / "wrapper.py"
    script.write_text(WRAPPER)
    return [
        sys.executable,
        str(script),
        "run",
        "segment",
        str(case),
        "-o",
        str(out),
        "--backend",
        "all=oracle",
        "--set",
        "segment.core_m=0.016",
        "--force",
        "--in-process",  # the file operations counted are this process's
    ]


def run(cmd, *, kill_at: int = 0, kill_after_s: float | None = None) -> tuple[int, str]:
    env = dict(os.environ, KILL_AT_CALL=str(kill_at), ROSE_USD_QUIET="1")
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    if kill_after_s is not None:
        try:
            proc.wait(timeout=kill_after_s)
        except subprocess.TimeoutExpired:
            proc.send_signal(signal.SIGKILL)
    _, err = proc.communicate(timeout=300)
    return proc.returncode, err


@pytest.fixture(scope="module")
def reference(tmp_path_factory, oracle_out, sample_case):
    """The old folder, the new one (a complete run) and how many file operations a run makes."""
    tmp = tmp_path_factory.mktemp("kill")
    new = tmp / "new"
    shutil.copytree(oracle_out, new)
    t0 = time.perf_counter()
    code, err = run(command(tmp, sample_case, new))
    assert code == 0, err
    ops = int(err.strip().rsplit(" ", 1)[1])
    return {"old": tree(oracle_out), "new": tree(new), "ops": ops, "seconds": time.perf_counter() - t0}


def is_old_or_new(out: Path, reference) -> str:
    now = tree(out)
    if now == reference["old"]:
        return "old"
    # the new layer carries its own wall time: every other file must be the new run's
    assert set(now) == set(reference["new"]), sorted(set(now) ^ set(reference["new"]))
    differ = [name for name in now if now[name] != reference["new"][name]]
    assert differ in ([], ["layers/masks.usda"]), differ
    assert consistency_problems(out) == []
    return "new"


def kill_and_check(tmp: Path, oracle_out: Path, case: Path, reference, **kill) -> str:
    out = tmp / "out"
    if out.exists():
        shutil.rmtree(out)
    shutil.copytree(oracle_out, out)
    run(command(tmp, case, out), **kill)
    recover(out)
    assert litter(out) == []
    state = is_old_or_new(out, reference)
    code, err = run(command(tmp, case, out))  # the re-run completes it
    assert code == 0, err
    assert litter(out) == [] and is_old_or_new(out, reference) == "new"
    return state


def test_kill_during_commit(tmp_path, oracle_out, sample_case, reference):
    """Kills at three file operations of the stage (its commit's first, middle and last steps):
    old or new after recovery, never a mix, no litter."""
    ops = reference["ops"]
    states = [
        kill_and_check(tmp_path, oracle_out, sample_case, reference, kill_at=k)
        for k in sorted({max(1, ops - 12), max(1, ops - 6), ops})
    ]
    assert "new" in states or "old" in states


@pytest.mark.slow
def test_twenty_random_kills(tmp_path, oracle_out, sample_case, reference):
    """20 kills at random file operations and random times (benchmark job)."""
    rng = random.Random(25)
    states = []
    for i in range(20):
        if i % 2:
            kill = {"kill_at": rng.randint(1, reference["ops"])}
        else:
            kill = {"kill_after_s": rng.uniform(0.5, reference["seconds"])}
        states.append(kill_and_check(tmp_path, oracle_out, sample_case, reference, **kill))
    print("states after the kills:", {s: states.count(s) for s in set(states)})
