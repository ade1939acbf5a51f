"""``bench speed all``: every stage end to end on a tiny generated case at two lengths, per-stage
times, end-to-end time, peak memory of the process tree and the frame scaling in speed-all.json
(no timing asserts: CI machines differ)."""

import dataclasses
import json
import subprocess
import sys
import time
from pathlib import Path

import pytest

from rose_usd.bench import speed
from rose_usd.bench.runner import ensure_case
from rose_usd.bench.speed import ALL_SETTINGS, _fit_linear, measure_all, table
from rose_usd.bench.suites import SUITES
from rose_usd.bench.worker import tree_rss_bytes
from rose_usd.cli import _frame_counts
from rose_usd.errors import ConfigError
from rose_usd.registry import STAGE_NAMES
from rose_usd.synth.motion import Task


def test_speed_all_on_a_tiny_case(tmp_path, monkeypatch):
    # the small suite's push case (160x120) at two lengths stands in for the 640x480 speed case
    push = next(s for s in SUITES["small"] if s.task == Task.PUSH)

    def tiny_case(frames, width, height, cases_dir):
        spec = dataclasses.replace(push, n_frames=frames, width=width, height=height)
        return ensure_case(spec, Path(cases_dir) / "speed" / f"{frames}f-{width}x{height}")

    monkeypatch.setattr(speed, "speed_case", tiny_case)
    out = tmp_path / "speed"
    # oracle backends where a stage has one: this tests the measuring, not perception on 160x120
    backends = {"all": "oracle"}
    summary = measure_all(backends, frames=[12, 16], width=160, height=120, out_dir=out, cases_dir=tmp_path / "cases")
    assert summary.get("error") is None, summary.get("error")
    assert json.loads((out / "speed-all.json").read_text()) == summary
    assert summary["until"] == "all" and summary["settings"] == ALL_SETTINGS
    assert [r["frames"] for r in summary["runs"]] == [12, 16]
    for run in summary["runs"]:
        assert list(run["stages"]) == list(STAGE_NAMES)  # every stage, in run order
        assert all(s["backend"] != "auto" and s["wall_time_s"] > 0 for s in run["stages"].values())
        assert run["stages"]["capture"]["backend"] == "oracle" and run["stages"]["gate"]["backend"] != "oracle"
        assert run["end_to_end_s"] >= 0.99 * run["stages_total_s"]
        assert run["peak_rss_tree_mb"] >= max(s["peak_rss_mb"] for s in run["stages"].values()) > 50
        assert run["render_variant"]
    scaling = summary["scaling"]
    assert scaling["frames"] == [12, 16] and set(scaling["stages"]) == set(STAGE_NAMES)
    assert scaling["fit"] is not None and len(scaling["s_per_frame"]) == 2
    text = table(summary)
    assert "end to end" in text and all(name in text for name in STAGE_NAMES)


def test_tree_rss_counts_children():
    """A child holding 200 MB counts in the tree's resident memory, not in this process's."""
    code = "import sys,time; b=bytearray(200*2**20); b[::4096]=b'x'*len(b[::4096]); print(1,flush=True); time.sleep(30)"
    child = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE)
    try:
        assert child.stdout.readline().strip() == b"1"
        time.sleep(0.1)
        alone = tree_rss_bytes(child.pid)
        assert alone > 190 * 2**20
        assert tree_rss_bytes() >= alone
    finally:
        child.kill()
        child.wait()


def test_linear_fit_and_frame_lists():
    fit = _fit_linear([75, 150, 300], [10 + 0.2 * n for n in (75, 150, 300)])
    assert fit == {"fixed_s": 10.0, "per_frame_s": 0.2, "r2": 1.0}
    assert _fit_linear([300], [70.0]) is None
    assert _frame_counts("75,150,300") == [75, 150, 300] and _frame_counts("300") == [300]
    for bad in ("", "abc", "1", "75,x"):
        with pytest.raises(ConfigError):
            _frame_counts(bad)
