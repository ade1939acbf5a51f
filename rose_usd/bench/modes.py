"""Perception modes: what a case gives the pipeline, derived from a generated (rgbd) case.

- ``rgbd``: RGB, sensor depth with realistic errors, cam_K.txt (the generated case itself);
- ``mono-imported``: RGB and the simulated outputs of MegaSaM, UniDepth, GeoCalib, SAM 2,
  FoundationPose and TRELLIS in their own formats under ``perception/``; no depth, no K;
- ``rgb``: frames only.
All modes keep ``gt/`` and ``rose.toml`` (ground truth is read only by oracle backends and metrics).
``ModeOptions`` change what a mode case gives: no prompts; each object's ``size_m`` in rose.toml
(its true largest extent, what a user who measured it would write); the camera's ``cam_K.txt``
(the intrinsics a user who calibrated the camera, or read them from its maker, would give).
"""

from __future__ import annotations

import enum
import os
import shutil
from dataclasses import dataclass
from pathlib import Path


class PerceptionMode(enum.Enum):
    RGBD = "rgbd"
    MONO_IMPORTED = "mono-imported"
    RGB = "rgb"


@dataclass(frozen=True)
class ModeOptions:
    """What a mode case changes in its mode's layout: ``prompts`` (false: rose.toml names the
    objects but points at none), ``size_prior`` (rose.toml gives each object's size_m) and
    ``intrinsics`` (cam_K.txt is kept where the mode drops it)."""

    prompts: bool = True
    size_prior: bool = False
    intrinsics: bool = False

    @classmethod
    def of(cls, summary: dict) -> "ModeOptions":
        """The options a results summary (``rose-usd bench run``'s results.json) was run with."""
        return cls(summary.get("prompts", True), summary.get("size_prior", False), summary.get("intrinsics", False))

    def folder(self, mode: "PerceptionMode") -> str:
        """The mode case's folder name beside the generated case (``base``)."""
        return (
            mode.value
            + ("" if self.prompts else "-unprompted")
            + ("-size" if self.size_prior else "")
            + ("-K" if self.adds_intrinsics(mode) else "")
        )

    def adds_intrinsics(self, mode: "PerceptionMode") -> bool:
        """Whether the options keep cam_K.txt where ``mode`` drops it."""
        return self.intrinsics and "cam_K.txt" not in _KEEP[mode]

    def keeps(self, mode: "PerceptionMode") -> tuple[str, ...]:
        """The generated case's files and folders that the mode case holds."""
        return _KEEP[mode] + (("cam_K.txt",) if self.adds_intrinsics(mode) else ())


_KEEP = {
    PerceptionMode.RGBD: ("rgb", "depth", "cam_K.txt", "rose.toml", "gt"),
    PerceptionMode.MONO_IMPORTED: ("rgb", "rose.toml", "gt"),
    PerceptionMode.RGB: ("rgb", "rose.toml", "gt"),
}


def _link_tree(src: Path, dst: Path) -> None:
    """Hard-link a file or folder tree (copy where links are not possible)."""
    if src.is_dir():
        dst.mkdir(parents=True, exist_ok=True)
        for child in src.iterdir():
            _link_tree(child, dst / child.name)
    else:
        try:
            os.link(src, dst)
        except OSError:
            shutil.copy2(src, dst)


def make_mode_case(
    base: Path, mode: PerceptionMode, out: Path, seed: int, options: ModeOptions = ModeOptions()
) -> Path:
    """Build the ``mode`` variant of generated case ``base`` at ``out`` (replaced if present),
    changed as ``options`` say."""
    prompts, size_prior = options.prompts, options.size_prior
    tmp = out.with_name(f".{out.name}.partial")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    for name in options.keeps(mode):
        if (base / name).exists():
            _link_tree(base / name, tmp / name)
    if mode is PerceptionMode.MONO_IMPORTED:
        from rose_usd.synth.perception import write_mono_imported

        write_mono_imported(tmp, seed)
    if not prompts or size_prior:
        toml = tmp / "rose.toml"
        lines = [line for line in toml.read_text().splitlines() if prompts or not line.startswith("prompt = ")]
        if size_prior:
            lines = _with_sizes(lines, base / "gt" / "scene.json")
        toml.unlink()  # a hard link to the generated case's file: replace, never edit
        toml.write_text("\n".join(lines) + "\n")
    shutil.rmtree(out, ignore_errors=True)
    tmp.rename(out)
    (out / ".mode").write_text(mode_stamp(mode, options))
    return out


def _with_sizes(lines: list[str], scene_json: Path) -> list[str]:
    """rose.toml's lines with ``size_m`` (the object's largest true extent) after each object's name."""
    import json

    sizes = {o["name"]: max(o["size_m"]) for o in json.loads(scene_json.read_text())["objects"]}
    out = []
    for line in lines:
        out.append(line)
        if line.startswith("name = "):
            name = line.split("=", 1)[1].strip().strip('"')
            if name in sizes:
                out.append(f"size_m = {sizes[name]:.5f}")
    return out


def mode_stamp(mode: PerceptionMode, options: ModeOptions = ModeOptions()) -> str:
    """What a mode case was made by (its mode, its options, and the simulator's version)."""
    from rose_usd.synth.perception import PERCEPTION_VERSION

    extra = (
        ("" if options.prompts else " unprompted")
        + (" size-prior" if options.size_prior else "")
        + (" intrinsics" if options.adds_intrinsics(mode) else "")
    )
    return f"{mode.value}{extra} v{PERCEPTION_VERSION}"
