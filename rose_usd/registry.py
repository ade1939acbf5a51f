"""The one table of pipeline stages, in run order. The CLI, the docs and the tests iterate it."""

from __future__ import annotations

from collections.abc import Callable

from rose_usd import capture, collect, gate, scene, segment, trajectory
from rose_usd import object as object_stage
from rose_usd.stage_api import StageDef

STAGES: tuple[StageDef, ...] = (
    capture.STAGE,
    segment.STAGE,
    scene.STAGE,
    object_stage.STAGE,
    trajectory.STAGE,
    gate.STAGE,
    collect.STAGE,
)
STAGE_NAMES: tuple[str, ...] = tuple(s.name for s in STAGES)
BY_NAME: dict[str, StageDef] = {s.name: s for s in STAGES}


def get(name: str) -> StageDef:
    from rose_usd.errors import ConfigError

    if name not in BY_NAME:
        raise ConfigError(f"unknown stage {name!r}", hint=f"stages: {', '.join(STAGE_NAMES)}")
    return BY_NAME[name]


def closure(name: str, backend_of: Callable[[StageDef], str] | None = None) -> list[StageDef]:
    """``name`` and every stage it needs, transitively, in run order (by the backends
    ``backend_of`` picks, when given: a backend may need less than its stage usually does)."""
    wanted = {get(name).name}
    for stage in reversed(STAGES):
        if stage.name in wanted:
            wanted.update(stage.needs_of(backend_of(stage)) if backend_of else stage.needs)
    return [s for s in STAGES if s.name in wanted]
