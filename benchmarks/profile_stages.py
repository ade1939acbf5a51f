"""Profile every stage of one run with cProfile, one profile per stage, and print each stage's hot
spots (the functions with the most time of their own, and the most time under them).

    python benchmarks/profile_stages.py CASE OUT [--until collect] [--top 12] [--set gate.frame_stride=1]
    python benchmarks/profile_stages.py CASE OUT --only collect,gate,scene   # OUT holds a finished run

With ``--only``, just those stages are run (and profiled), in the order given, on the layers
already in OUT (a copy of a finished run): give them last stage first, since a stage re-run
removes the layers after it.

Writes OUT/profile/STAGE.prof (open with ``python -m pstats`` or snakeviz) and prints the summary.
cProfile slows Python-heavy code more than code in C extensions, so compare stages by the wall
times printed here (measured inside the profile), and time them unprofiled with
``rose-usd bench speed all``."""

from __future__ import annotations

import argparse
import cProfile
import io
import pstats
import sys
import time
from pathlib import Path


def summary(prof: cProfile.Profile, top: int) -> str:
    out = io.StringIO()
    stats = pstats.Stats(prof, stream=out)
    stats.strip_dirs()
    out.write("-- most time of their own (tottime) --\n")
    stats.sort_stats("tottime").print_stats(top)
    out.write("-- most time under them (cumtime) --\n")
    stats.sort_stats("cumulative").print_stats(top + 8)
    text = out.getvalue()
    # keep the tables, drop pstats' preamble lines about files and ordering
    keep = [ln for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith(("Ordered by", "List reduced"))]
    return "\n".join(keep)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("case", type=Path)
    parser.add_argument("out", type=Path)
    parser.add_argument("--until", default=None, help="last stage (default: every stage)")
    parser.add_argument("--top", type=int, default=12)
    parser.add_argument("--set", action="append", default=[], metavar="STAGE.FIELD=VALUE")
    parser.add_argument("--only", default=None, help="comma-separated stages to run on OUT's layers, in this order")
    args = parser.parse_args(argv)

    from rose_usd import registry
    from rose_usd.cli import _parse_assignments
    from rose_usd.pipeline import Options, Pipeline

    settings = _parse_assignments(args.set, "--set")
    pipe = Pipeline(args.case, args.out, Options(settings=settings, force=True))
    prof_dir = args.out / "profile"
    prof_dir.mkdir(parents=True, exist_ok=True)
    stages = [registry.get(name) for name in args.only.split(",")] if args.only else pipe.plan(args.until)
    for stage_def in stages:
        prof = cProfile.Profile()
        t0 = time.perf_counter()
        prof.enable()
        outcome = pipe.run_stage(stage_def)
        prof.disable()
        wall = time.perf_counter() - t0
        prof.dump_stats(prof_dir / f"{stage_def.name}.prof")
        print(f"\n===== {stage_def.name} ({outcome.backend}): {wall:.1f} s under cProfile =====")
        print(summary(prof, args.top), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
