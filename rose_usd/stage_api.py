"""What a pipeline stage is: a definition (name, layer, upstream stages, config class, backends)
and the context a backend runs in. Stages register in :mod:`rose_usd.registry`."""

from __future__ import annotations

import ast
import contextlib
import functools
import hashlib
import importlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pxr import Usd

from rose_usd.case.layout import Case
from rose_usd.usd.stage import LayerWriter, TimeInfo


@dataclass(frozen=True)
class StageDef:
    """A pipeline stage."""

    name: str
    """CLI and config name, e.g. ``capture``."""
    layer: str
    """The layer it owns, e.g. ``world`` (layers/world.usda)."""
    needs: tuple[str, ...]
    """Stages whose layers it reads."""
    config: type
    """Frozen dataclass; its ``backend`` field is an enum of this stage's backends."""
    backends: Mapping[str, str]
    """backend name -> ``module:function`` taking a StageContext."""
    summary: str
    """One line for the CLI help and the docs."""
    side_dirs: tuple[str, ...] = ()
    """Folders of ``<out>`` this stage writes besides its layer (e.g. ``masks``)."""
    needs_by_backend: Mapping[str, tuple[str, ...]] = field(default_factory=dict)
    """Backends that need other stages than ``needs`` (e.g. a segment backend that works on RGB alone)."""
    requires: Mapping[str, tuple[str, ...]] = field(default_factory=dict)
    """backend name -> what it requires of the case (names in :data:`rose_usd.plan.REQUIREMENTS`),
    checked before any stage runs."""

    def needs_of(self, backend: str) -> tuple[str, ...]:
        """The stages this stage needs when ``backend`` runs it."""
        return self.needs_by_backend.get(backend, self.needs)

    def requires_of(self, backend: str) -> tuple[str, ...]:
        return tuple(self.requires.get(backend, ()))

    def backend_function(self, backend: str) -> Callable[["StageContext"], None]:
        return _resolve(self.backends[backend])


def _resolve(target: str):
    module, func = target.split(":")
    return getattr(importlib.import_module(module), func)


# ----------------------------------------------------------------------------- code version
_PACKAGE_DIR = Path(__file__).resolve().parent


def _module_file(module: str) -> Path | None:
    """The source file of a ``rose_usd`` module or package, None for anything else."""
    parts = module.split(".")
    if parts[0] != "rose_usd":
        return None
    base = _PACKAGE_DIR.joinpath(*parts[1:])
    for candidate in (base.with_suffix(".py"), base / "__init__.py"):
        if candidate.is_file():
            return candidate
    return None


def _imported_modules(path: Path, module: str) -> set[str]:
    """Every module an import statement of the file names (function-local ones included), with
    ``from a import b`` giving ``a`` and ``a.b`` (b may be a submodule)."""
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_bytes(), filename=str(path))):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join(anchor + ([base] if base else []))
            found.add(base)
            found.update(f"{base}.{alias.name}" for alias in node.names)
    return found


@functools.cache
def source_files(module: str) -> tuple[Path, ...]:
    """The rose_usd source files that running ``module`` executes: the module, its packages'
    ``__init__``, and what they import from rose_usd, transitively (read from the source, not by
    importing it)."""
    seen: dict[str, Path] = {}
    todo = [module]
    while todo:
        name = todo.pop()
        parts = name.split(".")
        for i in range(1, len(parts) + 1):  # the packages above it run first
            prefix = ".".join(parts[:i])
            path = _module_file(prefix)
            if path is not None and prefix not in seen:
                seen[prefix] = path
                todo.extend(_imported_modules(path, prefix))
    return tuple(sorted(set(seen.values())))


def code_version(stage_def: StageDef, backend: str) -> str:
    """The package version and a hash of every source file the backend runs: a layer made by other
    code is stale."""
    from rose_usd import __version__

    h = hashlib.sha256()
    module = stage_def.backends[backend].split(":")[0]
    for path in source_files(module):
        h.update(path.relative_to(_PACKAGE_DIR).as_posix().encode())
        h.update(hashlib.sha256(path.read_bytes()).digest())
    return f"{__version__}+{h.hexdigest()[:16]}"


@dataclass
class StageContext:
    """Everything a backend gets. Author only into ``stage`` (its edit target is the stage's own
    layer) and into folders from ``side_dir``; read inputs from ``case`` and the composed ``stage``."""

    stage_def: StageDef
    config: Any
    case: Case
    out_dir: Path
    time_info: TimeInfo
    writer: LayerWriter
    _deferred: list[str] | None = field(default=None, repr=False)

    @property
    def stage(self) -> Usd.Stage:
        return self.writer.stage

    @property
    def layer_dir(self) -> Path:
        """Folder of the layer being written (relative asset paths are anchored here)."""
        return self.out_dir / "layers"

    def side_dir(self, name: str) -> Path:
        if name not in self.stage_def.side_dirs:
            raise ValueError(f"stage {self.stage_def.name!r} did not declare side folder {name!r}")
        return self.writer.side_dir(name)

    @contextlib.contextmanager
    def deferred_warnings(self):
        """Warnings given inside are collected in the list this yields, neither printed nor kept:
        for work that may be thrown away (the caller ``warn``s the ones of the work it keeps)."""
        outer, self._deferred = self._deferred, []
        try:
            yield self._deferred
        finally:
            self._deferred = outer

    def record(self, **values: Any) -> None:
        """Add entries to the layer's provenance (e.g. fit residuals, timings, warnings)."""
        self.writer.provenance.setdefault("results", {}).update(values)

    def built_as(self, backend: str) -> None:
        """The layer is another backend's work (the planned one found it could not do better:
        stereo without parallax builds plane's scene); run summaries and ``inspect`` show both."""
        self.writer.provenance["built_as"] = backend

    def warn(self, message: str) -> None:
        """A warning the user should see: printed and kept in the layer's provenance (inside
        ``deferred_warnings``: only collected)."""
        from rose_usd.progress import say

        if self._deferred is not None:
            self._deferred.append(message)
            return

        self.writer.provenance.setdefault("warnings", []).append(message)
        say(f"warning: {self.stage_def.name}: {message}")
