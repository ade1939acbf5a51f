"""Shared fixtures. The sample's oracle reconstruction is made once per run and reused."""

from __future__ import annotations

import fcntl
import os
import shutil
from pathlib import Path

import numpy as np
import pytest

os.environ.setdefault("ROSE_USD_QUIET", "1")

REPO = Path(__file__).resolve().parents[1]
SAMPLE = REPO / "samples" / "push-box"
REFERENCE = REPO / "stages" / "push-box-oracle.json"


def oracle_options():
    """Every stage's oracle backend: the sample's ground-truth reconstruction."""
    from rose_usd.pipeline import Options

    return Options(backends={"all": "oracle"})


HUNG_TEST_S = 1000
"""Past this, a test's process prints every thread's stack and ends (``faulthandler``, from C:
it needs no GIL, where pytest-timeout's signal needs the main thread back in Python). Set only
where ``ROSE_USD_HUNG_STACKS`` is (CI): the stacks go to ``$ROSE_USD_HUNG_STACKS.PID``."""


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    import faulthandler

    prefix = os.environ.get("ROSE_USD_HUNG_STACKS")
    if not prefix:
        yield
        return
    with open(f"{prefix}.{os.getpid()}", "w") as f:  # this test's name, then the stacks if it hangs
        f.write(f"{item.nodeid} ran past {HUNG_TEST_S} s: every thread's stack, then its process ended\n")
        f.flush()
        faulthandler.dump_traceback_later(HUNG_TEST_S, exit=True, file=f)
        try:
            yield
        finally:
            faulthandler.cancel_dump_traceback_later()


@pytest.fixture(autouse=True)
def _no_thread_left_real_time():
    """A test after which a thread of its process runs real-time fails, and the threads are put
    back: every process started from such a thread would inherit it, and real-time threads that
    spin on two cores stall one another for many minutes (``rose_usd/core/realtime.py``)."""
    from rose_usd.core.realtime import scheduling, undo_realtime

    before = scheduling()
    yield
    left = undo_realtime(before)
    if left:
        pytest.fail(
            f"{len(left)} thread(s) of the test process left real-time (SCHED_FIFO/RR)"
            + (", the main one among them" if os.getpid() in left else "")
        )


def pytest_addoption(parser):
    parser.addoption(
        "--update-reference", action="store_true", help="rewrite stages/*.json from this run (deliberate golden update)"
    )


@pytest.fixture(scope="session")
def sample_case() -> Path:
    assert SAMPLE.is_dir(), f"bundled sample missing: {SAMPLE}"
    return SAMPLE


@pytest.fixture(scope="session")
def oracle_out(tmp_path_factory, sample_case, worker_id) -> Path:
    """The sample reconstructed with every stage's oracle backend (read-only for tests). Under
    pytest-xdist the workers share one, made by the first that asks (about 100 s each)."""
    from rose_usd.pipeline import Pipeline

    if worker_id == "master":
        root = tmp_path_factory.mktemp("oracle")
    else:  # this run's, beside the workers' own temporary folders
        root = tmp_path_factory.getbasetemp().parent / "oracle"
        root.mkdir(exist_ok=True)
    out = root / "out"
    with open(root / "lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not (root / "done").exists():
            shutil.rmtree(out, ignore_errors=True)
            Pipeline(sample_case, out, oracle_options()).run()
            (root / "done").touch()
    return out


@pytest.fixture
def case_copy(tmp_path, sample_case) -> Path:
    """A writable copy of the sample case, to break on purpose."""
    dst = tmp_path / "case"
    shutil.copytree(sample_case, dst)
    return dst


@pytest.fixture
def out_copy(tmp_path, oracle_out) -> Path:
    """A writable copy of the oracle reconstruction."""
    dst = tmp_path / "out"
    shutil.copytree(oracle_out, dst)
    return dst


def made_from(out: Path, case: Path) -> None:
    """Point the provenance of ``out``'s layers at ``case``, a copy of the case they were made from
    (an output folder holds one case's stages: ``usd.stage.check_out_case``)."""
    import json

    from pxr import Sdf

    from rose_usd.usd.stage import existing_layers, layer_file

    for name in existing_layers(out):
        layer = Sdf.Layer.FindOrOpen(str(layer_file(out, name)))
        data = dict(layer.customLayerData)
        prov = json.loads(data["rose"])
        prov["case"] = str(Path(case).resolve())
        data["rose"] = json.dumps(prov)
        layer.customLayerData = data
        layer.Save()


def can_on_box():
    """A green can standing on a purple box on a noisy grey table, seen from the front: the box's
    prompt holds the can's lower half. Returns the image, the two prompts and the true masks."""
    rng = np.random.default_rng(5)
    rgb = rng.integers(120, 170, (240, 320, 3)).astype(np.uint8)
    box, can = np.zeros((240, 320), bool), np.zeros((240, 320), bool)
    box[140:200, 100:220] = True
    can[70:160, 130:190] = True
    rgb[box] = (110, 40, 140)
    rgb[can] = (40, 170, 60)
    rgb[can & (np.arange(320)[None, :] % 12 < 2)] = (20, 90, 30)  # a print on the can
    return rgb, {"Box": (95, 135, 225, 205), "Can": (125, 65, 195, 165)}, {"Box": box & ~can, "Can": can}
