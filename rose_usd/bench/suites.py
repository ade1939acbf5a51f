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
    realistic: bool = False
    static_camera: bool = False
    lying: bool = False

    @property
    def name(self) -> str:
        extra = ("-lying" if self.lying else "") + ("-static" if self.static_camera else "")
        return f"{self.task.value}-{self.shape.value}{extra}-s{self.seed}"

    def generate_config(self) -> GenerateConfig:
        return GenerateConfig(
            task=self.task,
            shape=self.shape,
            seed=self.seed,
            n_frames=self.n_frames,
            width=self.width,
            height=self.height,
            spp=self.spp,
            realistic=self.realistic,
            static_camera=self.static_camera,
            lying=self.lying,
        )

    def matches(self, generator: dict, n_frames: int, width: int, height: int) -> bool:
        """Whether a generated case's recorded generator settings are this spec's."""
        return (
            generator.get("version") == GENERATOR_VERSION
            and generator.get("task") == self.task.value
            and generator.get("shape") == self.shape.value
            and generator.get("seed") == self.seed
            and generator.get("spp") == self.spp
            and generator.get("realistic", False) == self.realistic
            and generator.get("static_camera", False) == self.static_camera
            and generator.get("lying", False) == self.lying
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


def _realistic() -> tuple[CaseSpec, ...]:
    """As hard as a real video: a skin-toned hand whose fingers wrap and hide the object, printed
    and speckled objects on a cloth, same-colored clutter, lying objects, static and hand-held
    cameras (rose_usd.synth.generate, ``realistic``)."""
    layout = {  # task: (shape, static camera, lying)
        Task.UNSTACK: (ObjectShape.CAN, False, False),
        Task.PLACE: (ObjectShape.MUG, True, True),
        Task.LIFT: (ObjectShape.CAN, False, True),
        Task.PUSH: (ObjectShape.BOX, True, False),
        Task.ROTATE: (ObjectShape.MUG, False, False),
    }
    return tuple(
        CaseSpec(
            task, shape, 300 + ti, n_frames=64, width=480, height=360, spp=8, realistic=True, static_camera=st, lying=ly
        )
        for ti, (task, (shape, st, ly)) in enumerate(layout.items())
    )


SUITES: dict[str, tuple[CaseSpec, ...]] = {"default": _default(), "small": _small(), "realistic": _realistic()}


def get_suite(name: str) -> tuple[CaseSpec, ...]:
    if name not in SUITES:
        raise ConfigError(f"unknown suite {name!r}", hint=f"suites: {', '.join(SUITES)}")
    return SUITES[name]


def select_cases(specs: tuple[CaseSpec, ...], only: tuple[str, ...]) -> tuple[CaseSpec, ...]:
    """The cases of ``specs`` named in ``only`` by case name (``push-box-s13``) or task (``push``);
    all of them when ``only`` is empty."""
    unknown = [n for n in only if not any(n in (s.name, s.task.value) for s in specs)]
    if unknown:
        raise ConfigError(
            f"no case or task {', '.join(map(repr, unknown))} in this suite",
            hint=f"its cases: {', '.join(s.name for s in specs)}",
        )
    return tuple(s for s in specs if not only or s.name in only or s.task.value in only)
