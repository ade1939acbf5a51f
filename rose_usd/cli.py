"""The ``rose-usd`` command line.

Errors a user can fix print one line (``error: <file>: <what>. <fix>.``) and exit 1; anything else
is a bug: traceback, exit 2.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
import textwrap
import traceback
from pathlib import Path

from rose_usd.errors import ConfigError, InputError, RoseError
from rose_usd.pipeline import CLI_SOURCES


def _sample_case() -> Path:
    """The bundled sample (package data)."""
    return (Path(__file__).resolve().parent / "samples" / "push-box").resolve()  # the path the layers record


def _bench_dir(*parts: str) -> Path:
    from rose_usd.bench.runner import BENCH_DIR

    return BENCH_DIR.joinpath("results", *parts)


def _parse_assignments(values: list[str] | None, what: str) -> dict:
    out: dict = {}
    for item in values or []:
        if "=" not in item:
            raise ConfigError(
                f"{item!r} is not KEY=VALUE",
                path=what,
                hint=f"write e.g. {'capture=oracle' if what == '--backend' else 'gate.spp=16'}",
            )
        key, value = item.split("=", 1)
        if what == "--set":
            if "." not in key:
                raise ConfigError(f"{item!r} needs STAGE.FIELD=VALUE", path="--set", hint="write e.g. gate.spp=16")
            stage, field = key.split(".", 1)
            out.setdefault(stage.strip(), {})[field.strip().replace("-", "_")] = value.strip()
        else:
            if not key.strip() or not value.strip():
                raise ConfigError(f"{item!r} is not STAGE=NAME", path=what, hint="write e.g. capture=oracle")
            out[key.strip()] = value.strip()
    return out


def _size(text: str) -> tuple[int, int]:
    """--size WIDTHxHEIGHT as (width, height)."""
    try:
        width, height = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise ConfigError(f"--size {text!r} is not WIDTHxHEIGHT", hint="write e.g. --size 640x480") from None
    return width, height


def _prompts(values: list[str]) -> tuple:
    from rose_usd.case.config import parse_object_prompts

    out = []
    for value in values:
        try:
            out += parse_object_prompts([value])
        except (TypeError, ValueError) as exc:
            raise ConfigError(
                str(exc),
                path="--prompt",
                hint="write e.g. --prompt 0:120,80,200,170 (NAME=0:... names an object of the case, where it has"
                " several)",
            ) from None
    return tuple(out)


def _api_args(args) -> dict:
    settings = _parse_assignments(args.set, "--set")
    options = {
        "isolate": not getattr(args, "in_process", False),
        **CLI_SOURCES,
    }
    if getattr(args, "prompt", None):
        prompts = _prompts(args.prompt)
        settings.setdefault("segment", {})["prompts"] = prompts
        settings.setdefault("capture", {})["prompts"] = prompts  # sfm: origin and scale
        options["prompt_source"] = "--prompt"
    return {
        "backends": _parse_assignments(args.backend, "--backend"),
        "settings": settings,
        "force": args.force,
        "options": options,
    }


def cmd_reconstruct(args) -> int:
    from rose_usd.api import reconstruct

    result = reconstruct(args.case, args.output, validate=not args.no_validate, **_api_args(args))
    _print_result(result)
    return 0


def _print_result(result) -> None:
    from rose_usd.usd import inspect as usd_inspect

    print(usd_inspect.to_text(usd_inspect.dump(result.path)))
    print(f"reconstructed {result.case} -> {result.path} in {result.wall_time_s:.1f} s")
    print(result.summary())


def cmd_run(args) -> int:
    from rose_usd.api import reconstruct

    result = reconstruct(args.case, args.output, until=args.stage, validate=False, **_api_args(args))
    print(result.summary())
    return 0


def cmd_demo(args) -> int:
    from rose_usd.api import reconstruct

    case = Path(args.case) if args.case else _sample_case()
    if not case.exists():
        raise RoseError("the sample case is missing", path=case, hint="reinstall rose_usd, or give --case FOLDER")
    result = reconstruct(case, args.output, validate=not args.no_validate, **_api_args(args))
    _print_result(result)
    if (case / "gt" / "scene.json").is_file():
        print(_accuracy(case, result.out_dir))
    return 0


def _accuracy(case: Path, out: Path) -> str:
    """How close the reconstruction came to the case's ground truth (benchmark metrics)."""
    from rose_usd.bench.evaluate import evaluate

    score = evaluate(case, out, scene=False, rest=False)
    lines = [
        "accuracy against the sample's ground truth:",
        f"  cameras: APE {1e3 * score.camera_ape_translation_m:.2f} mm, {score.camera_ape_rotation_deg:.3f} deg; "
        f"gravity {score.gravity_error_deg:.2f} deg",
    ]
    for o in score.objects:
        mass = f", mass {o.mass_kg:.3f} kg (true {o.true_mass_kg:.3f})" if o.mass_kg and o.true_mass_kg else ""
        lines.append(
            f"  {o.name}: shape Chamfer {1e3 * o.shape_chamfer_m:.2f} mm, size {100 * o.size_error:+.1f} %{mass}; "
            f"trajectory APE {1e3 * o.ape_translation_m:.1f} mm, {o.ape_rotation_deg:.2f} deg; "
            f"mask IoU {o.mask_iou:.3f}"
        )
    if score.ssim_mean is not None:
        lines.append(f"  re-render SSIM {score.ssim_mean:.4f}")
    return "\n".join(lines)


def cmd_batch(args) -> int:
    from rose_usd.batch import batch

    api = _api_args(args)
    result = batch(
        args.cases,
        args.output,
        workers=args.workers,
        ray=args.ray,
        cpus_per_case=args.cpus_per_case,
        gpus_per_case=args.gpus_per_case,
        backends=api["backends"],
        settings=api["settings"],
        until=args.until,
        force=args.force,
        sources={k: v for k, v in api["options"].items() if k.endswith("_source")},
    )
    width = max(len(c.name) for c in result.cases)
    for c in result.cases:
        gate = "" if c.gate_passed is None else ("gate PASS" if c.gate_passed else "gate FAIL")
        ssim = "" if c.ssim_mean is None else f"SSIM {c.ssim_mean:.4f}"
        collect = "" if c.collect_success is None else f"collect {100 * c.collect_success:.0f} %"
        how = "recorded" if c.reused else f"{c.wall_time_s:.1f} s"
        print(
            f"{c.name:<{width}}  {c.status:<6}  {gate:<9}  {ssim:<11}  {collect:<12}  {how}"
            + (f"  {c.error}" if c.error else "")
        )
    done = len(result.cases) - len(result.failed)
    print(
        f"batch: {done} of {len(result.cases)} case(s) done in {result.wall_time_s:.1f} s; "
        f"summary in {result.out_dir / 'index.html'} (and summary.csv, summary.json)"
    )
    return 1 if result.failed else 0


def _stage_file(arg: str) -> Path:
    """A stage argument: a stage file, or an output folder that holds one (its rose.usda)."""
    from rose_usd.usd import paths

    path = Path(arg)
    if path.is_dir():
        if not (path / paths.ROOT_FILE).is_file():
            raise InputError(
                f"no {paths.ROOT_FILE} in this folder (not an output folder, or no stage has written into it yet)",
                path=path,
                hint="give an output folder of `rose-usd reconstruct` or a .usda file",
            )
        return path / paths.ROOT_FILE
    return path


def _composed(stage: Path) -> Path:
    """The output folder's stage where ``stage`` is one of its layers/ (a layer alone has no stage
    metadata and holds only its stage's prims), else ``stage``."""
    from rose_usd.usd import paths

    root = stage.parent.parent / paths.ROOT_FILE
    return root if stage.parent.name == "layers" and root.is_file() else stage


def cmd_inspect(args) -> int:
    from rose_usd.usd import inspect as usd_inspect

    given = _stage_file(args.stage)
    stage = _composed(given)
    if stage != given:
        print(f"inspecting {stage}, the stage that layers/{given.name} is a layer of", file=sys.stderr)
    data = usd_inspect.dump(stage)
    if args.json or args.normalized:
        print(json.dumps(usd_inspect.normalize(data) if args.normalized else data, indent=2, sort_keys=True))
    else:
        print(usd_inspect.to_text(data))
    return 0


def cmd_diff(args) -> int:
    from rose_usd.usd.diff import compare, load_dump

    lines = compare(
        load_dump(_stage_file(args.a)),
        load_dump(_stage_file(args.b)),
        rtol=args.rtol,
        atol=args.atol,
        ignore=tuple(args.ignore or ()),
    )
    for line in lines:
        print(line)
    print(f"{len(lines)} difference(s)" if lines else "stages match within tolerance")
    return 1 if lines else 0


def cmd_validate(args) -> int:
    from rose_usd import registry
    from rose_usd.usd import paths
    from rose_usd.usd.stage import existing_layers
    from rose_usd.usd.validate import validate as validate_stage

    given = _stage_file(args.stage)
    stage = _composed(given)
    if stage != given:  # one layer of an output folder
        print(f"validating {stage}, the stage that layers/{given.name} is a layer of (a layer has no stage metadata)")
    report = validate_stage(stage, with_newton=not args.no_newton)
    for line in report.errors:
        print(f"error: {line}")
    for line in report.warnings:
        print(f"warning: {line}")
    newton = ""
    if report.newton:
        bodies = report.newton["bodies"]
        newton = f"; Newton: {bodies} {'body' if bodies == 1 else 'bodies'}, {report.newton['shapes']} shapes"
    print(f"{report.validators} validators: {len(report.errors)} error(s), {len(report.warnings)} warning(s){newton}")
    if stage.name == paths.ROOT_FILE:  # an output folder: say which stages' layers it lacks
        present = set(existing_layers(stage.parent))
        missing = [s.name for s in registry.STAGES if s.layer not in present]
        if missing:
            print(f"incomplete: no layer of {', '.join(missing)} (rose-usd reconstruct on its case finishes it)")
    report.raise_if_invalid()
    return 0


def cmd_stages(args) -> int:
    from rose_usd import registry
    from rose_usd.stage_config import config_to_dict, setting_docs, setting_names

    def needing(stages) -> str:
        return f"the layers of {', '.join(stages)}" if stages else "no layer"

    for s in [registry.get(args.stage)] if args.stage else registry.STAGES:
        other = "".join(f"; with {b}: {needing(n)}" for b, n in s.needs_by_backend.items())
        print(f"{s.name:<11} layers/{s.layer}.usda  needs {needing(s.needs)}{other}")
        print(f"            backends: auto, {', '.join(s.backends)}")
        print(f"            {s.summary}")
        defaults = config_to_dict(s.config(), running_only=False)
        docs = setting_docs(s.config) if args.stage else {}
        for name in setting_names(s.config):
            owner, _, field = name.rpartition(".")
            default = defaults[owner][field] if owner else defaults[field]
            shown = f"{default:.6g}" if isinstance(default, float) else repr(default)
            print(f"              {s.name}.{name} = {shown}")
            if docs.get(name):
                print(textwrap.fill(docs[name], 100, initial_indent=" " * 18, subsequent_indent=" " * 18))
    return 0


def cmd_bench_generate(args) -> int:
    from rose_usd.synth.generate import GenerateConfig, generate_case
    from rose_usd.synth.motion import Task
    from rose_usd.synth.shapes import ObjectShape

    width, height = _size(args.size)
    config = GenerateConfig(
        task=Task(args.task),
        shape=ObjectShape(args.shape),
        seed=args.seed,
        n_frames=args.frames,
        width=width,
        height=height,
        fps=args.fps,
        spp=args.spp,
    )
    generate_case(config, args.output, overwrite=args.overwrite)
    return 0


def cmd_bench_run(args) -> int:
    from rose_usd.bench.modes import ModeOptions, PerceptionMode
    from rose_usd.bench.report import build_report
    from rose_usd.bench.runner import DEFAULT_CASES, run_suite

    mode = PerceptionMode(args.mode)
    backends = _parse_assignments(args.backend, "--backend") or {"all": "oracle"}
    settings = _parse_assignments(args.set, "--set")
    tag = "-".join(f"{k}={v}" for k, v in sorted(backends.items())).replace("all=", "")
    if args.no_prompts:
        tag += "-unprompted"
    if args.size_prior:
        tag += "-size-prior"
    if args.intrinsics:
        tag += "-intrinsics"
    if args.until:
        tag += f"-until-{args.until}"
    if args.case:
        tag += "-" + "+".join(args.case)
    out = Path(args.output) if args.output else _bench_dir(f"{args.suite}-{mode.value}-{tag}")
    command = (
        "rose-usd " + " ".join(sys.argv[1:])
        if sys.argv and sys.argv[0].endswith("rose-usd")
        else f"rose-usd bench run --suite {args.suite} --mode {mode.value}"
    )
    summary = run_suite(
        args.suite,
        mode,
        out,
        cases_dir=Path(args.cases) if args.cases else DEFAULT_CASES,
        backends=backends,
        settings=settings,
        command=command,
        until=args.until,
        options=ModeOptions(prompts=not args.no_prompts, size_prior=args.size_prior, intrinsics=args.intrinsics),
        start_from=Path(args.start_from) if args.start_from else None,
        rerun=tuple(args.rerun or ()),
        only=tuple(args.case or ()),
    )
    report = build_report(out)
    failed = [c["case"] for c in summary["cases"] if "error" in c]
    print(
        f"{len(summary['cases'])} cases in {summary['suite_wall_time_s']:.0f} s, {len(failed)} failed"
        f" -> {out}/results.json, {report}"
    )
    print(report.read_text().split("## Per case")[0])
    return 1 if failed else 0


def cmd_bench_real(args) -> int:
    from rose_usd.bench.real import evaluate_seven_scenes

    out = Path(args.output) if args.output else _bench_dir(f"real-{args.dataset}")
    if args.dataset == "sam2-cups":
        from rose_usd.bench.real import evaluate_sam2_cups

        result = evaluate_sam2_cups(Path(args.folder), out)
        print(json.dumps(result, indent=1))
        return 0
    result = evaluate_seven_scenes(
        Path(args.folder),
        out,
        backends=_parse_assignments(args.backend, "--backend") or None,
        scene=not args.capture_only,
    )
    print(json.dumps({k: v for k, v in result.items() if k != "capture_results"}, indent=1, default=float))
    return 0


def _frame_counts(text: str) -> list[int]:
    """--frames N or N,N,... as a list of positive ints."""
    try:
        counts = [int(v) for v in text.split(",") if v.strip()]
    except ValueError:
        counts = []
    if not counts or min(counts) < 2:
        raise ConfigError(f"--frames {text!r} is not a frame count", hint="e.g. --frames 300 or --frames 75,150,300")
    return counts


def cmd_bench_speed(args) -> int:
    from rose_usd import registry
    from rose_usd.bench.speed import ALL, measure, measure_all, table

    width, height = _size(args.size)
    frames = _frame_counts(args.frames)
    backends = _parse_assignments(args.backend, "--backend") or {}
    out = Path(args.output) if args.output else _bench_dir("speed")
    if args.stage == ALL:
        until = registry.get(args.until).name if args.until else None
        result = measure_all(backends, frames=frames, width=width, height=height, out_dir=out, until=until)
        print(table(result))
        print(json.dumps({k: v for k, v in result.items() if k != "runs"}, indent=1))
        return 1 if "error" in result else 0
    if args.stage not in registry.STAGE_NAMES:
        raise ConfigError(
            f"unknown stage {args.stage!r}", hint=f"give one of {', '.join(registry.STAGE_NAMES)}, or all"
        )
    if len(frames) > 1:
        raise ConfigError("several --frames are for `bench speed all`", hint=f"time {args.stage} at one length")
    result = measure(args.stage, backends, frames=frames[0], width=width, height=height, out_dir=out)
    print(json.dumps({k: v for k, v in result.items() if k != "all_stages"}, indent=1))
    return 1 if "error" in result else 0


def cmd_bench_rescore(args) -> int:
    from rose_usd.bench.report import build_report
    from rose_usd.bench.runner import DEFAULT_CASES, rescore

    rescore(Path(args.results), cases_dir=Path(args.cases) if args.cases else DEFAULT_CASES)
    print(build_report(Path(args.results)))
    return 0


def cmd_bench_report(args) -> int:
    from rose_usd.bench.report import build_report

    report = build_report(Path(args.results))
    print(report.read_text())
    return 0


def _add_pipeline_flags(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "-o",
        "--output",
        required=True,
        help="output folder (rose.usda, layers/, masks/, report/); made if missing, checked before any work",
    )
    p.add_argument(
        "--backend",
        action="append",
        metavar="STAGE=NAME",
        help="backend of a stage (repeatable); STAGE 'all' sets every stage that has it",
    )
    p.add_argument(
        "--set",
        action="append",
        metavar="STAGE.FIELD=VALUE",
        help="override a stage setting (repeatable); see `rose-usd stages`",
    )
    p.add_argument(
        "--prompt",
        action="append",
        metavar="[NAME=]FRAME:X0,Y0,X1,Y1",
        help="an object's prompt box (or FRAME:X,Y point) in pixels, overriding rose.toml"
        " (repeatable; NAME may be left out for one object); segment's and capture's (the prompted"
        " object sets the world's origin; with RGB only, its metric scale too)",
    )
    p.add_argument("--force", action="store_true", help="re-run stages even when their layer is up to date")
    p.add_argument(
        "--in-process",
        action="store_true",
        help="run every stage in this process (for a debugger or profiler), not each in a child"
        " process of its own (which keeps a stage's memory to its own)",
    )


class _Parser(argparse.ArgumentParser):
    """argparse with a usage error as one line and exit status 1, like every other error a user
    can fix (argparse's own prints the usage and exits 2, which rose-usd keeps for bugs)."""

    argv: list[str] = []

    def parse_known_args(self, args=None, namespace=None):
        _Parser.argv = list(sys.argv[1:] if args is None else args)
        return super().parse_known_args(args, namespace)

    def error(self, message: str):
        flag = re.match(r"argument (--[\w-]+).*: expected one argument$", message)
        after = [b for a, b in zip(self.argv, self.argv[1:]) if flag and a == flag.group(1)]
        if any(v.startswith("-") and v[1:2].isdigit() for v in after):  # argparse took the value for an option
            message += f" (a value that starts with '-' is written {flag.group(1)}=VALUE)"
        self.exit(1, f"error: {self.prog}: {message}; see `{self.prog} --help`\n")


def _non_negative(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not value >= 0.0:
        raise argparse.ArgumentTypeError(f"{text} is not a tolerance (a number >= 0)")
    return value


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="rose-usd", description="Casual video of a person moving an object -> simulator-ready OpenUSD stage."
    )
    sub = parser.add_subparsers(dest="command", required=True)
    _add_pipeline_commands(sub)
    _add_stage_commands(sub)
    _add_bench_commands(
        sub.add_parser("bench", help="benchmarks: generated cases with ground truth, speed, real recordings")
    )
    return parser


def _add_pipeline_commands(sub) -> None:
    """reconstruct, run, demo."""
    p = sub.add_parser(
        "reconstruct",
        help="run every stage on a case, collect's robot rollouts last, where the gate passed (skips stages that"
        " are up to date; `run gate` stops before collect)",
    )
    p.add_argument("case", help="case folder, or video file (with its settings in <name>.toml beside it)")
    _add_pipeline_flags(p)
    p.add_argument("--no-validate", action="store_true", help="skip UsdValidation and the Newton load at the end")
    p.set_defaults(func=cmd_reconstruct)

    p = sub.add_parser("run", help="run one stage, first running stages it needs whose layers are missing or stale")
    p.add_argument("stage", help="stage name (see `rose-usd stages`)")
    p.add_argument("case", help="case folder, or video file (with its settings in <name>.toml beside it)")
    _add_pipeline_flags(p)
    p.set_defaults(func=cmd_run)

    p = sub.add_parser(
        "batch",
        help="reconstruct many cases, each in its own process (or as Ray tasks); a re-run resumes where it stopped",
    )
    p.add_argument("cases", nargs="+", help="case folders or video files")
    p.add_argument("-o", "--output", required=True, help="batch folder: OUT/<case name>/ per case and the summary")
    p.add_argument("--workers", type=int, default=1, help="cases run at once, each in its own process (default 1)")
    p.add_argument(
        "--ray", metavar="ADDRESS", help="run the cases as Ray tasks: ADDRESS, auto (a running cluster) or local"
    )
    p.add_argument(
        "--cpus-per-case",
        type=float,
        default=1.0,
        help="with --ray: CPUs each case needs (default 1; a node must have them)",
    )
    p.add_argument("--gpus-per-case", type=float, default=0.0, help="with --ray: GPUs each case needs (default 0)")
    p.add_argument("--until", metavar="STAGE", help="run only this stage and what it needs, for every case")
    p.add_argument("--backend", action="append", metavar="STAGE=NAME", help="backend of a stage (as for reconstruct)")
    p.add_argument("--set", action="append", metavar="STAGE.FIELD=VALUE", help="override a stage setting")
    p.add_argument("--force", action="store_true", help="re-run every stage of every case")
    p.set_defaults(func=cmd_batch)

    p = sub.add_parser(
        "demo", help="reconstruct the bundled sample (auto backends), then score it against its ground truth"
    )
    p.add_argument("-o", "--output", default="out/demo", help="output folder (default out/demo)")
    p.add_argument("--case", help="another case folder instead of the bundled sample")
    p.add_argument("--backend", action="append", metavar="STAGE=NAME", help="backend of a stage (as for reconstruct)")
    p.add_argument("--set", action="append", metavar="STAGE.FIELD=VALUE", help="override a stage setting")
    p.add_argument("--force", action="store_true", help="re-run every stage")
    p.add_argument("--no-validate", action="store_true", help="skip validation at the end")
    p.add_argument(
        "--in-process",
        action="store_true",
        help="run every stage in this process (for a debugger or profiler), not each in a child"
        " process of its own (which keeps a stage's memory to its own)",
    )
    p.set_defaults(func=cmd_demo)


def _add_stage_commands(sub) -> None:
    """inspect, diff, validate, stages: what a stage holds, without running anything."""
    p = sub.add_parser(
        "inspect",
        help="dump a stage: layers, prims, schemas, physics, meshes, cameras, gate; where its layers disagree",
    )
    p.add_argument("stage", help="a .usda/.usd file, or an output folder (its rose.usda)")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.add_argument(
        "--normalized", action="store_true", help="the stable JSON form used by stages/ and diff (implies --json)"
    )
    p.set_defaults(func=cmd_inspect)

    p = sub.add_parser(
        "diff", help="compare two stages (or --json dumps) with tolerances, timings left out; exit 1 if they differ"
    )
    p.add_argument("a", help="a .usda/.usd file, an output folder (its rose.usda) or an `inspect --json` dump")
    p.add_argument("b", help="the same, to compare with a")
    p.add_argument("--rtol", type=_non_negative, default=1e-4, help="relative tolerance (default 1e-4)")
    p.add_argument("--atol", type=_non_negative, default=1e-6, help="absolute tolerance (default 1e-6)")
    p.add_argument("--ignore", action="append", metavar="SUBSTRING", help="skip keys containing this (repeatable)")
    p.set_defaults(func=cmd_diff)

    p = sub.add_parser(
        "validate",
        help="run every pxr.UsdValidation validator and Newton's add_usd on a stage; in an output folder, also"
        " check that its layers were made from one another and one case, and name the stages whose layers it lacks",
    )
    p.add_argument(
        "stage", help="a .usda/.usd file, or an output folder (its rose.usda; a file of its layers/ stands for it too)"
    )
    p.add_argument("--no-newton", action="store_true", help="skip the Newton load")
    p.set_defaults(func=cmd_validate)

    p = sub.add_parser("stages", help="list the pipeline stages, their backends and settings (with defaults)")
    p.add_argument("stage", nargs="?", help="one stage, its settings explained (e.g. `rose-usd stages gate`)")
    p.set_defaults(func=cmd_stages)


def _add_bench_commands(bench) -> None:
    bsub = bench.add_subparsers(dest="bench_command", required=True)
    _add_bench_generate(bsub)
    _add_bench_run(bsub)
    _add_bench_tools(bsub)


def _add_bench_generate(bsub) -> None:
    from rose_usd.synth.motion import Task
    from rose_usd.synth.shapes import ObjectShape

    p = bsub.add_parser("generate", help="render one synthetic case with full ground truth")
    p.add_argument("-o", "--output", required=True, help="case folder to create")
    p.add_argument("--task", default="push", choices=[t.value for t in Task], help="what the hand does (default push)")
    p.add_argument("--shape", default="box", choices=[s.value for s in ObjectShape], help="the object (default box)")
    p.add_argument("--seed", type=int, default=0, help="random seed of the scene and motion (default 0)")
    p.add_argument("--frames", type=int, default=48, help="frames to render (default 48)")
    p.add_argument("--size", default="320x240", help="WIDTHxHEIGHT (default 320x240)")
    p.add_argument("--fps", type=float, default=30.0, help="frame rate (default 30)")
    p.add_argument("--spp", type=int, default=16, help="samples per pixel (anti-aliasing)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing case folder")
    p.set_defaults(func=cmd_bench_generate)


def _add_bench_run(bsub) -> None:
    p = bsub.add_parser("run", help="run a suite of generated cases in one perception mode and score every stage")
    p.add_argument(
        "--suite",
        default="small",
        help="suite name: small (CI), default (5 tasks x 2 seeds, 640x480) or realistic"
        " (5 tasks, a fingered hand, printed objects, 480x360)",
    )
    p.add_argument(
        "--mode", default="rgbd", choices=["rgbd", "mono-imported", "rgb"], help="what the cases give the pipeline"
    )
    p.add_argument(
        "--case",
        action="append",
        metavar="NAME",
        help="run only this case (push-box-s13) or task's cases (push); repeatable (default: every case)",
    )
    p.add_argument("--backend", action="append", metavar="STAGE=NAME", help="backends (default all=oracle)")
    p.add_argument("--set", action="append", metavar="STAGE.FIELD=VALUE", help="stage settings")
    p.add_argument("-o", "--output", help="results folder (default benchmarks/results/SUITE-MODE-BACKENDS)")
    p.add_argument("--cases", help="where generated cases are cached (default benchmarks/cases)")
    p.add_argument(
        "--until", metavar="STAGE", help="run only this stage and what it needs (metrics of later stages are left out)"
    )
    p.add_argument(
        "--no-prompts",
        action="store_true",
        help="drop the object prompts from the cases' rose.toml (objects are named, never pointed at)",
    )
    p.add_argument(
        "--size-prior",
        action="store_true",
        help="give each object's size_m (its true largest extent) in the cases' rose.toml (rgb mode's metric scale)",
    )
    p.add_argument(
        "--intrinsics",
        action="store_true",
        help="keep the cases' cam_K.txt where the mode drops it (rgb, mono-imported): a calibrated camera",
    )
    p.add_argument(
        "--start-from",
        metavar="FOLDER",
        help="start each case from a copy of this earlier results folder's kept run (same suite and mode):"
        " its current layers (same config, inputs and code) are not run again, their times carried over",
    )
    p.add_argument(
        "--rerun",
        action="append",
        metavar="STAGE",
        help="with --start-from: run this stage even when its layer is current (what depends on it follows)",
    )
    p.set_defaults(func=cmd_bench_run)


def _add_bench_tools(bsub) -> None:
    """bench speed, real, rescore and report."""
    p = bsub.add_parser(
        "speed",
        help="time one stage, or every stage (`all`), on a long generated case (default 300 frames at 640x480)",
        description="STAGE: time that stage (its prerequisites run first, untimed) and write speed-STAGE.json."
        " all: run every stage with the auto backends and the gate on every frame, report each stage's wall"
        " time, the end-to-end time and the peak memory of the process tree, at each of --frames (e.g."
        " 75,150,300, with a linear fit of time against frames), and write speed-all.json.",
    )
    p.add_argument("stage", help="stage to time, or `all` for every stage end to end")
    p.add_argument("--backend", action="append", metavar="STAGE=NAME", help="backends (default: each stage's default)")
    p.add_argument("--frames", default="300", help="frames of the case; with `all` a list too, e.g. 75,150,300")
    p.add_argument("--size", default="640x480", help="WIDTHxHEIGHT of the generated case (default 640x480)")
    p.add_argument("--until", metavar="STAGE", help="with `all`: only STAGE and what it needs (default: every stage)")
    p.add_argument("-o", "--output", help="output folder (default benchmarks/results/speed)")
    p.set_defaults(func=cmd_bench_speed)
    p = bsub.add_parser(
        "real",
        help="run rose on a real recording: 7scenes (capture and scene mesh vs recorded poses),"
        " sam2-cups (masks of one cup, contact sheet)",
    )
    p.add_argument("dataset", choices=["7scenes", "sam2-cups"])
    p.add_argument(
        "folder", help="e.g. ../shared/data/real/7scenes-redkitchen-600-799 or ../shared/data/real/sam2-cups"
    )
    p.add_argument("-o", "--output", help="output folder (default benchmarks/results/real-DATASET)")
    p.add_argument(
        "--backend",
        action="append",
        metavar="STAGE=NAME",
        help="backends (default capture=rgbd, segment=classical, scene=tsdf)",
    )
    p.add_argument("--capture-only", action="store_true", help="stop after capture (no scene mesh comparison)")
    p.set_defaults(func=cmd_bench_real)
    p = bsub.add_parser(
        "rescore",
        help="score a results folder's runs again with the current metrics (no stage re-runs), then rebuild its report",
    )
    p.add_argument("results", help="a folder with results.json and runs/")
    p.add_argument("--cases", help="where generated cases are cached (default benchmarks/cases)")
    p.set_defaults(func=cmd_bench_rescore)

    p = bsub.add_parser("report", help="write report.md and plots for a results folder")
    p.add_argument("results", help="a folder with results.json")
    p.set_defaults(func=cmd_bench_report)


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except RoseError as exc:
        print(f"error: {exc.one_line()}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # output piped into `head` and the like
        sys.stderr.close()
        return 0
    except Exception:  # a bug: show everything
        traceback.print_exc()
        return 2


if __name__ == "__main__":
    sys.exit(main())
