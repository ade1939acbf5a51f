"""Many cases at once: ``rose-usd batch CASES... -o OUT`` and :func:`batch`.

Each case runs :func:`rose_usd.reconstruct` into ``OUT/<name>/`` in a process of its own (a
crash, a leak or a native library's global state stays with its case), a worker count at a time,
or as Ray tasks on a cluster (``ray=ADDRESS``, ``"auto"`` for a running one, ``"local"`` to start
one here) with their CPU and GPU needs declared. A case that fails is recorded with its one-line
error and does not stop the others. Every case is first checked as ``reconstruct`` checks it
(inputs, settings, output folder): one it would refuse is recorded as failed before any case
runs, and when it would refuse them all (a ``--set`` typo) the batch stops there, writing nothing.

**Resume.** A case is done when its ``batch.json`` is written, last and atomically, after its
reconstruction and validation; it records the hash of every layer file it saw, and what the case
was made from (``inputs_key``: rose_usd's code and the case's input files, by size and time). Run
again, a case whose record matches its layers on disk and its inputs is taken as it is, without
opening a stage; any other (an edited rose.toml, new frames, new code) is reconstructed again,
and that is make-like (``reconstruct`` skips the layers that are current, and a stage commits its
layer atomically), so a case killed halfway resumes at the stage it was in and a finished case is
left untouched (no file of it is rewritten).

The summary (``OUT/summary.csv``, ``summary.json``, ``index.html`` with each case's compare
picture) is rewritten atomically after every case, so a killed batch leaves the summary of the
cases finished so far.
"""

from __future__ import annotations

import contextlib
import csv
import hashlib
import html
import io
import json
import os
import sys
import time
import traceback
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from rose_usd.errors import ConfigError, RoseError
from rose_usd.progress import progress, quiet, say
from rose_usd.registry import STAGE_NAMES

RECORD = "batch.json"
"""The record of a finished case, in its output folder."""
REFUSED = "refused before any case ran"
"""How the error of a case the batch's first check refused begins."""
LOG = "batch.log"
"""A case's stages' progress and warnings, in its output folder (appended each run)."""
FIELDS = ("name", "case", "status", "gate_passed", "ssim_mean", "collect_success", "wall_time_s", "error")
"""The summary's columns, then each stage's seconds (``STAGE_FIELDS``)."""
STAGE_FIELDS = tuple(f"{s}_s" for s in STAGE_NAMES)
"""A stage's seconds in the summary (empty where it did not run)."""


@dataclass
class CaseResult:
    """One case of a batch."""

    name: str
    case: str
    out_dir: str
    status: str
    """``done`` (reconstructed and valid), ``failed`` (a stage failed, or the stage is invalid)."""
    gate_passed: bool | None = None
    ssim_mean: float | None = None
    collect_success: float | None = None
    """The collect stage's success rate over its rollouts, None when it did not run."""
    wall_time_s: float = 0.0
    """Seconds spent on this case in the run that finished it."""
    stage_times_s: dict[str, float] = field(default_factory=dict)
    """Seconds per stage as its layer records them: this run's, or the earlier run's that made a
    layer this one found up to date (after a resume, the whole case's times)."""
    error: str | None = None
    stages_ran: list[str] = field(default_factory=list)
    layers: dict[str, str] = field(default_factory=dict)
    """Layer file -> hash when the case finished: what ``batch.json`` vouches for."""
    reused: bool = False
    """Taken from an earlier run's record (nothing ran)."""

    def row(self) -> dict[str, Any]:
        times = {field: self.stage_times_s.get(s) for field, s in zip(STAGE_FIELDS, STAGE_NAMES, strict=True)}
        return {k: getattr(self, k) for k in FIELDS} | times


@dataclass
class BatchResult:
    out_dir: Path
    cases: list[CaseResult]
    wall_time_s: float

    @property
    def failed(self) -> list[CaseResult]:
        return [c for c in self.cases if c.status != "done"]


def case_names(cases: Sequence[str | os.PathLike]) -> list[str]:
    """An output folder name per case: its folder's (or video file's stem) name, made unique."""
    names: list[str] = []
    for case in cases:
        path = Path(case)
        base = (path.stem if path.suffix and not path.is_dir() else path.name) or "case"
        name, k = base, 2
        while name in names:
            name, k = f"{base}-{k}", k + 1
        names.append(name)
    return names


def _layer_hashes(out_dir: Path) -> dict[str, str]:
    from rose_usd.usd.stage import root_file

    files = sorted((out_dir / "layers").glob("*.usd*")) + [root_file(out_dir)]
    return {str(p.relative_to(out_dir)): hashlib.sha256(p.read_bytes()).hexdigest()[:16] for p in files if p.is_file()}


def inputs_key(case: str | os.PathLike) -> str:
    """What a finished case's record was made from, told by stat alone: rose_usd's source files and
    the case's input files (``Case.input_files``: frames or video, depth, cam_K.txt, rose.toml,
    perception/, imu/), each by path, size and modification time; "" when the case cannot be read
    (its run says why). A change makes the case run again through ``reconstruct``, which redoes
    only the stages whose config, inputs or code changed (a file touched, not changed: none)."""
    from rose_usd.case.layout import load_case

    try:
        files = load_case(case, STAGE_NAMES).input_files()
    except (RoseError, OSError):
        return ""
    h = hashlib.sha256()
    for path in [*sorted(Path(__file__).resolve().parent.rglob("*.py")), *files]:
        st = path.stat()
        h.update(f"{path}\0{st.st_size}\0{st.st_mtime_ns}\n".encode())
    return h.hexdigest()[:16]


def _recorded(out_dir: Path) -> tuple[CaseResult, dict[str, str]] | None:
    """The finished case recorded in ``out_dir`` whose layers are still the ones the record vouches
    for, with the options and inputs keys it was made under; None otherwise."""
    try:
        data = json.loads((out_dir / RECORD).read_text())
        keys = {"options": data.pop("options"), "inputs": data.pop("inputs")}
        result = CaseResult(**data)
    except (OSError, ValueError, TypeError, KeyError):
        return None
    if result.status != "done" or result.layers != _layer_hashes(out_dir):
        return None
    result.reused = True
    return result, keys


def _other_cases(out: Path, names: list[str]) -> list[CaseResult]:
    """The cases an earlier batch finished in ``out`` that this one does not name, as recorded
    (``_recorded``): the summary keeps them (a batch of some of the cases rewrote it with those
    alone)."""
    folders = sorted(p for p in out.iterdir() if p.is_dir() and p.name not in names) if out.is_dir() else []
    return [got[0] for folder in folders if (got := _recorded(folder)) is not None]


def _record(out_dir: Path, options_key: str, case_key: str) -> CaseResult | None:
    """The finished case recorded in ``out_dir`` (``_recorded``), when it was made with the same
    options from the same inputs and code (``case_key``: ``inputs_key``), after what an interrupted
    later run left is cleared away or its commit finished (``usd.stage.recover``)."""
    from rose_usd.usd.stage import recover

    recover(out_dir)
    got = _recorded(out_dir)
    if got is None or not case_key or got[1] != {"options": options_key, "inputs": case_key}:
        return None
    return got[0]


def run_case(
    name: str,
    case: str,
    out_dir: str,
    options: Mapping[str, Any],
    options_key: str,
    case_key: str,
) -> dict[str, Any]:
    """Reconstruct one case (in a worker process or a Ray task) and record it, its stages' progress
    and warnings going to ``out_dir/batch.log``; never raises. ``case_key``: its ``inputs_key``."""
    out = Path(out_dir)
    earlier = _record(out, options_key, case_key)
    if earlier is not None:
        return asdict(earlier)
    t0 = time.perf_counter()
    result = CaseResult(name=name, case=str(case), out_dir=str(out), status="failed")
    try:
        from rose_usd.api import reconstruct

        with _stderr_to(out / LOG):
            rec = reconstruct(case, out, validate=True, check=False, **options)
        result.stages_ran = [o.name for o in rec.outcomes if o.status == "ran"]
        result.stage_times_s = _stage_times(rec.outcomes)
        result.error = rec.error
        if rec.validation is not None and not rec.validation.ok:
            result.error = result.error or f"{rec.path}: the stage is not valid ({rec.validation.errors[0]})"
        if rec.gate is not None:
            result.gate_passed, result.ssim_mean = bool(rec.gate.passed), round(float(rec.gate.ssim_mean), 4)
        if rec.collect is not None and rec.collect.rollouts:
            result.collect_success = round(float(rec.collect.success_rate), 4)
        result.status = "done" if result.error is None else "failed"
    except RoseError as exc:
        result.error = exc.one_line()
    except Exception as exc:  # a bug in one case must not stop the batch: recorded with its place
        last = traceback.extract_tb(exc.__traceback__)[-1]
        result.error = f"bug: {type(exc).__name__}: {exc} ({Path(last.filename).name}:{last.lineno})"
    result.wall_time_s = round(time.perf_counter() - t0, 2)
    if result.status == "done":
        from rose_usd.usd.stage import write_text_atomic

        result.layers = _layer_hashes(out)
        record = asdict(result) | {"options": options_key, "inputs": case_key}
        write_text_atomic(out / RECORD, json.dumps(record, indent=1))
    return asdict(result)


def batch(
    cases: Iterable[str | os.PathLike],
    out: str | os.PathLike,
    *,
    workers: int = 1,
    ray: str | None = None,
    cpus_per_case: float = 1.0,
    gpus_per_case: float = 0.0,
    backends: Mapping[str, Any] | None = None,
    settings: Mapping[str, Mapping[str, Any]] | None = None,
    until: str | None = None,
    force: bool = False,
    sources: Mapping[str, str] | None = None,
) -> BatchResult:
    """Reconstruct every case into ``out/<name>/`` (module docstring); returns each case's result.

    Args:
        workers: cases run at once, each in its own process (local runs).
        ray: run each case as a Ray task instead: an address, ``"auto"`` (a running cluster) or
            ``"local"`` (start one here); ``cpus_per_case``/``gpus_per_case`` are its resources.
        backends, settings, until, force: as for :func:`rose_usd.reconstruct`, for every case.
        sources: what errors in ``settings`` and ``backends`` name as their source
            (:class:`rose_usd.pipeline.Options`' ``settings_source``, ``prompt_source``,
            ``backends_source``; the CLI's flags).

    Raises:
        RoseError: no case, a case that does not exist, ``out`` that cannot be a folder, or every
            case refused by ``reconstruct``'s checks (inputs, settings, output folder; a ``--set``
            typo). A case refused while others pass is recorded as failed, before any runs.
    """
    cases = [str(c) for c in cases]
    if not cases:
        raise ConfigError("no case given", hint="rose-usd batch CASE [CASE ...] -o OUT")
    missing = [c for c in cases if not Path(c).exists()]
    if missing:
        raise ConfigError(f"case {missing[0]!r} does not exist", path=missing[0], hint="check the path")
    if workers < 1:
        raise ConfigError(f"--workers {workers}", hint="run at least 1 case at a time")
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ConfigError("the batch output is a file", path=out, hint="give a folder for -o")
    options, options_key = _options(backends, settings, until, force, sources)
    names = case_names(cases)
    jobs = [(name, case, str(out / name), options, options_key, inputs_key(case)) for name, case in zip(names, cases)]
    earlier = {job[0]: _record(Path(job[2]), options_key, job[5]) for job in jobs}
    refused = _preflight([job for job in jobs if earlier[job[0]] is None])
    if len(refused) == len(jobs):  # the command's own mistake (a --set typo)
        raise next(iter(refused.values()))
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    results: dict[str, CaseResult] = {}
    others = _other_cases(out, names)

    def finished(data: dict) -> None:
        result = results[data["name"]] = CaseResult(**data)
        write_summary(out, [results[n] for n in names if n in results] + others)
        say(_line(result))

    for name, case in zip(names, cases):
        if name in refused:
            line = f"{REFUSED}: {refused[name].one_line()}"
            made = str(out / name) if (out / name).is_dir() else ""  # an earlier batch's, or none
            finished(asdict(CaseResult(name=name, case=case, out_dir=made, status="failed", error=line)))
        elif earlier[name] is not None:
            finished(asdict(earlier[name]))
    jobs = [job for job in jobs if job[0] not in results]
    if jobs and len(jobs) < len(names):
        reused = len(results) - len(refused)
        say(f"batch: {len(jobs)} of {len(names)} cases to run ({len(refused)} refused, {reused} recorded earlier)")

    if jobs and ray:
        _run_ray(jobs, ray, cpus_per_case, gpus_per_case, finished)
    elif jobs:
        _run_local(jobs, workers, finished)
    return BatchResult(out, [results[n] for n in names], time.perf_counter() - t0)


@contextlib.contextmanager
def _stderr_to(path: Path):
    """Send this process's stderr (and its children's: each stage runs in one) to the end of
    ``path``, progress and warnings on, until the block ends."""
    path.parent.mkdir(parents=True, exist_ok=True)
    sys.stderr.flush()
    saved, quiet_was = os.dup(2), os.environ.get("ROSE_USD_QUIET")
    os.environ["ROSE_USD_QUIET"] = "0"
    try:
        with open(path, "a") as log:
            log.write(f"--- {time.strftime('%Y-%m-%d %H:%M:%S')} pid {os.getpid()}\n")
            log.flush()
            os.dup2(log.fileno(), 2)
            try:
                yield
            finally:
                sys.stderr.flush()
                os.dup2(saved, 2)
    finally:
        os.close(saved)
        if quiet_was is None:
            os.environ.pop("ROSE_USD_QUIET", None)
        else:
            os.environ["ROSE_USD_QUIET"] = quiet_was


def _line(r: CaseResult) -> str:
    """One line on a finished case."""
    if r.status != "done":
        if (r.error or "").startswith(REFUSED):
            return f"batch: {r.name} {r.error}"
        return f"batch: {r.name} failed after {r.wall_time_s:.0f} s: {r.error}"
    gate = "" if r.gate_passed is None else f", gate {'PASS' if r.gate_passed else 'FAIL'} SSIM {r.ssim_mean:.3f}"
    collect = "" if r.collect_success is None else f", collect {100 * r.collect_success:.0f} %"
    how = "recorded earlier" if r.reused else f"in {r.wall_time_s:.0f} s"
    return f"batch: {r.name} done {how}{gate}{collect}"


def _stage_times(outcomes) -> dict[str, float]:
    """Seconds per stage of a finished run: those that ran, and for those found up to date what
    their layer records (``StageOutcome.made_in_s``)."""
    return {o.name: round(o.made_in_s, 2) for o in outcomes if o.made_in_s is not None}


def _options(backends, settings, until, force: bool, sources) -> tuple[dict, str]:
    """Every case's ``reconstruct`` arguments, and the key a finished case's record is reused
    under: the same options (a forced run's is never reused by itself), whatever ``sources``
    (what errors name as the settings' source, not what a case is made with)."""
    options = {
        "backends": dict(backends or {}),
        "settings": {k: dict(v) for k, v in (settings or {}).items()},
        "until": until,
        "force": force,
    }
    key = hashlib.sha256(json.dumps(options, sort_keys=True, default=str).encode()).hexdigest()[:16]
    if force:
        key += f"-{time.time_ns()}"
    return {**options, "options": dict(sources or {})}, key


def _preflight(jobs: list[tuple]) -> dict[str, RoseError]:
    """Every case's inputs, settings and output folder checked as ``reconstruct`` checks them,
    before any case runs: name -> the error of each case it would refuse (a typo in the tenth
    case's rose.toml is known at once, not after nine reconstructions)."""
    from rose_usd.pipeline import Options, Pipeline

    refused = {}
    for name, case, out_dir, options, *_keys in jobs:
        try:
            given = {"backends": options["backends"], "settings": options["settings"], "force": options["force"]}
            pipe = Pipeline(case, out_dir, Options(**given, **options["options"]))
            pipe.plan(options["until"])
            pipe.check_output()
        except RoseError as exc:
            refused[name] = exc
    return refused


def _run_local(jobs: list[tuple], workers: int, finished) -> None:
    """The jobs in ``workers`` processes, each tied to this one (``die_with_parent``: a batch killed
    with SIGKILL leaves no worker writing on). Ctrl-C stops the batch: the cases not started are
    dropped, the running ones are interrupted (their stage rolls its layer back) and waited for,
    then KeyboardInterrupt goes on; the summary holds the cases finished before."""
    import multiprocessing
    import signal
    from concurrent.futures import ProcessPoolExecutor, as_completed, wait

    from rose_usd.core.lifetime import die_with_parent

    context = multiprocessing.get_context("spawn")  # no fork of a process that holds USD, Warp or Open3D
    pool = ProcessPoolExecutor(
        max_workers=workers,
        mp_context=context,
        max_tasks_per_child=1,
        initializer=die_with_parent,
        initargs=(os.getpid(),),
    )
    reported = set()
    try:
        futures = {pool.submit(run_case, *job): job for job in jobs}
        for future in progress(as_completed(futures), "batch", total=len(futures), unit="case"):
            finished(future.result())
            reported.add(future)
    except KeyboardInterrupt:
        # the cases not started are dropped; a terminal's Ctrl-C reached the running ones too
        # (their stage rolls back and they end), a script's may not have: they are asked again
        running = [f for f in futures if not f.cancel() and not f.done()]
        if wait(running, timeout=3.0).not_done:
            for proc in list(getattr(pool, "_processes", {}).values()):
                with contextlib.suppress(OSError):
                    os.kill(proc.pid, signal.SIGINT)
        pool.shutdown(wait=True, cancel_futures=True)
        # a case that finished before the Ctrl-C reached this loop is in the summary too, also one
        # whose worker was interrupted after writing its record, before handing its result back
        for future, (_name, _case, out_dir, _options, key, inputs) in futures.items():
            if future in reported:
                continue
            if future.done() and not future.cancelled() and future.exception() is None:
                finished(future.result())
            elif (done := _record(Path(out_dir), key, inputs)) is not None:
                finished(asdict(done) | {"reused": False})  # run by this batch
        raise
    pool.shutdown(wait=True)


def _run_ray(jobs: list[tuple], address: str, cpus: float, gpus: float, finished) -> None:
    try:
        import ray
    except ImportError:
        raise ConfigError(
            "--ray needs the ray package", hint="pip install 'rose-usd[ray]' (or run without --ray)"
        ) from None
    started = not ray.is_initialized()
    if started:
        ray.init(address=None if address == "local" else address, include_dashboard=False, log_to_driver=not quiet())
    try:
        _check_fits(ray.nodes(), cpus, gpus, address)
        task = ray.remote(num_cpus=cpus, num_gpus=gpus, max_retries=0)(run_case)
        pending = [task.remote(*job) for job in jobs]
        bar = progress(range(len(pending)), "batch (ray)", total=len(pending), unit="case")
        for _ in bar:
            done, pending = ray.wait(pending, num_returns=1)
            finished(ray.get(done[0]))
    finally:
        if started:
            ray.shutdown()


def _check_fits(nodes: list[dict], cpus: float, gpus: float, address: str) -> None:
    """A case's CPUs and GPUs must fit one live node of the cluster (``ray.nodes()``): Ray waits
    without end, and without a word to the caller, on a task that no node can run. A cluster
    started here is refused; another, which an autoscaler may grow, is warned about."""
    alive = [node.get("Resources", {}) for node in nodes if node.get("Alive")]
    if any(r.get("CPU", 0.0) >= cpus and r.get("GPU", 0.0) >= gpus for r in alive):
        return
    largest = max(alive, key=lambda r: (r.get("CPU", 0.0), r.get("GPU", 0.0)), default={})
    message = (
        f"no node of the Ray cluster has {cpus:g} CPUs and {gpus:g} GPUs for a case (the largest:"
        f" {largest.get('CPU', 0.0):g} CPUs, {largest.get('GPU', 0.0):g} GPUs)"
    )
    if address == "local":
        raise ConfigError(message, hint="lower --cpus-per-case / --gpus-per-case to what this machine has")
    print(f"warning: {message}; the cases wait until such a node joins", file=sys.stderr, flush=True)


def write_summary(out: Path, results: list[CaseResult]) -> None:
    """``summary.csv``, ``summary.json`` and ``index.html`` in ``out``, each written atomically."""
    from rose_usd.usd.stage import write_text_atomic

    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=[*FIELDS, *STAGE_FIELDS])
    writer.writeheader()
    for r in results:
        writer.writerow(r.row())
    write_text_atomic(out / "summary.csv", buf.getvalue())
    write_text_atomic(out / "summary.json", json.dumps([asdict(r) for r in results], indent=1))
    write_text_atomic(out / "index.html", _html(out, results))


def _html(out: Path, results: list[CaseResult]) -> str:
    done = sum(r.status == "done" for r in results)
    passed = sum(bool(r.gate_passed) for r in results)
    rows = []
    for r in results:
        picture = Path(r.out_dir) / "report" / "compare.png"
        img = (
            f'<a href="{html.escape(os.path.relpath(picture, out))}"><img src="'
            f'{html.escape(os.path.relpath(picture, out))}" width="480"></a>'
            if r.out_dir and picture.is_file()
            else ""
        )
        gate = "" if r.gate_passed is None else ("PASS" if r.gate_passed else "FAIL")
        cells = [
            html.escape(r.name),
            html.escape(r.status),
            gate,
            "" if r.ssim_mean is None else f"{r.ssim_mean:.4f}",
            "" if r.collect_success is None else f"{100 * r.collect_success:.0f} %",
            f"{r.wall_time_s:.1f} s",
            html.escape(", ".join(f"{k} {v:.1f} s" for k, v in r.stage_times_s.items())),
            html.escape(r.error or ""),
            img,
        ]
        rows.append("<tr>" + "".join(f"<td>{c}</td>" for c in cells) + "</tr>")
    head = "".join(
        f"<th>{h}</th>" for h in ("case", "status", "gate", "SSIM", "collect", "time", "stages", "error", "compare")
    )
    return (
        "<!doctype html><meta charset='utf-8'><title>rose-usd batch</title>"
        "<style>body{font-family:sans-serif}td,th{border:1px solid #ccc;padding:4px;vertical-align:top}"
        "table{border-collapse:collapse}</style>"
        f"<h1>rose-usd batch</h1><p>{len(results)} case(s): {done} done, {passed} passed the gate.</p>"
        f"<table><tr>{head}</tr>{''.join(rows)}</table>"
    )
