"""Perception modes: what a case gives the pipeline, derived from a generated (rgbd) case.

- ``rgbd``: RGB, sensor depth with realistic errors, cam_K.txt (the generated case itself);
- ``mono-imported``: RGB and the simulated outputs of MegaSaM, UniDepth, GeoCalib, SAM 2,
  FoundationPose and TRELLIS in their own formats under ``perception/``; no depth, no K;
- ``rgb``: frames only; with ``size_prior``, rose.toml also gives each object's ``size_m`` (its
  true largest extent, what a user who measured it would write).
All modes keep ``gt/`` and ``rose.toml`` (ground truth is read only by oracle backends and metrics).
"""

from __future__ import annotations

import enum
import os
import shutil
from pathlib import Path


class PerceptionMode(enum.Enum):
    RGBD = "rgbd"
    MONO_IMPORTED = "mono-imported"
    RGB = "rgb"


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
    base: Path, mode: PerceptionMode, out: Path, seed: int, *, prompts: bool = True, size_prior: bool = False
) -> Path:
    """Build the ``mode`` variant of generated case ``base`` at ``out`` (replaced if present);
    without ``prompts``, its rose.toml names the objects but points at none of them; with
    ``size_prior``, it gives each object's size_m."""
    tmp = out.with_name(f".{out.name}.partial")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    for name in _KEEP[mode]:
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
    (out / ".mode").write_text(mode_stamp(mode, prompts, size_prior))
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


def mode_stamp(mode: PerceptionMode, prompts: bool = True, size_prior: bool = False) -> str:
    """What a mode case was made by (its mode, prompts or not, the size prior, and the simulator's version)."""
    from rose_usd.synth.perception import PERCEPTION_VERSION

    return f"{mode.value}{'' if prompts else ' unprompted'}{' size-prior' if size_prior else ''} v{PERCEPTION_VERSION}"
