"""The classical tracker on every run of a kept ``rose-usd bench run ... --until object`` results
folder: each run is copied, its trajectory stage run with ``--backend trajectory=tracker`` (the
earlier layers are up to date, so only the tracker runs), and scored against ground truth.

    python benchmarks/trajectory_tracker.py RESULTS_DIR -o OUT_DIR [--work /tmp/tracker-runs]

Writes OUT_DIR/report.md (per object: APE and RPE, frames lost, re-acquisitions, frames per
second of the tracker alone) and OUT_DIR/ape.png (APE per frame of every object). Each run's
case is read from its world layer's provenance; the backends are the runs' own."""

from __future__ import annotations

import argparse
import json
import shutil
import time
from pathlib import Path

import numpy as np

from rose_usd.bench.evaluate import evaluate
from rose_usd.pipeline import Options, Pipeline
from rose_usd.usd.stage import layer_file, read_provenance


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("results", type=Path)
    ap.add_argument("-o", "--out", type=Path, required=True)
    ap.add_argument("--work", type=Path, default=Path("/tmp/tracker-runs"))
    args = ap.parse_args()
    summary = json.loads((args.results / "results.json").read_text())
    backends = dict(summary["backends"]) | {"trajectory": "tracker"}
    rows, curves = [], {}
    for run in sorted(p for p in (args.results / "runs").iterdir() if p.is_dir()):
        case = Path(read_provenance(layer_file(run, "world"))["case"])
        out = args.work / run.name
        if out.exists():
            shutil.rmtree(out)
        shutil.copytree(run, out)
        t0 = time.perf_counter()
        Pipeline(case, out, Options(backends=backends, settings=summary.get("settings", {}))).run("trajectory")
        wall = time.perf_counter() - t0
        facts = read_provenance(layer_file(out, "trajectory"))["results"]["objects"]
        for o in evaluate(case, out).objects:
            f = facts[o.name]
            rows.append(
                f"| {run.name} | {o.name} | {1000 * o.ape_translation_m:.1f} | {o.ape_rotation_deg:.1f} | {1000 * o.rpe_translation_m:.2f} | {o.rpe_rotation_deg:.2f} "
                f"| {f['frames_lost']} | {f['reacquired']} | {f['moved_untouched']} | {f['fitness_mean']:.3f} | {f['frames_per_s']:.1f} | {wall:.1f} |"
            )
            curves[f"{run.name}/{o.name}"] = np.array(o.ape_translation_per_frame_m) * 1000
            print(rows[-1], flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    head = [
        f"Tracker over `{args.results}` (backends {json.dumps(backends)}).",
        "",
        "| case | object | APE t (mm) | APE r (deg) | RPE t (mm) | RPE r (deg) | lost | re-acquired | moved untouched | fitness | tracker frames/s | stage wall (s) |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    (args.out / "report.md").write_text("\n".join(head + rows) + "\n")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9, 4.5))
    for name, c in curves.items():
        ax.plot(c, label=name, lw=1)
    ax.axhline(10, color="k", ls="--", lw=0.8)
    ax.set_xlabel("frame")
    ax.set_ylabel("object APE translation (mm)")
    ax.legend(fontsize=6, ncol=3)
    fig.tight_layout()
    fig.savefig(args.out / "ape.png", dpi=110)


if __name__ == "__main__":
    main()
