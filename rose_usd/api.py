"""The Python API: :func:`reconstruct` a case into a stage, and what it returns."""

from __future__ import annotations

import functools
import os
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pxr import Usd

from rose_usd.layers.gate import GateResult, read_gate
from rose_usd.layers.objects import describe, object_paths
from rose_usd.layers.robot import CollectResult, read_collect
from rose_usd.layers.world import read_scale
from rose_usd.pipeline import BackendChoice, Options, Pipeline, StageOutcome
from rose_usd.usd import stage as usd_stage
from rose_usd.usd.validate import ValidationReport


@dataclass
class Reconstruction:
    """What :func:`reconstruct` did, and where the stage is."""

    case: Path
    out_dir: Path
    plan: dict[str, str]
    """stage -> the backend that ran it (``auto`` resolved), in run order; ``planned->built``
    where it built another backend's layer (``stereo->plane``: a camera too still for stereo)."""
    outcomes: list[StageOutcome]
    """Per stage: ``ran``, ``skipped``, ``failed`` or ``not run``, its wall time and backend."""
    wall_time_s: float
    gate: GateResult | None = None
    """The quality gate's results, None when the gate has not run."""
    collect: CollectResult | None = None
    """The robot demonstrations' results, None when the collect stage has not run."""
    validation: ValidationReport | None = None
    """UsdValidation and Newton's ``add_usd`` on the composed stage, None when not asked for."""
    error: str | None = field(default=None)
    """The one-line message of the stage that failed (only with ``check=False``)."""

    @property
    def ok(self) -> bool:
        """No stage failed, the stage is valid (when validated) and the gate passed (when it ran)."""
        return (
            self.error is None
            and (self.validation is None or self.validation.ok)
            and (self.gate is None or self.gate.passed)
        )

    @property
    def path(self) -> Path:
        """The root layer, ``<out>/rose.usda``."""
        return usd_stage.root_file(self.out_dir)

    @functools.cached_property
    def stage(self) -> Usd.Stage:
        """The composed stage (every layer written so far)."""
        return usd_stage.open_stage(self.path)

    def summary(self) -> str:
        """Per stage one line, then the gate's and validation's."""
        lines = [
            f"  {o.name:<11} {o.backend:<15} {o.status:<8} {o.wall_time_s:7.1f} s" + (f"  {o.error}" if o.error else "")
            for o in self.outcomes
        ]
        names = list(object_paths(self.stage))
        if names:
            scale = read_scale(self.stage)  # a prior's (RGB only) is uncertain: say which
            how = f"; metric scale from {scale.source} (+-{100 * scale.uncertainty:.0f} %)" if scale.uncertainty else ""
            lines.append(f"objects: {'; '.join(describe(self.stage, n) for n in names)}{how}")
        if self.gate is not None:
            lines.append(self.gate.summary())
        if self.collect is not None:
            lines.append(self.collect.summary())
        if self.validation is not None:
            newton = self.validation.newton or {}
            bodies = newton.get("bodies", "?")
            lines.append(
                f"validation: {self.validation.validators} UsdValidation validators, {len(self.validation.errors)} "
                f"error(s), {len(self.validation.warnings)} warning(s); Newton add_usd: {bodies} "
                f"{'body' if bodies == 1 else 'bodies'}, {newton.get('shapes', '?')} shapes"
            )
        return "\n".join(lines)


def reconstruct(
    case: str | os.PathLike,
    out: str | os.PathLike,
    *,
    backends: Mapping[str, BackendChoice] | None = None,
    settings: Mapping[str, Mapping[str, Any]] | None = None,
    until: str | None = None,
    force: bool = False,
    validate: bool = True,
    check: bool = True,
    options: Mapping[str, Any] | None = None,
) -> Reconstruction:
    """Reconstruct a case (a folder or a video file) into ``out/rose.usda``.

    Every stage runs its ``auto`` backend unless ``backends`` names one; the plan and what each
    chosen backend needs are checked before anything is written. Stages whose layer in ``out`` is
    current (same config, inputs and code) are skipped.

    Args:
        case: the case folder or video file.
        out: the output folder.
        backends: stage -> backend name (``"fusion"``), the stage's backend enum member
            (``ObjectBackend.FUSION``) or a config instance (``ObjectConfig(backend=..., voxel_m=...)``,
            the stage's whole config); ``{"all": "oracle"}`` sets every stage that has it.
        settings: stage -> {setting: value}, as ``--set stage.setting=value``.
        until: run only this stage and the stages it needs.
        force: re-run the stages even when their layers are current (with ``until``, that stage only).
        validate: run every UsdValidation validator and Newton's ``add_usd`` on the result.
        check: raise the error of a failing stage; with False it is recorded in the result.
        options: further :class:`rose_usd.pipeline.Options` fields (``settings_source``,
            ``prompt_source``: what errors name as the source of ``settings``; the CLI's flags).

    Returns:
        A :class:`Reconstruction`: the plan, each stage's outcome, the gate's results, the
        validation report and the composed stage.

    Raises:
        RoseError: bad input or options (always, before anything is written), or a failing stage
            (with ``check``).
    """
    t0 = time.perf_counter()
    pipe = Pipeline(
        case,
        out,
        Options(backends=dict(backends or {}), settings=dict(settings or {}), force=force, **dict(options or {})),
    )
    outcomes = pipe.run(until, check=check)
    result = Reconstruction(
        case=Path(case),
        out_dir=Path(out),
        plan={o.name: o.backend for o in outcomes},
        outcomes=outcomes,
        wall_time_s=time.perf_counter() - t0,
        error=next((o.error for o in outcomes if o.status == "failed"), None),
    )
    if result.path.is_file():
        result.gate = read_gate(result.stage)
        result.collect = read_collect(result.stage)
        if validate and result.error is None:
            from rose_usd.usd.validate import validate as validate_stage

            result.validation = validate_stage(result.path)
            if check:
                result.validation.raise_if_invalid()
    return result
