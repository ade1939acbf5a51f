"""Benchmark suites: which cases, at what size. Cases are deterministic in their spec."""

from __future__ import annotations

from dataclasses import dataclass

from rose_usd.errors import ConfigError
from rose_usd.synth.generate import GENERATOR_VERSION, GenerateConfig
from rose_usd.synth.motion import Task
from rose_usd.synth.shapes import ObjectShape

TASK_ORDER = (Task.UNSTACK, Task.PLACE, Task.LIFT, Task.PUSH, Task.ROTATE)
# the manipulated object's shape per task, for the first and second seed
_SHAPES = {
    Task.UNSTACK: (ObjectShape.CAN, ObjectShape.BOX),
    Task.PLACE: (ObjectShape.MUG, ObjectShape.CAN),
    Task.LIFT: (ObjectShape.CAN, ObjectShape.MUG),
    Task.PUSH: (ObjectShape.BOX, ObjectShape.MUG),
    Task.ROTATE: (ObjectShape.MUG, ObjectShape.BOX),
}


@dataclass(frozen=True)
class CaseSpec:
    task: Task
    shape: ObjectShape
    seed: int
    n_frames: int
    width: int
    height: int
    spp: int

    @property
    def name(self) -> str:
        return f"{self.task.value}-{self.shape.value}-s{self.seed}"

    def generate_config(self) -> GenerateConfig:
        return GenerateConfig(
            task=self.task,
            shape=self.shape,
            seed=self.seed,
            n_frames=self.n_frames,
            width=self.width,
            height=self.height,
            spp=self.spp,
        )

    def matches(self, generator: dict, n_frames: int, width: int, height: int) -> bool:
        """Whether a generated case's recorded generator settings are this spec's."""
        return (
            generator.get("version") == GENERATOR_VERSION
            and generator.get("task") == self.task.value
            and generator.get("shape") == self.shape.value
            and generator.get("seed") == self.seed
            and generator.get("spp") == self.spp
            and (n_frames, width, height) == (self.n_frames, self.width, self.height)
        )


def _default() -> tuple[CaseSpec, ...]:
    specs = []
    for ti, task in enumerate(TASK_ORDER):
        for k in range(2):
            seed = 100 * (k + 1) + ti
            specs.append(
                CaseSpec(task, _SHAPES[task][k], seed, n_frames=150 + (seed * 37) % 61, width=640, height=480, spp=8)
            )
    return tuple(specs)


def _small() -> tuple[CaseSpec, ...]:
    return tuple(
        CaseSpec(task, _SHAPES[task][0], 10 + ti, n_frames=24, width=160, height=120, spp=16)
        for ti, task in enumerate(TASK_ORDER)
    )


SUITES: dict[str, tuple[CaseSpec, ...]] = {"default": _default(), "small": _small()}


def get_suite(name: str) -> tuple[CaseSpec, ...]:
    if name not in SUITES:
        raise ConfigError(f"unknown suite {name!r}", hint=f"suites: {', '.join(SUITES)}")
    return SUITES[name]
