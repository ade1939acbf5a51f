"""Running stages: configs from defaults, rose.toml and the command line; make-like skipping of
stages whose config and inputs are unchanged; provenance for every layer."""

from __future__ import annotations

import hashlib
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

from rose_usd import registry
from rose_usd.case.layout import Case, load_case
from rose_usd.errors import ConfigError, StageError
from rose_usd.progress import say
from rose_usd.stage_api import (
    StageContext,
    StageDef,
    build_config,
    config_hash,
    config_to_dict,
)
from rose_usd.usd import stage as usd_stage

_hash_cache: dict[tuple[str, int, int], str] = {}


def _cached_file_hash(path: Path) -> str:
    st = path.stat()
    key = (str(path.resolve()), st.st_size, st.st_mtime_ns)
    if key not in _hash_cache:
        _hash_cache[key] = usd_stage.file_hash(path)
    return _hash_cache[key]


def _files_hash(files: list[Path], root: Path) -> str:
    h = hashlib.sha256()
    for f in sorted(files):
        h.update(str(f.relative_to(root) if f.is_relative_to(root) else f).encode())
        h.update(_cached_file_hash(f).encode())
    return h.hexdigest()[:16]


@dataclass
class Options:
    """What the user chose on the command line (strongest) on top of rose.toml and defaults."""

    backends: Mapping[str, str] = field(default_factory=dict)
    """stage -> backend; key ``all`` applies to every stage that has that backend."""
    settings: Mapping[str, Mapping[str, object]] = field(default_factory=dict)
    """stage -> {field: value}."""
    force: bool = False
    """Re-run stages even when they are up to date."""


@dataclass(frozen=True)
class StageOutcome:
    name: str
    ran: bool
    wall_time_s: float
    backend: str


class Pipeline:
    """The stages of one case writing into one output folder."""

    def __init__(self, case: Case | str | Path, out_dir: str | Path, options: Options | None = None):
        self.case = case if isinstance(case, Case) else load_case(case, registry.STAGE_NAMES)
        self.out_dir = Path(out_dir)
        self.options = options or Options()
        for stage in list(self.options.backends) + list(self.options.settings):
            if stage != "all":
                registry.get(stage)
        self.time_info = usd_stage.TimeInfo(fps=self.case.fps, n_frames=self.case.n_frames)

    # ------------------------------------------------------------------ config
    def config(self, stage_def: StageDef):
        case_cfg = self.case.config
        values: dict[str, object] = dict(case_cfg.stage_overrides.get(stage_def.name, {}))
        source = str(self.case.folder / "rose.toml")
        backend = self.options.backends.get(stage_def.name) or case_cfg.backends.get(stage_def.name)
        if backend is None and "all" in self.options.backends and self.options.backends["all"] in stage_def.backends:
            backend = self.options.backends["all"]
        if backend is not None:
            if backend not in stage_def.backends and not (backend == "auto" and stage_def.auto_backend):
                raise ConfigError(
                    f"stage {stage_def.name!r} has no backend {backend!r}",
                    hint=f"backends of {stage_def.name}: {', '.join(stage_def.backends)}"
                    + (", auto" if stage_def.auto_backend else ""),
                )
            values["backend"] = backend
        values.update(self.options.settings.get(stage_def.name, {}))
        config = build_config(stage_def, values, source=source)
        if config.backend.value == "auto":
            # the layer records the backend that ran, never "auto"
            config = build_config(stage_def, {**values, "backend": stage_def.resolve_auto(self.case)}, source=source)
        return config

    # ------------------------------------------------------------------ staleness
    def input_hashes(self, stage_def: StageDef, config) -> dict[str, str]:
        inputs = {"case": _files_hash(self.case.input_files(), self.case.folder)}
        if config.backend.value == "oracle" or stage_def.name == "gate":
            gt_dir = self.case.folder / "gt"
            if gt_dir.is_dir():
                inputs["gt"] = _files_hash([p for p in gt_dir.rglob("*") if p.is_file()], self.case.folder)
        for need in stage_def.needs_of(config.backend.value):
            layer = usd_stage.layer_file(self.out_dir, registry.get(need).layer)
            inputs[f"layer:{registry.get(need).layer}"] = _cached_file_hash(layer) if layer.is_file() else "missing"
        return inputs

    def is_current(self, stage_def: StageDef) -> bool:
        """Whether the stage's layer exists and was made from the same config and inputs."""
        prov = usd_stage.read_provenance(usd_stage.layer_file(self.out_dir, stage_def.layer))
        if prov is None:
            return False
        config = self.config(stage_def)
        time_info = usd_stage.read_time_info(self.out_dir)
        return (
            prov.get("config_hash") == config_hash(config)
            and prov.get("inputs") == self.input_hashes(stage_def, config)
            and time_info == self.time_info
        )

    # ------------------------------------------------------------------ running
    def run_stage(self, stage_def: StageDef) -> StageOutcome:
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
            "inputs": self.input_hashes(stage_def, config),
            "case": str(self.case.root.resolve()),
        }
        func = stage_def.backend_function(config.backend.value)
        say(f"[{stage_def.name}] backend {config.backend.value}")
        writer = usd_stage.LayerWriter(self.out_dir, stage_def.layer, self.time_info, provenance)
        with writer:
            func(StageContext(stage_def, config, self.case, self.out_dir, self.time_info, writer))
        wall = float(writer.provenance["wall_time_s"])
        say(f"[{stage_def.name}] wrote {usd_stage.layer_file(self.out_dir, stage_def.layer)} in {wall:.1f} s")
        return StageOutcome(stage_def.name, True, wall, config.backend.value)

    def run(self, target: str | None = None) -> list[StageOutcome]:
        """Run ``target`` (or every stage) and whatever it needs that is missing or stale."""
        stages = registry.closure(target, lambda s: self.config(s).backend.value) if target else list(registry.STAGES)
        for stage_def in stages:  # every config is checked before any stage runs
            self.config(stage_def)
        outcomes = []
        for stage_def in stages:
            must = self.options.force and (target is None or stage_def.name == target)
            # is_current compares the upstream layers' hashes, so a re-run upstream stage makes
            # exactly its dependents stale
            if must or not self.is_current(stage_def):
                outcomes.append(self.run_stage(stage_def))
            else:
                prov = usd_stage.read_provenance(usd_stage.layer_file(self.out_dir, stage_def.layer)) or {}
                say(f"[{stage_def.name}] up to date")
                outcomes.append(StageOutcome(stage_def.name, False, 0.0, str(prov.get("backend", ""))))
        if not usd_stage.root_file(self.out_dir).is_file():
            usd_stage.write_root(self.out_dir, self.time_info)
        return outcomes
