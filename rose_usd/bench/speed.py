"""``rose-usd bench speed``: wall time and peak memory of one stage on a long case (default 300
frames at 640x480, the size the speed targets are set for), each stage in its own process like
the suites."""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

from rose_usd.bench.runner import DEFAULT_CASES, _git_commit, ensure_case
from rose_usd.bench.suites import CaseSpec
from rose_usd.bench.worker import run_worker
from rose_usd.progress import say
from rose_usd.synth.motion import Task
from rose_usd.synth.shapes import ObjectShape


def speed_case(frames: int, width: int, height: int, cases_dir: Path = DEFAULT_CASES) -> tuple[Path, float]:
    spec = CaseSpec(Task.PUSH, ObjectShape.MUG, seed=900, n_frames=frames, width=width, height=height, spp=8)
    return ensure_case(spec, Path(cases_dir) / "speed")


def measure(
    stage: str,
    backends: dict,
    *,
    frames: int = 300,
    width: int = 640,
    height: int = 480,
    out_dir: Path,
    cases_dir: Path = DEFAULT_CASES,
) -> dict:
    """Run ``stage`` (after its prerequisites, which are not timed) and report its wall time."""
    case, gen_time = speed_case(frames, width, height, cases_dir)
    out_dir = Path(out_dir)
    run_out = out_dir / "runs" / f"{stage}-{frames}x{width}x{height}"
    result_file = out_dir / "runs" / f"{stage}-{frames}x{width}x{height}.json"
    say(f"bench speed: {stage} on {case} ({frames} frames {width}x{height})")
    t0 = time.perf_counter()
    run_worker(case, run_out, result_file, backends, until=stage)
    result = json.loads(result_file.read_text())
    if "error" in result:
        return {"stage": stage, "error": result["error"]}
    st = result["stages"][stage]
    summary = {
        "stage": stage,
        "backend": st["backend"],
        "frames": frames,
        "size": [width, height],
        "wall_time_s": st["wall_time_s"],
        "frames_per_s": round(frames / st["wall_time_s"], 2),
        "peak_rss_mb": st["peak_rss_mb"],
        "all_stages": result["stages"],
        "case_generate_time_s": round(gen_time, 1),
        "process_wall_time_s": round(time.perf_counter() - t0, 1),
        "commit": _git_commit(),
        "cpus": os.cpu_count(),
    }
    (out_dir / f"speed-{stage}.json").write_text(json.dumps(summary, indent=1) + "\n")
    return summary
