"""``rose-usd bench run``: generate (or reuse) a suite's cases, derive the perception mode, run
every case in its own process, and write results.json and results.csv."""

from __future__ import annotations

import csv
import datetime as dt
import json
import os
import platform
import shutil
import subprocess
import time
from importlib import metadata
from pathlib import Path

from rose_usd.bench.modes import ModeOptions, PerceptionMode, make_mode_case, mode_stamp
from rose_usd.bench.suites import CaseSpec, get_suite, select_cases
from rose_usd.bench.worker import run_worker
from rose_usd.case.gt import GroundTruth
from rose_usd.errors import InputError
from rose_usd.progress import say
from rose_usd.synth.generate import generate_case

BENCH_DIR = Path("benchmarks")
"""Where benchmark results and generated cases go by default, relative to the working directory."""
DEFAULT_CASES = BENCH_DIR / "cases"


def ensure_case(spec: CaseSpec, suite_dir: Path) -> tuple[Path, float]:
    """The generated (rgbd) case of ``spec``, regenerated when missing or made by other settings.
    Returns its folder and the seconds spent generating (0 when reused)."""
    base = suite_dir / spec.name / "base"
    manifest = base / "gt" / "scene.json"
    if manifest.is_file():
        try:
            gt = GroundTruth(base / "gt")
            if spec.matches(gt.data.get("generator", {}), gt.n_frames, gt.width, gt.height):
                return base, 0.0
        except InputError:
            pass
    say(f"bench: generating {spec.name} ({spec.n_frames} frames {spec.width}x{spec.height})")
    t0 = time.perf_counter()
    generate_case(spec.generate_config(), base, overwrite=True)
    return base, time.perf_counter() - t0


def ensure_mode(base: Path, spec: CaseSpec, mode: PerceptionMode, options: ModeOptions = ModeOptions()) -> Path:
    """The ``mode`` case of generated case ``base`` with ``options``, made again when missing or stale."""
    out = base.parent / options.folder(mode)
    stamp = out / ".mode"
    base_stamp = (base / "gt" / "scene.json").stat().st_mtime_ns
    if (
        stamp.is_file()
        and stamp.read_text() == mode_stamp(mode, options)
        and (out / "gt" / "scene.json").stat().st_mtime_ns == base_stamp
    ):
        return out
    return make_mode_case(base, mode, out, spec.seed, options)


def _flatten(result: dict) -> list[dict]:
    """One CSV row per (case, object)."""
    rows = []
    score = result.get("score") or {}
    base = {k: result[k] for k in ("case", "task", "shape", "seed", "mode", "n_frames", "error") if k in result}
    for key in (
        "camera_ape_translation_m",
        "camera_ape_rotation_deg",
        "camera_rpe_translation_m",
        "camera_rpe_rotation_deg",
        "gravity_error_deg",
        "scale_error",
        "height_scale_error",
        "scene_chamfer_m",
        "scene_chamfer_visible_m",
        "scene_ghost_cm2",
        "ssim_mean",
        "gate_passed",
    ):
        base[key] = score.get(key)
    for name, st in (result.get("stages") or {}).items():
        base[f"time_{name}_s"] = st["wall_time_s"]
        base[f"rss_{name}_mb"] = st["peak_rss_mb"]
    base["peak_rss_mb"] = result.get("peak_rss_mb")
    for obj in score.get("objects") or [{}]:
        row = dict(base)
        for key, value in obj.items():
            if key != "ape_translation_per_frame_m":
                row[f"object_{key}"] = value
        rows.append(row)
    return rows


def run_suite(
    suite: str,
    mode: PerceptionMode,
    out_dir: Path,
    *,
    cases_dir: Path = DEFAULT_CASES,
    backends: dict | None = None,
    settings: dict | None = None,
    command: str = "",
    until: str | None = None,
    options: ModeOptions = ModeOptions(),
    start_from: Path | None = None,
    rerun: tuple[str, ...] = (),
    only: tuple[str, ...] = (),
) -> dict:
    """Run every case of ``suite`` in ``mode`` into ``out_dir``/runs and write the results. With
    ``start_from`` (an earlier results folder of the same suite, mode and options), each case starts
    from a copy of that folder's kept run: its layers that are still current are not run again
    (their recorded wall times and peak memory are carried over), so later stages can be added to
    a kept benchmark. Stages in ``rerun`` run even when current. ``only``: the cases to run, by
    case or task name (default every case)."""
    specs = select_cases(get_suite(suite), only)
    source = _start_from(start_from, suite, mode, options) if start_from else None
    commit = _git_commit()  # at the start: the code that runs
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    suite_dir = Path(cases_dir) / suite
    backends = dict(backends or {"all": "oracle"})
    results = []
    t_start = time.perf_counter()
    for i, spec in enumerate(specs, start=1):
        base, gen_time = ensure_case(spec, suite_dir)
        case = ensure_mode(base, spec, mode, options)
        run_out = out_dir / "runs" / spec.name
        result_file = out_dir / "runs" / f"{spec.name}.json"
        say(f"bench [{i}/{len(specs)}] {spec.name} ({mode.value})")
        earlier = source["cases"].get(spec.name) if source else None
        if earlier is not None:
            if run_out.exists():
                shutil.rmtree(run_out)
            shutil.copytree(Path(start_from) / "runs" / spec.name, run_out)
        t0 = time.perf_counter()
        proc = run_worker(
            case,
            run_out,
            result_file,
            backends,
            settings=settings,
            until=until,
            reuse=earlier is not None,
            rerun=list(rerun) if rerun else None,
        )
        result = (
            json.loads(result_file.read_text())
            if result_file.is_file()
            else {"error": f"worker exited with {proc.returncode} and wrote no result"}
        )
        for name, st in (result.get("stages") or {}).items():
            if st.get("reused"):
                st["peak_rss_mb"] = ((earlier or {}).get("stages") or {}).get(name, {}).get("peak_rss_mb")
        result.update(
            case=spec.name,
            task=spec.task.value,
            shape=spec.shape.value,
            seed=spec.seed,
            mode=mode.value,
            n_frames=spec.n_frames,
            size=[spec.width, spec.height],
            generate_time_s=round(gen_time, 1),
            case_wall_time_s=round(time.perf_counter() - t0, 1),
        )
        if "error" in result:
            say(f"bench: {spec.name} failed: {result['error']}")
        results.append(result)
    summary = {
        "suite": suite,
        "mode": mode.value,
        "backends": backends,
        "settings": settings or {},
        "until": until,
        "prompts": options.prompts,
        "size_prior": options.size_prior,
        "intrinsics": options.intrinsics,
        "only": list(only),
        "started_from": {"folder": str(start_from), "commit": source["commit"], "rerun": list(rerun)}
        if source
        else None,
        "command": command,
        "date": dt.datetime.now(dt.UTC).isoformat(timespec="seconds"),
        "machine": {"cpus": os.cpu_count(), "platform": platform.platform(), "python": platform.python_version()},
        "versions": {p: _version(p) for p in ("rose-usd", "usd-core", "mitsuba", "newton", "warp-lang", "open3d")},
        "commit": commit,
        "suite_wall_time_s": round(time.perf_counter() - t_start, 1),
        "cases": results,
    }
    _write(summary, out_dir)
    return summary


def _start_from(folder: Path, suite: str, mode: PerceptionMode, options: ModeOptions) -> dict:
    """The earlier results folder's summary, checked to hold runs of the same cases; its cases by name."""
    folder = Path(folder)
    summary_file = folder / "results.json"
    if not summary_file.is_file() or not (folder / "runs").is_dir():
        raise InputError(
            "no kept benchmark here (results.json and runs/ are needed)",
            path=folder,
            hint="pass a folder that `rose-usd bench run` wrote on this machine",
        )
    summary = json.loads(summary_file.read_text())
    theirs = (summary["suite"], summary["mode"], ModeOptions.of(summary))
    if theirs != (suite, mode.value, options):
        raise InputError(
            f"its runs are of suite {theirs[0]!r}, mode {theirs[1]!r}, {theirs[2]}, "
            f"not {suite!r}, {mode.value!r}, {options}",
            path=summary_file,
            hint="start from a folder of the same suite, mode and options",
        )
    cases = {c["case"]: c for c in summary["cases"] if "error" not in c and (folder / "runs" / c["case"]).is_dir()}
    return {"commit": summary.get("commit"), "cases": cases}


def kept_runs_parser(doc: str, cases: Path = DEFAULT_CASES):
    """The command line that the scripts under benchmarks/ drawing from a results folder's kept
    runs share: RESULTS, -o/--output PNG and --cases (default ``cases``; see ``kept_runs``); each
    adds its own."""
    import argparse

    parser = argparse.ArgumentParser(description=doc.split("\n\n")[0])
    parser.add_argument("results", type=Path)
    parser.add_argument("-o", "--output", type=Path, required=True)
    parser.add_argument("--cases", type=Path, default=cases)
    return parser


def kept_runs(results: Path, cases_dir: Path = DEFAULT_CASES, only: str | None = None):
    """For the scripts that look into a results folder's kept runs: (the case's summary entry, its
    generated case folder in the results' mode, its run folder) for each case that ran without
    error and kept its run, in the summary's order (only names containing ``only``, if given)."""
    summary = json.loads((Path(results) / "results.json").read_text())
    for entry in summary["cases"]:
        run = Path(results) / "runs" / entry["case"]
        if "error" not in entry and run.is_dir() and (not only or only in entry["case"]):
            folder = ModeOptions.of(summary).folder(PerceptionMode(summary["mode"]))
            yield entry, Path(cases_dir) / summary["suite"] / entry["case"] / folder, run


def rescore(out_dir: Path, *, cases_dir: Path = DEFAULT_CASES) -> dict:
    """Score a results folder's runs again with the current metrics (no stage re-runs): for a
    metric added after the runs were made. The summary records the commit that rescored."""
    out_dir = Path(out_dir)
    summary = json.loads((out_dir / "results.json").read_text())
    mode = PerceptionMode(summary["mode"])
    specs = {s.name: s for s in get_suite(summary["suite"])}
    from rose_usd.bench.evaluate import evaluate

    for result in summary["cases"]:
        if "error" in result:
            continue
        spec = specs[result["case"]]
        base, _ = ensure_case(spec, Path(cases_dir) / summary["suite"])
        say(f"bench rescore {spec.name}")
        result["score"] = evaluate(
            ensure_mode(base, spec, mode, ModeOptions.of(summary)),
            out_dir / "runs" / spec.name,
        ).to_json()
    summary["rescored_by"] = _git_commit()
    _write(summary, out_dir)
    return summary


def _write(summary: dict, out_dir: Path) -> None:
    """results.json and results.csv (one row per object) of a suite run."""
    results = summary["cases"]
    (out_dir / "results.json").write_text(json.dumps(summary, indent=1, default=float) + "\n")
    rows = [row for r in results for row in _flatten(r)]
    keys = list(dict.fromkeys(k for row in rows for k in row))
    with open(out_dir / "results.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=keys)
        writer.writeheader()
        writer.writerows(rows)


def _version(pkg: str) -> str:
    try:
        return metadata.version(pkg)
    except metadata.PackageNotFoundError:
        return "absent"


_SOURCE = Path(__file__).resolve().parent


def _git_commit() -> str | None:
    """The commit of the checkout this code runs from (None when installed from a wheel), with
    ``-dirty`` when tracked files have uncommitted changes."""
    try:
        commit = subprocess.run(
            ["git", "-C", str(_SOURCE), "rev-parse", "--short", "HEAD"], capture_output=True, text=True, check=True
        ).stdout.strip()
        dirty = subprocess.run(
            ["git", "-C", str(_SOURCE), "status", "--porcelain", "--untracked-files=no"],
            capture_output=True,
            text=True,
            check=True,
        ).stdout.strip()
        return commit + ("-dirty" if dirty else "")
    except (OSError, subprocess.CalledProcessError):
        return None
