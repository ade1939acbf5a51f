"""``rose-usd bench speed``: wall time and peak memory on a long generated case (default 300
frames at 640x480, the size the speed targets are set for).

``bench speed STAGE`` times one stage (its prerequisites run first, untimed);
``bench speed all`` runs every stage with the auto backends and the gate on every frame, and
reports each stage's wall time, the end-to-end time, the peak memory of the whole process tree,
and, given several lengths (``--frames 75,150,300``), how the time scales with the frame count.
Every run is a fresh process like the suites'."""

from __future__ import annotations

import json
import os
import platform
import shutil
import subprocess
import time
from pathlib import Path

from rose_usd.bench.runner import DEFAULT_CASES, _git_commit, ensure_case
from rose_usd.bench.suites import CaseSpec
from rose_usd.bench.worker import run_worker
from rose_usd.progress import say
from rose_usd.synth.motion import Task
from rose_usd.synth.shapes import ObjectShape

ALL = "all"
"""``bench speed all``: every stage, end to end."""

ALL_SETTINGS = {"gate": {"frame_stride": 1}}
"""What ``bench speed all`` sets on top of the defaults: the gate re-renders every frame."""


SPEED_CASE = dict(task=Task.ROTATE, shape=ObjectShape.MUG, seed=304, spp=8, realistic=True)
"""The realistic suite's rotate-mug case (rotate-mug-s304: a hand-held camera, a hand whose
fingers wrap the mug), at the length and size asked for. The push-mug cases used before (seed
900, and the default suite's seed 203) fail the object stage at 75 and 150 frames ("object 'Mug'
is never clearly visible"), so they cannot time the whole pipeline."""


def speed_case(frames: int, width: int, height: int, cases_dir: Path = DEFAULT_CASES) -> tuple[Path, float]:
    spec = CaseSpec(**SPEED_CASE, n_frames=frames, width=width, height=height)
    # one folder per length and size: the case's name does not say them, and the scaling run
    # (75, 150, 300 frames) needs all of them side by side
    return ensure_case(spec, Path(cases_dir) / "speed" / f"{frames}f-{width}x{height}")


def machine() -> dict:
    """What the timings were taken on: CPU count, processor, and the NVIDIA GPU when there is one."""
    info = {"cpus": os.cpu_count(), "processor": platform.processor() or platform.machine(), "gpu": None}
    if shutil.which("nvidia-smi"):
        try:
            out = subprocess.run(
                ["nvidia-smi", "--query-gpu=name", "--format=csv,noheader"], capture_output=True, text=True, timeout=20
            )
            info["gpu"] = out.stdout.strip() or None
        except (OSError, subprocess.SubprocessError):
            pass
    return info


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


def _fit_linear(xs: list[float], ys: list[float]) -> dict | None:
    """Least-squares ``y = a + b x`` and how much of y it explains (R^2); None under two points."""
    n = len(xs)
    if n < 2 or len(set(xs)) < 2:
        return None
    mx, my = sum(xs) / n, sum(ys) / n
    sxx = sum((x - mx) ** 2 for x in xs)
    b = sum((x - mx) * (y - my) for x, y in zip(xs, ys)) / sxx
    a = my - b * mx
    ss_tot = sum((y - my) ** 2 for y in ys)
    ss_res = sum((y - a - b * x) ** 2 for x, y in zip(xs, ys))
    return {
        "fixed_s": round(a, 2),
        "per_frame_s": round(b, 4),
        "r2": round(1 - ss_res / ss_tot, 4) if ss_tot > 0 else 1.0,
    }


def scaling(runs: list[dict]) -> dict:
    """How end-to-end and per-stage time grow with the frame count: a linear fit over the runs
    (cost linear in frames: a small fixed part, R^2 near 1) and each run's seconds per frame."""
    ok = sorted((r for r in runs if "error" not in r), key=lambda r: r["frames"])
    frames = [r["frames"] for r in ok]
    out = {
        "frames": frames,
        "end_to_end_s": [r["end_to_end_s"] for r in ok],
        "s_per_frame": [round(r["end_to_end_s"] / r["frames"], 3) for r in ok],
        "fit": _fit_linear(frames, [r["end_to_end_s"] for r in ok]),
        "stages": {},
    }
    for name in ok[0]["stages"] if ok else []:
        times = [r["stages"][name]["wall_time_s"] for r in ok]
        out["stages"][name] = {"wall_time_s": times, "fit": _fit_linear(frames, times)}
    return out


def measure_all(
    backends: dict,
    *,
    frames: list[int] | tuple[int, ...] = (300,),
    width: int = 640,
    height: int = 480,
    out_dir: Path,
    cases_dir: Path = DEFAULT_CASES,
    until: str | None = None,
) -> dict:
    """Every stage (``until``: only that stage and what it needs) on the speed case of each
    length in ``frames``, each length in a fresh process; writes ``OUT/speed-all.json``."""
    from rose_usd.bench.worker import EVERY_STAGE

    until = until or EVERY_STAGE
    out_dir = Path(out_dir)
    runs = []
    for n in frames:
        case, gen_time = speed_case(n, width, height, cases_dir)
        tag = f"all-{n}x{width}x{height}"
        run_out, result_file = out_dir / "runs" / tag, out_dir / "runs" / f"{tag}.json"
        say(f"bench speed: stages {until} on {case} ({n} frames {width}x{height})")
        t0 = time.perf_counter()
        run_worker(case, run_out, result_file, backends, settings=ALL_SETTINGS, until=until)
        process_wall = time.perf_counter() - t0
        result = json.loads(result_file.read_text())
        if "error" in result:
            runs.append({"frames": n, "error": result["error"], "finished_stages": result.get("finished_stages")})
            continue
        stages = result["stages"]
        gate_file = run_out / "report" / "gate.json"
        gate = json.loads(gate_file.read_text()) if gate_file.is_file() else {}
        runs.append(
            {
                "frames": n,
                "stages": stages,
                "stages_total_s": round(sum(s["wall_time_s"] for s in stages.values()), 2),
                "end_to_end_s": result["pipeline_wall_time_s"],
                "frames_per_s": round(n / result["pipeline_wall_time_s"], 2),
                "peak_rss_tree_mb": result["peak_rss_tree_mb"],
                "render_variant": gate.get("render_variant"),
                "gate_ssim_mean": gate.get("ssim_mean"),
                "gate_passed": gate.get("passed"),
                "evaluate_time_s": result["evaluate_time_s"],
                "process_wall_time_s": round(process_wall, 1),
                "case_generate_time_s": round(gen_time, 1),
            }
        )
    summary = {
        "stage": ALL,
        "until": until,
        "backends": backends or "auto",
        "settings": ALL_SETTINGS,
        "size": [width, height],
        "runs": runs,
        "scaling": scaling(runs),
        "peak_rss_tree_mb": max((r["peak_rss_tree_mb"] for r in runs if "error" not in r), default=None),
        "commit": _git_commit(),
        "machine": machine(),
        "date": time.strftime("%Y-%m-%d"),
    }
    if any("error" in r for r in runs):
        summary["error"] = "; ".join(f"{r['frames']} frames: {r['error']}" for r in runs if "error" in r)
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "speed-all.json").write_text(json.dumps(summary, indent=1) + "\n")
    return summary


def table(summary: dict) -> str:
    """``bench speed all``'s result as a Markdown table: one row per stage, one column per length."""
    runs = [r for r in summary["runs"] if "error" not in r]
    if not runs:
        return "no run finished: " + summary.get("error", "")
    head = "| stage | backend | " + " | ".join(f"{r['frames']} frames (s)" for r in runs) + " |"
    lines = [head, "|" + " --- |" * (2 + len(runs))]
    for name, st in runs[-1]["stages"].items():
        cells = [f"{r['stages'][name]['wall_time_s']:.1f}" if name in r["stages"] else "-" for r in runs]
        lines.append(f"| {name} | {st['backend']} | " + " | ".join(cells) + " |")
    lines.append("| **end to end** | | " + " | ".join(f"**{r['end_to_end_s']:.1f}**" for r in runs) + " |")
    lines.append("| peak RSS, process tree (MB) | | " + " | ".join(f"{r['peak_rss_tree_mb']:.0f}" for r in runs) + " |")
    return "\n".join(lines)
