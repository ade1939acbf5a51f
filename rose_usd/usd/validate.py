"""Validation of a written stage: every pxr.UsdValidation validator, and a load through Newton."""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

from pxr import Usd, UsdValidation

from rose_usd.errors import ValidationError
from rose_usd.usd import stage as stage_mod


@dataclass
class ValidationReport:
    """What validation found. ``errors`` empty means valid."""

    path: str
    validators: int = 0
    errors: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    newton: dict | None = None

    @property
    def ok(self) -> bool:
        return not self.errors

    def raise_if_invalid(self) -> None:
        if self.errors:
            raise ValidationError(
                f"{len(self.errors)} validation error(s), first: {self.errors[0]}",
                path=self.path,
                hint="run `rose-usd inspect` on it, and re-run the stage that wrote the offending prim",
            )


def usd_validation(stage: Usd.Stage) -> tuple[int, list[str], list[str]]:
    """Run all registered UsdValidation validators. Returns (count, errors, warnings)."""
    validators = UsdValidation.ValidationRegistry().GetOrLoadAllValidators()
    found = UsdValidation.ValidationContext(validators).Validate(stage)
    errors, warnings = [], []
    for item in found:
        if item.HasNoError():
            continue
        sites = ", ".join(
            str(site.GetPrim().GetPath()) if site.IsPrim() else str(site.GetLayer().identifier)
            for site in item.GetSites()
        )
        text = f"{item.GetValidator().GetMetadata().name}: {item.GetMessage()}" + (f" [{sites}]" if sites else "")
        (errors if item.GetType() == UsdValidation.ValidationErrorType.Error else warnings).append(text)
    return len(validators), errors, warnings


def newton_load(path: str | os.PathLike) -> dict:
    """Load a stage with Newton's ``ModelBuilder.add_usd``; returns counts of what it built."""
    from rose_usd.sim.engine import newton as load_newton  # heavy: imported only here

    builder = load_newton().ModelBuilder()
    result = builder.add_usd(str(path))
    return {
        "bodies": int(builder.body_count),
        "shapes": int(builder.shape_count),
        "gravity": [float(v) for v in builder.gravity],
        "path_body_map": {str(k): int(v) for k, v in dict(result.get("path_body_map", {})).items()},
    }


def validate(path: str | os.PathLike, *, with_newton: bool = True) -> ValidationReport:
    """Validate a stage file: composition, all UsdValidation validators, and (optionally) Newton."""
    path = Path(path)
    report = ValidationReport(path=str(path))
    stage = stage_mod.open_stage(path)  # composition errors raise
    report.validators, report.errors, report.warnings = usd_validation(stage)
    if path.name == stage_mod.paths.ROOT_FILE:
        # an output folder: its layers must have been made from one another and from one case
        report.errors[:0] = stage_mod.consistency_problems(path.parent)
    if with_newton:
        try:
            report.newton = newton_load(path)
        except Exception as exc:  # Newton raises many types; any failure to load is a validation error
            report.errors.append(f"newton add_usd: {type(exc).__name__}: {exc}")
    return report
