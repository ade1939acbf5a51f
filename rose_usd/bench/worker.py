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


def _rss_bytes() -> int:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * _PAGE


class RssMonitor:
    """Samples this process's resident memory every 10 ms; ``peak()`` since the last ``reset()``."""

    def __init__(self, interval_s: float = 0.01):
        self._peak = 0
        self._stop = threading.Event()
        self._interval = interval_s
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            self._peak = max(self._peak, _rss_bytes())
            time.sleep(self._interval)

    def reset(self) -> None:
        self._peak = _rss_bytes()

    def peak_mb(self) -> float:
        return max(self._peak, _rss_bytes()) / 2**20

    def stop(self) -> None:
        self._stop.set()


DEFAULT_UNTIL = "gate"
"""The last stage a benchmark run reaches unless ``--until`` names another."""


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
    from rose_usd.pipeline import Options, Pipeline
    from rose_usd.usd.stage import layer_file, read_provenance

    monitor = RssMonitor()
    pipe = Pipeline(case, out, Options(backends=backends, settings=settings, force=True))
    stages = {}
    # the benchmark of Tables 2 and 3 ends at the gate; robot demonstrations (collect) run only
    # when asked for with --until collect
    for stage_def in pipe.plan(until or DEFAULT_UNTIL):
        if reuse and stage_def.name not in rerun and pipe.is_current(stage_def):
            prov = read_provenance(layer_file(out, stage_def.layer))
            stages[stage_def.name] = {
                "backend": prov["backend"],
                "wall_time_s": prov["wall_time_s"],
                "peak_rss_mb": None,
                "reused": True,
            }
            continue
        monitor.reset()
        outcome = pipe.run_stage(stage_def)
        stages[stage_def.name] = {
            "backend": outcome.backend,
            "wall_time_s": outcome.wall_time_s,
            "peak_rss_mb": round(monitor.peak_mb(), 1),
        }
    t0 = time.perf_counter()
    score = evaluate(case, out)
    monitor.stop()
    return {
        "stages": stages,
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
        result = {"error": exc.one_line()}
        code = 1
    except Exception as exc:  # a crash in one case must not lose the others: record it
        result = {"error": f"{type(exc).__name__}: {exc}", "traceback": traceback.format_exc()}
        code = 2
    args.result.parent.mkdir(parents=True, exist_ok=True)
    args.result.write_text(json.dumps(result, indent=1, default=float) + "\n")
    return code


if __name__ == "__main__":
    sys.exit(main())
