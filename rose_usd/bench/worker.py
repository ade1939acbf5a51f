"""One benchmark case in its own process: run every stage, measure wall time and peak memory per
stage, score the result. ``python -m rose_usd.bench.worker --case C --out O --result R.json``."""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import threading
import time
import traceback
from pathlib import Path

_PAGE = os.sysconf("SC_PAGE_SIZE")


def _rss_bytes(pid: int | str = "self") -> int:
    try:
        with open(f"/proc/{pid}/statm") as f:
            return int(f.read().split()[1]) * _PAGE
    except (OSError, IndexError, ValueError):  # the process ended meanwhile
        return 0


def _children(pid: int) -> list[int]:
    """The live child processes of ``pid`` (Linux's /proc/PID/task/TID/children)."""
    kids = []
    try:
        tasks = os.listdir(f"/proc/{pid}/task")
    except OSError:
        return kids
    for tid in tasks:
        try:
            with open(f"/proc/{pid}/task/{tid}/children") as f:
                kids += [int(k) for k in f.read().split()]
        except (OSError, ValueError):
            pass
    return kids


def tree_rss_bytes(pid: int | None = None) -> int:
    """Resident memory of ``pid`` (default this process) and all its descendants together."""
    todo, total, seen = [pid or os.getpid()], 0, set()
    while todo:
        p = todo.pop()
        if p in seen:
            continue
        seen.add(p)
        total += _rss_bytes(p)
        todo += _children(p)
    return total


class RssMonitor:
    """Samples the resident memory of this process and its child processes together every 10 ms;
    ``peak_mb()`` since the last ``reset()``, ``overall_peak_mb()`` since the start."""

    def __init__(self, interval_s: float = 0.01):
        self._peak = 0
        self._overall = 0
        self._stop = threading.Event()
        self._interval = interval_s
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _sample(self) -> int:
        rss = tree_rss_bytes()
        self._peak = max(self._peak, rss)
        self._overall = max(self._overall, rss)
        return rss

    def _run(self) -> None:
        while not self._stop.is_set():
            self._sample()
            time.sleep(self._interval)

    def reset(self) -> None:
        self._peak = 0
        self._sample()

    def peak_mb(self) -> float:
        self._sample()
        return self._peak / 2**20

    def overall_peak_mb(self) -> float:
        self._sample()
        return self._overall / 2**20

    def stop(self) -> None:
        self._stop.set()


DEFAULT_UNTIL = "gate"
"""The last stage a benchmark run reaches unless ``--until`` names another."""

EVERY_STAGE = "all"
"""``--until all``: every stage, not only what the last one needs."""


def run_case(
    case: Path,
    out: Path,
    backends: dict,
    settings: dict,
    until: str | None = None,
    reuse: bool = False,
    rerun: tuple[str, ...] = (),
) -> dict:
    """Run the stages into ``out`` and score them. With ``reuse``, a stage whose layer in ``out`` is
    current (same config, inputs and code) is kept, with the wall time its provenance recorded,
    unless it is in ``rerun``."""
    from rose_usd import registry
    from rose_usd.bench.evaluate import evaluate
    from rose_usd.pipeline import CLI_SOURCES, Options, Pipeline
    from rose_usd.usd.stage import layer_file, read_provenance, shown_backend

    monitor = RssMonitor()
    t_start = time.perf_counter()
    pipe = Pipeline(case, out, Options(backends=backends, settings=settings, force=True, isolate=True, **CLI_SOURCES))
    stages = {}
    # the benchmark of Tables 2 and 3 ends at the gate; robot demonstrations (collect) run only
    # when asked for with --until collect
    for stage_def in pipe.plan(None if until == EVERY_STAGE else until or DEFAULT_UNTIL):
        if reuse and stage_def.name not in rerun and pipe.is_current(stage_def):
            prov = read_provenance(layer_file(out, stage_def.layer))
            stages[stage_def.name] = {
                "backend": shown_backend(prov, prov["backend"]),
                "wall_time_s": prov["wall_time_s"],
                "peak_rss_mb": None,
                "reused": True,
            }
            continue
        monitor.reset()
        try:
            outcome = pipe.run_stage(stage_def)
        except Exception as exc:  # the stages that finished are still measured
            exc.finished_stages = stages
            raise
        stages[stage_def.name] = {
            "backend": outcome.backend,
            "wall_time_s": outcome.wall_time_s,
            "peak_rss_mb": round(monitor.peak_mb(), 1),
        }
    t0 = time.perf_counter()
    pipeline_wall = t0 - t_start
    peak_tree = monitor.overall_peak_mb()
    score = evaluate(case, out)
    monitor.stop()
    return {
        "stages": stages,
        # from the pipeline's construction to its last stage's end (the stages and what runs
        # between them), and the peak resident memory of this process and its children meanwhile
        "pipeline_wall_time_s": round(pipeline_wall, 2),
        "peak_rss_tree_mb": round(peak_tree, 1),
        "stage_results": {
            name: (read_provenance(layer_file(out, registry.get(name).layer)) or {}).get("results") for name in stages
        },
        "score": score.to_json(),
        "depth_scale_error": _depth_scale_error(case, out),
        "evaluate_time_s": round(time.perf_counter() - t0, 2),
        "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
    }


def _depth_scale_error(case: Path, out: Path) -> float | None:
    """Benchmark-only: alpha * (simulated MegaSaM scale) - 1, the error of the fitted metric depth
    scale, when the case's MegaSaM input was simulated and capture fitted an alpha."""
    from rose_usd.usd.stage import layer_file, read_provenance

    sim = case / "perception" / "simulated.json"
    results = (read_provenance(layer_file(out, "world")) or {}).get("results") or {}
    if not sim.is_file() or "alpha" not in results:
        return None
    return float(results["alpha"]) * float(json.loads(sim.read_text())["megasam"]["scale"]) - 1.0


def run_worker(
    case: Path,
    out: Path,
    result: Path,
    backends: dict,
    *,
    settings: dict | None = None,
    until: str | None = None,
    reuse: bool = False,
    rerun: list[str] | None = None,
) -> subprocess.CompletedProcess:
    """Run one case in a fresh Python process (its own peak memory and a crash of its own)."""
    command = [sys.executable, "-m", "rose_usd.bench.worker", "--case", str(case), "--out", str(out)]
    command += ["--result", str(result), "--backends", json.dumps(backends), "--settings", json.dumps(settings or {})]
    command += (["--until", until] if until else []) + (["--reuse"] if reuse else [])
    command += ["--rerun", ",".join(rerun)] if rerun else []
    return subprocess.run(command, env=dict(os.environ, ROSE_USD_QUIET=os.environ.get("ROSE_USD_QUIET", "1")))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--case", required=True, type=Path)
    parser.add_argument("--out", required=True, type=Path)
    parser.add_argument("--result", required=True, type=Path)
    parser.add_argument("--backends", default="{}", help="JSON {stage: backend}")
    parser.add_argument("--settings", default="{}", help="JSON {stage: {field: value}}")
    parser.add_argument("--until", default=None, help="run only this stage and what it needs")
    parser.add_argument("--reuse", action="store_true", help="keep the layers in --out that are current")
    parser.add_argument("--rerun", default="", help="comma-separated stages to run even when current")
    args = parser.parse_args(argv)
    from rose_usd.errors import RoseError

    try:
        result = run_case(
            args.case,
            args.out,
            json.loads(args.backends),
            json.loads(args.settings),
            args.until,
            args.reuse,
            tuple(filter(None, args.rerun.split(","))),
        )
        code = 0
    except RoseError as exc:
        result = {"error": exc.one_line(), "finished_stages": getattr(exc, "finished_stages", None)}
        code = 1
    except Exception as exc:  # a crash in one case must not lose the others: record it
        result = {"error": f"{type(exc).__name__}: {exc}", "traceback": traceback.format_exc()}
        result["finished_stages"] = getattr(exc, "finished_stages", None)
        code = 2
    args.result.parent.mkdir(parents=True, exist_ok=True)
    args.result.write_text(json.dumps(result, indent=1, default=float) + "\n")
    return code


if __name__ == "__main__":
    sys.exit(main())
