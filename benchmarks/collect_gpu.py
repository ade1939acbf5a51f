"""The collect stage alone on a finished reconstruction, timed: rollouts per minute and successes,
on the GPU (every rollout its own world, stepped together) or the CPU (one after another).

    python benchmarks/collect_gpu.py OUT --case CASE --grasps 8 --perturbations 512 --device cuda -o RESULT.json

OUT holds a reconstruction of CASE up to the trajectory layer (``rose-usd reconstruct``, or the
demo's ``out/demo``). The stage runs on it as ``rose-usd run collect`` would, without checking
whether the layers before it are current (a GPU machine may lack their stages' packages).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from rose_usd import registry
from rose_usd.pipeline import Options, Pipeline
from rose_usd.usd.stage import layer_file, read_provenance


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("out", type=Path)
    parser.add_argument("--case", type=Path, required=True)
    parser.add_argument("--grasps", type=int, default=8)
    parser.add_argument("--perturbations", type=int, default=512)
    parser.add_argument("--device", choices=("cuda", "cpu"), default="cuda")
    parser.add_argument("--max-worlds", type=int, default=4096)
    parser.add_argument("-o", "--output", type=Path)
    args = parser.parse_args()
    settings = {
        "collect": {
            "grasps": args.grasps,
            "perturbations": args.perturbations,
            "newton.device": args.device,
            "newton.max_worlds": args.max_worlds,
        }
    }
    pipe = Pipeline(args.case, args.out, Options(settings=settings))
    t0 = time.perf_counter()
    pipe.run_stage(registry.get("collect"))
    wall = time.perf_counter() - t0
    results = (read_provenance(layer_file(args.out, "robot")) or {}).get("results") or {}
    rollouts = int(results.get("rollouts", 0))
    successes = int(results.get("successes", 0))
    summary = {
        "device": args.device,
        "grasps": args.grasps,
        "perturbations": args.perturbations,
        "rollouts": rollouts,
        "successes": successes,
        "stage_wall_s": round(wall, 1),
        "build_s": results.get("build_s"),
        "plan_s": results.get("plan_s"),
        "rollout_s_total": round(float(sum(results.get("rollout_wall_s", []))), 1),
        "rollouts_per_minute": results.get("rollouts_per_minute"),
        "successful_rollouts_per_minute_of_stage": round(60.0 * successes / max(wall, 1e-9), 1),
        "worlds": results.get("worlds"),
        "status": results.get("status"),
    }
    text = json.dumps(summary, indent=1)
    print(text)
    if args.output:
        args.output.parent.mkdir(parents=True, exist_ok=True)
        args.output.write_text(text + "\n")


if __name__ == "__main__":
    main()
