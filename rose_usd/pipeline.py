"""Running stages: configs from defaults, rose.toml and the caller; the plan (``auto`` resolved) and
its preflight before anything is written; make-like skipping of stages whose config, inputs and
code are unchanged; provenance for every layer."""

from __future__ import annotations

import contextlib
import dataclasses
import difflib
import enum
import hashlib
import json
import os
import pickle
import time
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from rose_usd import plan as planning
from rose_usd import registry
from rose_usd.case.layout import Case, load_case
from rose_usd.errors import ConfigError, RoseError, StageError
from rose_usd.progress import say
from rose_usd.stage_api import StageContext, StageDef, code_version
from rose_usd.stage_config import build_config, check_config, config_hash, config_to_dict, flatten, setting_names
from rose_usd.usd import stage as usd_stage

_hash_cache: dict[tuple[str, int, int], str] = {}


def _cached_file_hash(path: Path) -> str:
    st = path.stat()
    key = (str(path.resolve()), st.st_size, st.st_mtime_ns)
    if key not in _hash_cache:
        _hash_cache[key] = usd_stage.file_hash(path)
    return _hash_cache[key]


def _files_hash(files: list[Path], root: Path, settings: Path | None = None) -> str:
    """The files' hash (their paths under ``root`` and contents); the case's ``settings`` file
    among them by ``_settings_hash``."""
    h = hashlib.sha256()
    for f in sorted(files):
        h.update(str(f.relative_to(root) if f.is_relative_to(root) else f).encode())
        h.update((_settings_hash(f) if f == settings else _cached_file_hash(f)).encode())
    return h.hexdigest()[:16]


def _settings_hash(path: Path) -> str:
    """A case's settings file (rose.toml, a video's <name>.toml) hashed without its stage tables
    and ``[backends]``: each stage's own table and backend are in its config, hashed apart, so an
    edit of ``[gate]`` makes the gate stale, not every stage (a new user's ``spp = 8`` there re-ran
    capture onwards and removed the robot's dataset). Comments and layout do not count either."""
    try:
        data = tomllib.loads(path.read_text())
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError):
        return _cached_file_hash(path)
    kept = {k: v for k, v in data.items() if k not in registry.STAGE_NAMES and k != "backends"}
    return hashlib.sha256(json.dumps(kept, sort_keys=True, default=str).encode()).hexdigest()


def _changed_settings(stage: str, made_with: object, config) -> str:
    """The settings a layer was made with that differ from ``config``'s, as " (a, b 1 -> 2)" (values
    where short), or "" where the layer recorded none."""
    if not isinstance(made_with, dict):
        return ""
    was, now = flatten(made_with), flatten(json.loads(json.dumps(config_to_dict(config))))
    shown = []
    for k in sorted(set(was) | set(now)):
        if was.get(k, None) != now.get(k, None):
            a, b = (json.dumps(d[k]) if k in d else "unset" for d in (was, now))
            shown.append(f"{stage}.{k}" + (f" {a} -> {b}" if len(a) + len(b) <= 40 else ""))
    return f" ({', '.join(shown[:4])}{', ...' if len(shown) > 4 else ''})" if shown else ""


BackendChoice = str | enum.Enum | Any
"""A backend's name, its member of the stage's backend enum, or a whole config instance."""


CLI_SOURCES = {"settings_source": "--set", "prompt_source": "--set", "backends_source": "--backend"}
"""``Options``' sources where settings and backends come from the command line's flags."""


@dataclass
class Options:
    """What the caller chose (strongest) on top of rose.toml and the configs' defaults."""

    backends: Mapping[str, BackendChoice] = field(default_factory=dict)
    """stage -> backend name, backend enum member, or an instance of the stage's config (which
    then is the stage's whole config: rose.toml's section and ``settings`` are not applied to
    it); key ``all`` applies a name to every stage that has that backend."""
    settings: Mapping[str, Mapping[str, object]] = field(default_factory=dict)
    """stage -> {field: value}."""
    force: bool = False
    """Re-run stages even when they are up to date."""
    settings_source: str = "settings="
    """What errors in ``settings`` name as their source (the CLI: ``--set``)."""
    prompt_source: str = "settings="
    """What errors in ``settings["segment"]["prompts"]`` name as their source (``--set``, ``--prompt``)."""
    backends_source: str = "backends="
    """What errors in ``backends`` name as their source (the CLI: ``--backend``)."""
    isolate: bool = False
    """Run each stage in a child process of its own (``multiprocessing``'s spawn), which ends with
    it: the memory a stage holds is its own libraries and data, not those of every stage before it
    in the process (300 frames at 640x480: 2.3 GB peak in one process, the largest stage alone
    1.3 GB). The layers are all that passes between stages either way. Off, stages run in the
    caller's process (what tests that patch a stage's code need); the CLI turns it on."""


@dataclass(frozen=True)
class StageOutcome:
    """What happened to one stage of a run."""

    name: str
    status: str
    """``ran``, ``skipped`` (its layer was up to date), ``failed`` or ``not run`` (a stage before
    it failed)."""
    wall_time_s: float
    backend: str
    error: str | None = None
    """The failure's one-line message."""
    removed: tuple[str, ...] = ()
    """The layers after it that its new layer made stale, removed in its commit."""
    recorded_s: float | None = None
    """A stage found up to date: the seconds its layer records it took to make."""

    @property
    def ran(self) -> bool:
        return self.status == "ran"

    @property
    def made_in_s(self) -> float | None:
        """Seconds its layer took to make: this run's where it ran, the layer's record where it
        was up to date, None otherwise."""
        return self.wall_time_s if self.ran else self.recorded_s


class Pipeline:
    """The stages of one case writing into one output folder."""

    def __init__(self, case: Case | str | Path, out_dir: str | Path, options: Options | None = None):
        self.options = options or Options()
        self._check_option_stages()
        self.case = case if isinstance(case, Case) else load_case(case, registry.STAGE_NAMES)
        self.out_dir = usd_stage.check_out_dir(out_dir)
        self.time_info = usd_stage.TimeInfo(fps=self.case.fps, n_frames=self.case.n_frames)
        self._configs: dict[str, Any] = {}
        self._unresolved: dict[str, Any] = {}
        # one typed reading of every stage's settings (rose.toml, then the caller's), whichever
        # stages this run involves: a mistake anywhere fails before anything is written
        for stage_def in registry.STAGES:
            self._unresolved[stage_def.name] = self._build_config(stage_def)
        planning.check_categories(self.case)
        planning.check_prompts(self.case, self._unresolved["segment"].prompts, self._prompts_where())

    def _prompts_where(self) -> str:
        """Where the segment stage's prompts come from: the caller's (``--prompt``) or rose.toml."""
        return self._setting_where("segment", "prompts", self.options.prompt_source)

    def _setting_where(self, stage: str, name: str, given: str) -> str:
        """Where setting ``stage.name`` comes from: ``given`` (the caller's flag) where the caller
        set it, else the case's settings file."""
        return given if name in flatten(self.options.settings.get(stage, {})) else str(self.case.settings_file)

    def _check_option_stages(self) -> None:
        chosen = self.options.backends_source
        sources = ((chosen, self.options.backends), (self.options.settings_source, self.options.settings))
        for what, given in sources:
            for stage in given:
                if stage == "all" and what == chosen:
                    continue
                if stage not in registry.STAGE_NAMES:
                    raise ConfigError(
                        f"unknown stage {stage!r}", path=what, hint=f"stages: {', '.join(registry.STAGE_NAMES)}"
                    )
        everyone = self.options.backends.get("all")
        if everyone is not None:
            name = everyone.value if isinstance(everyone, enum.Enum) else everyone
            known = sorted({b for s in registry.STAGES for b in s.backends})
            if not isinstance(name, str) or (name != planning.AUTO and name not in known):
                raise ConfigError(
                    f"no stage has a backend {name!r}", path=chosen, hint=f"backends: auto, {', '.join(known)}"
                )

    # ------------------------------------------------------------------ config
    def _backend_choice(self, stage_def: StageDef) -> tuple[BackendChoice | None, str | None]:
        """The backend asked for and where it was asked (``--backend`` or rose.toml's path)."""
        choice = self.options.backends.get(stage_def.name)
        if choice is not None:
            return choice, self.options.backends_source
        choice = self.case.config.backends.get(stage_def.name)
        if choice is not None:
            return choice, str(self.case.settings_file)
        everyone = self.options.backends.get("all")
        if isinstance(everyone, str | enum.Enum):
            everyone = everyone.value if isinstance(everyone, enum.Enum) else everyone
            if everyone in stage_def.backends:
                return everyone, self.options.backends_source
        return None, None

    def config(self, stage_def: StageDef):
        """The stage's config with ``auto`` resolved (the layer records the backend that ran)."""
        if stage_def.name not in self._configs:
            config = self._unresolved[stage_def.name]
            if config.backend.value == planning.AUTO:
                backend = planning.resolve_auto(stage_def.name, self.case)
                config = dataclasses.replace(config, backend=type(config.backend)(backend))
            self._configs[stage_def.name] = config
        return self._configs[stage_def.name]

    def _build_config(self, stage_def: StageDef):
        toml = str(self.case.settings_file)
        choice, where = self._backend_choice(stage_def)
        if isinstance(choice, stage_def.config):
            return check_config(stage_def.name, choice, source=where)
        if choice is not None:
            if isinstance(choice, enum.Enum):
                choice = choice.value
            if not isinstance(choice, str) or (choice not in stage_def.backends and choice != planning.AUTO):
                given = f"{type(choice).__name__} instance" if dataclasses.is_dataclass(choice) else repr(choice)
                close = (
                    difflib.get_close_matches(choice, list(stage_def.backends), n=1) if isinstance(choice, str) else []
                )
                raise ConfigError(
                    f"stage {stage_def.name!r} has no backend {given}",
                    path=where,
                    hint=(f"did you mean {close[0]}? " if close else "")
                    + f"backends of {stage_def.name}: auto, {', '.join(stage_def.backends)}",
                )
        names = setting_names(stage_def.config)
        from_toml = flatten(self.case.config.stage_overrides.get(stage_def.name, {}), names)
        from_caller = flatten(self.options.settings.get(stage_def.name, {}), names)
        # each source on its own first, so that an error names the one it is in
        build_config(stage_def.name, stage_def.config, from_toml, source=toml, strict=True)
        build_config(stage_def.name, stage_def.config, from_caller, source=self.options.settings_source)
        values = {**from_toml, **from_caller}
        if choice is not None:
            values["backend"] = choice
        return build_config(stage_def.name, stage_def.config, values, source=where)

    # ------------------------------------------------------------------ plan
    def plan(self, target: str | None = None) -> list[StageDef]:
        """The stages a run of ``target`` (or of everything) involves, in run order, after checking
        that every one of them has what its backend requires (nothing is written before)."""
        if target is None:
            stages = list(registry.STAGES)
        else:
            stages = registry.closure(target, lambda s: self.config(s).backend.value)
        backends = {s.name: self.config(s).backend.value for s in stages}
        planning.preflight(self.case, backends, {s.name: s.requires_of(backends[s.name]) for s in stages})
        prompts = self.config(registry.get("segment")).prompts if "segment" in backends else None
        if backends.get("segment") == "flow":
            planning.check_prompted(self.case, prompts, self._prompts_where())
        elif backends.get("segment") == "classical":
            planning.check_all_or_none(self.case, prompts, self._prompts_where())
        if "collect" in backends:
            where = self._setting_where("collect", "object_name", self.options.settings_source)
            planning.check_collect_object(self.case, self.config(registry.get("collect")).object_name, where)
        return stages

    def check_output(self) -> None:
        """The output folder is this case's (``usd.stage.check_out_case``), checked after the
        inputs: a broken input is named as such, not as another case."""
        usd_stage.check_out_case(self.out_dir, self.case.root, lambda: self._inputs_hash(self.case.input_files()))

    def plan_line(self, stages: list[StageDef]) -> str:
        return "plan: " + " ".join(f"{s.name}={self.config(s).backend.value}" for s in stages)

    # ------------------------------------------------------------------ staleness
    def input_hashes(self, stage_def: StageDef, config) -> dict[str, str]:
        inputs = {"case": self._inputs_hash(self.case.input_files())}
        if config.backend.value == "oracle" or stage_def.name == "gate":
            gt_dir = self.case.folder / "gt"
            if gt_dir.is_dir():
                inputs["gt"] = _files_hash([p for p in gt_dir.rglob("*") if p.is_file()], self.case.folder)
        for need in stage_def.needs_of(config.backend.value):
            layer = usd_stage.layer_file(self.out_dir, registry.get(need).layer)
            inputs[f"layer:{registry.get(need).layer}"] = _cached_file_hash(layer) if layer.is_file() else "missing"
        return inputs

    def _case_parts(self) -> dict[str, str]:
        """The case's input files' hash per entry of the case folder (``rgb/``, ``rose.toml``, the
        video): what a stale layer's reason names when the case changed."""
        groups: dict[str, list[Path]] = {}
        for f in self.case.input_files():
            rel = f.relative_to(self.case.folder) if f.is_relative_to(self.case.folder) else Path(f.name)
            groups.setdefault(rel.parts[0] + ("/" if len(rel.parts) > 1 else ""), []).append(f)
        return {k: self._inputs_hash(v) for k, v in groups.items()}

    def _inputs_hash(self, files: list[Path]) -> str:
        """The hash of some of the case's input files (its settings file without its stage tables)."""
        return _files_hash(files, self.case.folder, self.case.config.path)

    def is_current(self, stage_def: StageDef) -> bool:
        """Whether the stage's layer exists and was made from the same config, inputs and code."""
        return self.why_stale(stage_def) is None

    def why_stale(self, stage_def: StageDef) -> str | None:
        """Why the stage must run again (its layer missing; made by other code, with other
        settings, from other inputs, or at another frame count or rate), None when it is current."""
        prov = usd_stage.read_provenance(usd_stage.layer_file(self.out_dir, stage_def.layer))
        if prov is None:
            return "its layer is missing"
        config = self.config(stage_def)
        if prov.get("code") != code_version(stage_def, config.backend.value):
            return "rose_usd's code changed since its layer was made"
        if prov.get("config_hash") != config_hash(config):
            return "its settings changed" + _changed_settings(stage_def.name, prov.get("config"), config)
        made_from, now = prov.get("inputs") or {}, self.input_hashes(stage_def, config)
        changed = [
            k.removeprefix("layer:") for k in sorted(set(made_from) | set(now)) if made_from.get(k) != now.get(k)
        ]
        if changed:
            if "case" in changed and isinstance(prov.get("case_parts"), dict):
                parts, was = self._case_parts(), prov["case_parts"]
                named = [k for k in sorted(set(parts) | set(was)) if parts.get(k) != was.get(k)]
                changed[changed.index("case")] = f"case: {', '.join(named)}" if named else "case"
            return f"what it was made from changed ({'; '.join(changed)})"
        if usd_stage.read_time_info(self.out_dir) != self.time_info:
            return "the frame count or rate changed"
        return None

    # ------------------------------------------------------------------ running
    def run_stage(self, stage_def: StageDef) -> StageOutcome:
        if self.options.isolate:
            return _in_child_process(self, stage_def)
        config = self.config(stage_def)
        for need in stage_def.needs_of(config.backend.value):
            if not usd_stage.layer_file(self.out_dir, registry.get(need).layer).is_file():
                raise StageError(
                    f"stage {stage_def.name!r} needs layer {registry.get(need).layer!r}, which is missing",
                    path=self.out_dir,
                    hint=f"run `rose-usd run {need}` first",
                )
        provenance = {
            "stage": stage_def.name,
            "backend": config.backend.value,
            "config": config_to_dict(config),
            "config_hash": config_hash(config),
            "code": code_version(stage_def, config.backend.value),
            "inputs": self.input_hashes(stage_def, config),
            "case": str(self.case.root.resolve()),
            "case_parts": self._case_parts(),
        }
        func = stage_def.backend_function(config.backend.value)
        say(f"[{stage_def.name}] backend {config.backend.value}")
        side_dirs = {s.layer: s.side_dirs for s in registry.STAGES}
        writer = usd_stage.LayerWriter(self.out_dir, stage_def.layer, self.time_info, provenance, side_dirs)
        with writer:
            _fresh_random_state()
            func(StageContext(stage_def, config, self.case, self.out_dir, self.time_info, writer))
        wall = float(writer.provenance["wall_time_s"])
        say(f"[{stage_def.name}] wrote {usd_stage.layer_file(self.out_dir, stage_def.layer)} in {wall:.1f} s")
        backend = usd_stage.shown_backend(writer.provenance, config.backend.value)
        return StageOutcome(stage_def.name, "ran", wall, backend, removed=tuple(writer.removed))

    def run(self, target: str | None = None, *, check: bool = True) -> list[StageOutcome]:
        """Run ``target`` (or every stage) and whatever it needs that is missing or stale.

        Every config and the plan's preflight are checked before any stage runs. A stage that
        fails leaves its previous layer as it was; with ``check`` its error propagates, otherwise
        it is recorded in its outcome and the stages after it are ``not run``. While it runs, no
        other run may write the output folder (``usd.stage.output_lock``)."""
        stages = self.plan(target)
        self.check_output()
        with usd_stage.output_lock(self.out_dir):
            return self._run(stages, target, check)

    def _run(self, stages: list[StageDef], target: str | None, check: bool) -> list[StageOutcome]:
        say(self.plan_line(stages))
        for line in usd_stage.recover(self.out_dir):
            say(f"[{self.out_dir}] {line}")
        outcomes: list[StageOutcome] = []
        failed: str | None = None
        for stage_def in stages:
            backend = self.config(stage_def).backend.value
            if failed is not None:
                outcomes.append(StageOutcome(stage_def.name, "not run", 0.0, backend))
                continue
            must = self.options.force and (target is None or stage_def.name == target)
            # why_stale compares the upstream layers' hashes, so a re-run upstream stage makes
            # exactly its dependents stale
            why = self.why_stale(stage_def) or ("--force" if must else None)
            if why is not None:
                if why != "its layer is missing":
                    say(f"[{stage_def.name}] runs again: {why}")
                t0 = time.perf_counter()
                try:
                    outcomes.append(self.run_stage(stage_def))
                    self._say_removed(outcomes[-1], stages)
                except RoseError as exc:
                    if check:
                        raise
                    failed = exc.one_line()
                    outcomes.append(
                        StageOutcome(stage_def.name, "failed", time.perf_counter() - t0, backend, error=failed)
                    )
            else:
                say(f"[{stage_def.name}] up to date")
                prov = usd_stage.read_provenance(usd_stage.layer_file(self.out_dir, stage_def.layer)) or {}
                made = float(prov["wall_time_s"]) if prov.get("wall_time_s") is not None else None
                shown = usd_stage.shown_backend(prov, backend)
                outcomes.append(StageOutcome(stage_def.name, "skipped", 0.0, shown, recorded_s=made))
        if usd_stage.existing_layers(self.out_dir) and not usd_stage.root_file(self.out_dir).is_file():
            usd_stage.write_root(self.out_dir, self.time_info)
        return outcomes

    @staticmethod
    def _say_removed(outcome: StageOutcome, stages: list[StageDef]) -> None:
        """Which layers the stage's commit removed as stale; what to do only for those this run
        does not make again."""
        if not outcome.removed:
            return
        later = {s.layer for s in stages}
        left = [s.name for s in registry.STAGES if s.layer in outcome.removed and s.layer not in later]
        # `run STAGE` makes the missing layers before it too: the last one left makes them all
        say(
            f"[{outcome.name}] removed the layers it made stale: {', '.join(outcome.removed)}"
            + (
                f" (make them again with `rose-usd run {left[-1]} ...` or `rose-usd reconstruct`)"
                if left
                else " (this run makes them again)"
            )
        )


def _in_child_process(pipe: Pipeline, stage_def: StageDef) -> StageOutcome:
    """``pipe.run_stage(stage_def)`` in a spawned child process; its outcome, or its error raised
    here (a RoseError as the child raised it; a bug's traceback is printed by the child). The
    child dies with this process (``PR_SET_PDEATHSIG``): a killed run leaves no stage running on."""
    import multiprocessing

    ctx = multiprocessing.get_context("spawn")
    receive, send = ctx.Pipe(duplex=False)
    options = dataclasses.replace(pipe.options, isolate=False)
    child = ctx.Process(
        target=_child_stage,
        args=(send, pipe.case, pipe.out_dir, options, stage_def.name, os.getpid()),
        name=stage_def.name,
    )
    with _sigint_ignored():  # inherited: the child's start-up is never interrupted mid-import
        child.start()
    try:
        send.close()
        ok, result = pickle.loads(receive.recv_bytes())  # rebuilt once in the child (_child_stage)
    except EOFError:
        ok, result = False, None
    except KeyboardInterrupt:
        _interrupt(child)
        raise
    finally:
        child.join()
        receive.close()
    if ok:
        return result
    if result is None:
        raise _ended_early(stage_def.name, child.exitcode, pipe.out_dir)
    raise result


def _ended_early(stage: str, code: int | None, out_dir: Path) -> BaseException:
    """What to raise for a stage's child process that ended before it sent its outcome:
    KeyboardInterrupt where Ctrl-C stopped it (it reached the child, not this process, which
    ignores SIGINT when a script started it in the background), else one line saying whether it
    was stopped, killed (SIGKILL: most often the kernel's out-of-memory killer) or ended otherwise.
    Its layer is written only when it finishes."""
    import signal

    if code in (-signal.SIGINT, 128 + signal.SIGINT):
        return KeyboardInterrupt()
    again = "its layer was not written (an earlier one is kept); the same command goes on from there"
    if code in (-signal.SIGTERM, 128 + signal.SIGTERM):
        return StageError(f"stage {stage!r} was stopped (SIGTERM)", path=out_dir, hint=again)
    if code == -signal.SIGKILL:
        return StageError(
            f"stage {stage!r}'s process was killed (SIGKILL), most likely for lack of memory",
            path=out_dir,
            hint=f"{again}; free memory, or run fewer jobs side by side",
        )
    return StageError(
        f"stage {stage!r}'s process ended (exit code {code}) before it finished", path=out_dir, hint=again
    )


@contextlib.contextmanager
def _sigint_ignored():
    """SIGINT ignored meanwhile (on the main thread; elsewhere signals cannot be set)."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    before = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, before)


def _interrupt(child, *, settle_s: float = 2.0, rollback_s: float = 10.0) -> None:
    """Ctrl-C reached this process while ``child`` runs a stage. A terminal's Ctrl-C reaches the
    child too, which then rolls its layer back and ends: give it ``settle_s``. Otherwise send it
    SIGINT, give it ``rollback_s``, then kill it (a killed commit is recovered at the next run)."""
    import signal

    try:
        child.join(settle_s)
        if child.is_alive():
            os.kill(child.pid, signal.SIGINT)
            child.join(rollback_s)
    except KeyboardInterrupt:  # asked again: do not wait
        pass
    if child.is_alive():
        child.kill()


def _child_stage(send, case: Case, out_dir: Path, options: Options, name: str, parent: int) -> None:
    import signal

    from rose_usd.core.lifetime import (
        after_interrupt,
        die_with_parent,
        note_interrupt,
        raise_after_import,
        redeliver_lost_interrupts,
    )

    die_with_parent(parent)
    redeliver_lost_interrupts()
    interrupted = []

    def on_sigint(signum, frame):
        signal.signal(signal.SIGINT, after_interrupt)  # one interrupt: the rollback runs to its end
        interrupted.append(signum)
        note_interrupt()  # no layer commits from now on, should the KeyboardInterrupt be lost
        if raise_after_import(frame):  # not inside a native module's init: raised once it is over
            return
        raise KeyboardInterrupt

    signal.signal(signal.SIGINT, on_sigint)  # it started ignoring SIGINT (_sigint_ignored)
    try:
        result = (True, Pipeline(case, out_dir, options).run_stage(registry.get(name)))
    except BaseException as exc:
        # an interrupted import can come out as another error (ImportError, a RoseError naming a
        # missing library): after an interrupt, whatever ended the stage is the interrupt
        if interrupted:  # the layer is rolled back; the parent says "interrupted"
            os._exit(130)
        if not isinstance(exc, RoseError):
            import traceback

            traceback.print_exc()
        result = (False, exc)
    if interrupted:  # after the layer's commit: it is kept, and the run stops here
        os._exit(130)
    try:
        payload = pickle.dumps(result)
        pickle.loads(payload)  # what the parent will rebuild
    except Exception as exc:  # an error that does not cross whole: its text
        error = result[1]
        text = error.one_line() if isinstance(error, RoseError) else f"{type(error).__name__}: {error}"
        payload = pickle.dumps(
            (False, (StageError if isinstance(error, RoseError) else RuntimeError)(f"{text} ({exc})"))
        )
    send.send_bytes(payload)
    send.close()


def _fresh_random_state() -> None:
    """OpenCV's global random generator (GrabCut's k-means draws from it) back to a fresh
    process's state (``setRNGSeed(0)`` is that state), so that a stage's result does not depend
    on what ran before it in the process: a batch or Ray worker runs case after case."""
    import cv2

    cv2.setRNGSeed(0)
