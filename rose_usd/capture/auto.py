"""The capture backend ``auto`` resolves to, by what the case holds."""

from __future__ import annotations

from rose_usd.case.layout import Case
from rose_usd.errors import InputError


def choose(case: Case) -> str:
    if case.has_depth:
        return "rgbd"
    if any((case.folder / "perception").glob("*_sgd_cvd_hr.npz")) or any(
        (case.folder / "perception").glob("*_droid.npz")
    ):
        return "megasam"
    if (case.folder / "gt" / "scene.json").is_file():
        return "oracle"
    raise InputError(
        "no capture backend fits this case: it has no depth/, no MegaSaM output and no ground truth",
        path=case.folder,
        hint="add depth maps (rgbd) or perception/<scene>_sgd_cvd_hr.npz from MegaSaM",
    )
