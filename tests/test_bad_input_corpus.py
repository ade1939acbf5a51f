"""The bad-input corpus (issue 25): every case a new user may meet, made from the sample in a
temporary folder, gets exit status 1, one line on stderr naming the offending file (or flag), and
leaves an earlier good output folder byte for byte as it was.

Each case is (id, class, mutate, needles): ``mutate(ctx)`` breaks a copy of the sample (or the
output) and returns the command line; the error line must contain every needle and none of the
``forbidden`` substrings. ``ROSE_CORPUS_LOG=FILE`` appends each case's outcome (``clean``,
``late``, ``wrong file``, ``traceback``, ``garbage pass``, ``vague``) to FILE as JSON lines, which
is how the counts before and after the fixes were taken.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import pytest
from conftest import made_from
from PIL import Image

from rose_usd.cli import main

N = 48  # frames of the sample


# ----------------------------------------------------------------------------- helpers
@dataclass
class Ctx:
    case: Path
    out: Path
    tmp: Path
    env: dict = field(default_factory=dict)
    watch: list = field(default_factory=list)
    """Extra files or folders that must come through unchanged."""


def tree_hash(root: Path) -> dict[str, str]:
    root = Path(root)
    if root.is_file():
        return {root.name: hashlib.sha256(root.read_bytes()).hexdigest()}
    if not root.exists():
        return {}
    return {
        str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(root.rglob("*"))
        if p.is_file()
    }


def capture(ctx, *extra):
    return ["run", "capture", str(ctx.case), "-o", str(ctx.out), *extra]


def segment(ctx, *extra):
    """Up to the segment stage: capture would write its layer first, were a check of the prompts late."""
    return ["run", "segment", str(ctx.case), "-o", str(ctx.out), *extra]


def toml(ctx, text: str, *, keep_object: bool = False) -> None:
    base = 'fps = 30\n[[objects]]\nname = "Box"\ncategory = "box"\nprompt = { frame = 0, box = [174, 90, 208, 127] }\n'
    (ctx.case / "rose.toml").write_text((base if keep_object else "") + text)


def obj_toml(ctx, extra: str) -> None:
    """The sample's object with extra keys."""
    toml(ctx, extra + "\n", keep_object=True)


def write_K(ctx, text: str, name: str = "cam_K.txt") -> None:
    (ctx.case / name).write_text(text)


def K_rows(fx=252.5, fy=252.5, cx=160.6, cy=118.0) -> str:
    return f"{fx!r} 0 {cx!r}\n0 {fy!r} {cy!r}\n0 0 1\n"


def depth_frames(ctx) -> list[Path]:
    return sorted((ctx.case / "depth").glob("*.png"))


def zero_depth(ctx, frames) -> None:
    for t in frames:
        cv2.imwrite(str(ctx.case / "depth" / f"{t:06d}.png"), np.zeros((240, 320), np.uint16))


def npy_depth(ctx, value: float) -> None:
    shutil.rmtree(ctx.case / "depth")
    (ctx.case / "depth").mkdir()
    for t in range(N):
        np.save(ctx.case / "depth" / f"{t:06d}.npy", np.full((240, 320), value, np.float32))


def video(ctx, name: str = "video.avi", keep_depth: bool = False, fraction: float = 1.0) -> Path:
    frames = sorted((ctx.case / "rgb").glob("*.png"))
    path = ctx.case / name
    fourcc = cv2.VideoWriter_fourcc(*("MJPG" if name.endswith(".avi") else "mp4v"))
    writer = cv2.VideoWriter(str(path), fourcc, 30, (320, 240))
    for f in frames:
        writer.write(cv2.imread(str(f)))
    writer.release()
    if fraction < 1.0:
        data = path.read_bytes()
        path.write_bytes(data[: int(len(data) * fraction)])
    shutil.rmtree(ctx.case / "rgb")
    if not keep_depth:
        shutil.rmtree(ctx.case / "depth")
    return path


def poses(ctx, bad_text: str | None = None, frame: int = 7) -> list[str]:
    """FoundationPose's ob_in_cam/ (a valid pose per frame, frame ``frame`` replaced by ``bad_text``),
    and the command that reads it."""
    folder = ctx.case / "perception" / "ob_in_cam"
    folder.mkdir(parents=True)
    pose = np.eye(4)
    pose[:3, 3] = [0.0, 0.0, 0.6]
    for t in range(N):
        np.savetxt(folder / f"{t:06d}.txt", pose)
    if bad_text is not None:
        (folder / f"{frame:06d}.txt").write_text(bad_text)
    return [
        "reconstruct",
        str(ctx.case),
        "-o",
        str(ctx.out),
        "--backend",
        "all=oracle",
        "--backend",
        "trajectory=foundationpose",
        "--no-validate",
    ]


def megasam(ctx, **changes) -> list[str]:
    """MegaSaM's npz in place of depth/ (auto capture picks megasam), with ``changes`` applied."""
    images = np.stack([cv2.imread(str(p))[..., ::-1] for p in sorted((ctx.case / "rgb").glob("*.png"))])
    depth = np.stack([cv2.imread(str(p), cv2.IMREAD_UNCHANGED) / 1000.0 for p in depth_frames(ctx)])
    data = {
        "images": images.astype(np.uint8),
        "depths": np.clip(depth, 1e-3, 1e2).astype(np.float16),
        "intrinsic": np.loadtxt(ctx.case / "cam_K.txt").astype(np.float32),
        "cam_c2w": np.tile(np.eye(4, dtype=np.float32), (N, 1, 1)),
    }
    for key, fn in changes.items():
        data[key] = fn(data[key])
    shutil.rmtree(ctx.case / "depth")
    (ctx.case / "perception").mkdir(exist_ok=True)
    np.savez(ctx.case / "perception" / "push_sgd_cvd_hr.npz", **data)
    return capture(ctx)


def geocalib(ctx, text: str) -> list[str]:
    (ctx.case / "perception").mkdir(exist_ok=True)
    (ctx.case / "perception" / "geocalib.json").write_text(text)
    return capture(ctx)


def imu(ctx, text: str) -> list[str]:
    (ctx.case / "imu").mkdir(exist_ok=True)
    (ctx.case / "imu" / "gravity.txt").write_text(text)
    return capture(ctx)


def sam2_masks(ctx, bad: bytes | None = None, mode: str = "P") -> list[str]:
    folder = ctx.case / "perception" / "masks"
    folder.mkdir(parents=True)
    ids = np.zeros((240, 320), np.uint8)
    ids[90:127, 174:208] = 1
    for t in range(N):
        Image.fromarray(ids, mode="L").convert(mode).save(folder / f"{t:05d}.png")
    if bad is not None:
        (folder / "00005.png").write_bytes(bad)
    return ["run", "segment", str(ctx.case), "-o", str(ctx.out), "--backend", "capture=oracle"]


def set_provenance(layer_path: Path, **changes) -> None:
    """Edit a layer's recorded provenance (to fake a layer made from something else)."""
    from pxr import Sdf

    layer = Sdf.Layer.FindOrOpen(str(layer_path))
    data = dict(layer.customLayerData)
    prov = json.loads(data["rose"])
    for key, value in changes.items():
        if isinstance(value, dict):
            prov.setdefault(key, {}).update(value)
        else:
            prov[key] = value
    data["rose"] = json.dumps(prov, sort_keys=True)
    layer.customLayerData = data
    layer.Save()


def validate_out(ctx) -> list[str]:
    return ["validate", str(ctx.out / "rose.usda"), "--no-newton"]


def mixed(ctx) -> list[str]:
    """A world layer made from another case, beside the rest of this one."""
    set_provenance(ctx.out / "layers" / "world.usda", inputs={"case": "0123456789abcdef"})
    return validate_out(ctx)


def changed_object(ctx) -> list[str]:
    """An object layer re-made after the trajectory and gate that read it."""
    set_provenance(ctx.out / "layers" / "object.usda", results={"remade": True})
    return validate_out(ctx)


def short_root(ctx) -> list[str]:
    from pxr import Sdf

    layer = Sdf.Layer.FindOrOpen(str(ctx.out / "rose.usda"))
    layer.endTimeCode = 1
    layer.Save()
    return validate_out(ctx)


def lost_layer(ctx) -> list[str]:
    from rose_usd.usd.stage import TimeInfo, write_root

    (ctx.out / "layers" / "trajectory.usda").unlink()
    write_root(ctx.out, TimeInfo(30.0, N))
    return validate_out(ctx)


def touched(ctx, rel: str) -> list[str]:
    path = next(p for p in sorted((ctx.out / rel).rglob("*")) if p.is_file())
    if path.suffix == ".png":
        img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        cv2.imwrite(str(path), 255 - img)
    else:
        path.write_bytes(path.read_bytes() + b"\n")
    return validate_out(ctx)


def journal(ctx) -> list[str]:
    """An interrupted commit: its journal and staging folder are still there."""
    staging = ctx.out / ".staging-scene-1-deadbeef"
    (staging / "textures").mkdir(parents=True)
    (staging / "textures" / "t.png").write_bytes(b"new")
    (ctx.out / ".commit-scene.json").write_text(
        json.dumps({"layer": "scene", "staging": staging.name, "sides": ["textures"], "fps": 30.0, "n_frames": N})
    )
    return validate_out(ctx)


def leftovers_then_bad_K(ctx) -> list[str]:
    (ctx.out / ".staging-masks-1-0badc0de" / "masks").mkdir(parents=True)
    (ctx.out / ".old-masks-0badc0de").mkdir()
    write_K(ctx, K_rows(fy=2525.0))
    return capture(ctx)


def not_a_stage(ctx, command: str, content: bytes | None, name: str = "thing.usda") -> list[str]:
    path = ctx.tmp / name
    if content is not None:
        path.write_bytes(content)
    if command == "diff":
        return ["diff", str(path), str(ctx.out / "rose.usda")]
    return [command, str(path)] + (["--no-newton"] if command == "validate" else [])


PNG = cv2.imencode(".png", np.zeros((4, 4, 3), np.uint8))[1].tobytes()


def out_arg(ctx, target: str) -> list[str]:
    return ["run", "capture", str(ctx.case), "-o", target]


def a_file(ctx) -> list[str]:
    f = ctx.tmp / "afile"
    f.write_text("keep me")
    ctx.watch.append(f)
    return out_arg(ctx, str(f))


def under_a_file(ctx) -> list[str]:
    f = ctx.tmp / "afile"
    f.write_text("keep me")
    ctx.watch.append(f)
    return out_arg(ctx, str(f / "out"))


def layers_is_file(ctx) -> list[str]:
    shutil.rmtree(ctx.out / "layers")
    (ctx.out / "layers").write_text("not a folder")
    return capture(ctx, "--force")


def root_is_dir(ctx) -> list[str]:
    (ctx.out / "rose.usda").unlink()
    (ctx.out / "rose.usda").mkdir()
    return capture(ctx, "--force")


def cache_unwritable(ctx) -> list[str]:
    video(ctx)
    ctx.env.update(HOME="/proc/rose-home", ROSE_USD_CACHE="/proc/rose-cache", XDG_CACHE_HOME="/proc/rose-xdg")
    return ["run", "segment", str(ctx.case), "-o", str(ctx.out), "--backend", "segment=flow"]


def video_depth(ctx, n_depth: int) -> list[str]:
    video(ctx, keep_depth=True)
    frames = depth_frames(ctx)
    for p in frames[n_depth:]:
        p.unlink()
    for t in range(len(frames), n_depth):
        shutil.copy(frames[-1], ctx.case / "depth" / f"{t:06d}.png")
    return capture(ctx)


# ----------------------------------------------------------------------------- the corpus
@dataclass(frozen=True)
class Bad:
    id: str
    cls: int
    mutate: object
    needles: tuple[str, ...]
    forbidden: tuple[str, ...] = ()


def _c(id, cls, mutate, *needles, forbidden=()):
    return Bad(id, cls, mutate, tuple(needles), tuple(forbidden))


def _toml_case(id, cls, text, *needles, keep=True, forbidden=()):
    def mutate(ctx):
        toml(ctx, text, keep_object=keep)
        return capture(ctx)

    return _c(id, cls, mutate, "rose.toml", *needles, forbidden=forbidden)


def _K_case(id, text, *needles):
    def mutate(ctx):
        write_K(ctx, text)
        return capture(ctx)

    return _c(id, 6, mutate, "cam_K.txt", *needles)


def _pose_case(id, text):
    return _c(id, 5, lambda ctx: poses(ctx, text), "000007.txt")


def _set_case(id, cls, setting, *needles, flag="--set", forbidden=("rose.toml",)):
    return _c(id, cls, lambda ctx: capture(ctx, flag, setting), flag, *needles, forbidden=forbidden)


_EYE_T = "1 0 0 {}\n0 1 0 {}\n0 0 1 {}\n0 0 0 1\n"

CORPUS: list[Bad] = [
    # 1. depth with no valid pixel: too few valid frames is refused, naming depth/
    _c("depth-all-zero", 1, lambda ctx: (zero_depth(ctx, range(N)), capture(ctx))[1], "depth"),
    _c("depth-most-zero", 1, lambda ctx: (zero_depth(ctx, range(4, N)), capture(ctx))[1], "depth"),
    _c("depth-all-nan-npy", 1, lambda ctx: (npy_depth(ctx, np.nan), capture(ctx))[1], "depth"),
    _c(
        "depth-all-saturated",
        1,
        lambda ctx: (
            [cv2.imwrite(str(p), np.full((240, 320), 65535, np.uint16)) for p in depth_frames(ctx)],
            capture(ctx),
        )[1],
        "depth",
    ),
    # 2. layers that disagree: validate says so, naming the layer
    _c("mix-other-case", 2, mixed, "layers/", "another case"),
    _c("mix-remade-object", 2, changed_object, "layers/trajectory.usda"),
    _c("mix-root-time-range", 2, short_root, "rose.usda"),
    _c("mix-lost-upstream", 2, lost_layer, "layers/trajectory.usda"),
    # 3. physics overrides
    _toml_case("mass-negative", 3, "mass_kg = -1", "mass_kg"),
    _toml_case("mass-zero", 3, "mass_kg = 0", "mass_kg"),
    _toml_case("mass-nan", 3, "mass_kg = nan", "mass_kg"),
    _toml_case("friction-negative", 3, "friction = -1", "friction"),
    _toml_case("friction-text", 3, 'friction = "high"', "friction"),
    _toml_case("restitution-inf", 3, "restitution = inf", "restitution"),
    _toml_case("restitution-above-one", 3, "restitution = 1.5", "restitution"),
    _toml_case("size-negative", 3, "size_m = -0.06", "size_m"),
    _toml_case("size-text", 3, 'size_m = "6cm"', "size_m"),
    _toml_case("size-centimetres", 3, "size_m = 14", "size_m", "size_m = 0.14"),
    _toml_case("hollow-text", 3, 'hollow = "no"', "hollow"),
    _toml_case("hollow-int", 3, "hollow = 1", "hollow"),
    _toml_case("density-zero", 3, "density_kg_m3 = 0", "density_kg_m3"),
    _toml_case("mesh-up-bad", 3, 'mesh_up = "up"', "mesh_up"),
    _toml_case("mesh-units-bad", 3, 'mesh_units = "feet"', "mesh_units", "not a unit"),
    _toml_case("mesh-not-text", 3, "mesh = 3", "mesh"),
    _toml_case("mesh-missing", 3, 'mesh = "nope/box.obj"', "nope/box.obj", "does not exist"),
    # 4. reserved object names
    _toml_case("name-interactor", 4, '[[objects]]\nname = "Interactor"\n', "Interactor", keep=False),
    _toml_case("name-world", 4, '[[objects]]\nname = "World"\n', "World", keep=False),
    _toml_case("name-cameras", 4, '[[objects]]\nname = "Cameras"\n', "Cameras", keep=False),
    _toml_case("name-interactor-lower", 4, '[[objects]]\nname = "interactor"\n', "interactor", keep=False),
    _toml_case("names-differ-by-case", 4, '[[objects]]\nname = "Box"\n[[objects]]\nname = "box"\n', "box", keep=False),
    # 5. imported poses and other importers' numbers
    _pose_case("pose-nan", _EYE_T.format("nan", 0, 0.6)),
    _pose_case("pose-huge", _EYE_T.format("1e300", 0, 0.6)),
    _pose_case("pose-inf", _EYE_T.format(0, "inf", 0.6)),
    _pose_case("pose-far", _EYE_T.format(0, 0, 1e4)),
    _pose_case("pose-3x4", "1 0 0 0\n0 1 0 0\n0 0 1 0.6\n"),
    _pose_case("pose-text", "this is not a pose\n"),
    _pose_case("pose-not-rigid", "2 0 0 0\n0 1 0 0\n0 0 1 0.6\n0 0 0 1\n"),
    _pose_case("pose-empty", ""),
    _c("megasam-huge-pose", 5, lambda ctx: megasam(ctx, cam_c2w=lambda c: c * 1e30), "push_sgd_cvd_hr.npz"),
    _c("megasam-bad-K", 5, lambda ctx: megasam(ctx, intrinsic=lambda k: -k), "push_sgd_cvd_hr.npz"),
    _c(
        "megasam-depth-nan",
        5,
        lambda ctx: megasam(ctx, depths=lambda d: np.full_like(d, np.nan)),
        "push_sgd_cvd_hr.npz",
    ),
    _c("imu-nan", 5, lambda ctx: imu(ctx, "nan 9.8 0\n"), "gravity.txt"),
    _c("imu-zero", 5, lambda ctx: imu(ctx, "0 0 0\n"), "gravity.txt"),
    _c("imu-columns", 5, lambda ctx: imu(ctx, "0 9.8\n"), "gravity.txt"),
    _c("imu-text", 5, lambda ctx: imu(ctx, "down\n"), "gravity.txt"),
    # 6. intrinsics
    _K_case("fy-ten-fx", K_rows(fy=2525.0), "fy"),
    _K_case("fy-huge", K_rows(fy=1e308), "fy"),
    _K_case("fy-tiny", K_rows(fy=0.001), "fy"),
    _K_case("cx-edge", K_rows(cx=0.5), "principal point"),
    _K_case("cy-edge", K_rows(cy=0.5), "principal point"),
    _K_case("K-2x3", "252 0 160\n0 252 118\n", "3x3"),
    _K_case("K-text", "focal 252\n", "3x3"),
    _K_case("K-empty", "", "3x3"),
    # 7. truncated video
    _c(
        "video-half",
        7,
        lambda ctx: (
            video(ctx, fraction=0.5),
            ["run", "segment", str(ctx.case), "-o", str(ctx.out), "--backend", "segment=flow"],
        )[1],
        "video.avi",
        "header",
    ),
    _c(
        "video-tail",
        7,
        lambda ctx: (
            video(ctx, fraction=0.9),
            ["run", "segment", str(ctx.case), "-o", str(ctx.out), "--backend", "segment=flow"],
        )[1],
        "video.avi",
        "header",
    ),
    _c(
        "video-mp4-cut",
        7,
        lambda ctx: (
            video(ctx, "video.mp4", fraction=0.5),
            ["run", "segment", str(ctx.case), "-o", str(ctx.out), "--backend", "segment=flow"],
        )[1],
        "video.mp4",
    ),
    # 8. wrong types in rose.toml
    _toml_case("name-number", 8, "[[objects]]\nname = 3\n", "name", keep=False),
    _toml_case("name-empty", 8, '[[objects]]\nname = ""\n', "name", keep=False),
    _toml_case("prompt-box-text", 8, '[[objects]]\nname = "Box"\nprompt = { box = ["a", 1, 2, 3] }\n', "prompt"),
    _toml_case("prompt-box-nested", 8, '[[objects]]\nname = "Box"\nprompt = { box = [[1, 2], [3, 4]] }\n', "prompt"),
    _toml_case("prompt-text", 8, '[[objects]]\nname = "Box"\nprompt = "box"\n', "prompt"),
    _toml_case("prompt-frame-nan", 8, '[[objects]]\nname = "Box"\nprompt = { frame = nan, point = [5, 5] }\n', "frame"),
    _toml_case(
        "prompt-frame-float", 8, '[[objects]]\nname = "Box"\nprompt = { frame = 1.5, point = [5, 5] }\n', "frame"
    ),
    _toml_case(
        "prompt-frame-bool", 8, '[[objects]]\nname = "Box"\nprompt = { frame = true, point = [5, 5] }\n', "frame"
    ),
    _toml_case("prompt-unknown-key", 8, '[[objects]]\nname = "Box"\nprompt = { frame = 0, pt = [5, 5] }\n', "pt"),
    _toml_case("fps-bool", 8, "fps = true\n", "fps", keep=False),
    _toml_case("fps-text", 8, 'fps = "30"\n', "fps", keep=False),
    _toml_case("fps-nan", 8, "fps = nan\n", "fps", keep=False),
    _toml_case("stage-key-at-top", 8, 'capture = "oracle"\n', "capture", "[backends]", keep=False),
    _toml_case("category-number", 8, '[[objects]]\nname = "Box"\ncategory = 5\n', "category", keep=False),
    _toml_case("objects-text", 8, 'objects = "Box"\n', "objects", keep=False),
    _toml_case("objects-numbers", 8, "objects = [1]\n", "objects", keep=False),
    _toml_case("objects-table", 8, '[objects]\nname = "Box"\n', "[[objects]]", keep=False),
    _toml_case("backend-number", 8, "[backends]\ncapture = 3\n", "capture", keep=False),
    _toml_case("settings-not-table", 8, "[capture]\nrgbd = 3\n", "rgbd", keep=False),
    _c(
        "not-utf8",
        8,
        lambda ctx: ((ctx.case / "rose.toml").write_bytes(b"fps = 30 # caf\xe9\n"), capture(ctx))[1],
        "rose.toml",
        "UTF-8",
    ),
    _toml_case("toml-syntax", 8, "fps = = 30\n", "TOML", keep=False),
    # 9. output folders
    _c("out-is-file", 9, a_file, "afile"),
    _c("out-under-file", 9, under_a_file, "afile"),
    _c("out-empty", 9, lambda ctx: out_arg(ctx, ""), "-o"),
    _c("out-proc", 9, lambda ctx: out_arg(ctx, "/proc/rose-out"), "/proc/rose-out"),
    _c("out-dev-null", 9, lambda ctx: out_arg(ctx, "/dev/null"), "/dev/null"),
    _c("out-layers-is-file", 9, layers_is_file, "layers"),
    _c("out-root-is-dir", 9, root_is_dir, "rose.usda"),
    _c("frame-cache-unwritable", 9, cache_unwritable, "rose-cache", "ROSE_USD_CACHE"),
    # 10. interrupted commits and mixed side folders
    _c("commit-journal-left", 10, journal, ".commit-scene.json"),
    _c("side-folder-mixed-textures", 10, lambda ctx: touched(ctx, "textures"), "textures"),
    _c("side-folder-mixed-masks", 10, lambda ctx: touched(ctx, "masks"), "masks"),
    _c("side-folder-mixed-report", 10, lambda ctx: touched(ctx, "report"), "report"),
    _c("leftovers-and-bad-K", 10, leftovers_then_bad_K, "cam_K.txt"),
    # 11. inspect, validate, diff on files that are not stages
    _c("inspect-png", 11, lambda ctx: not_a_stage(ctx, "inspect", PNG, "pic.png"), "pic.png"),
    _c("inspect-text", 11, lambda ctx: not_a_stage(ctx, "inspect", b"hello\n", "notes.txt"), "notes.txt"),
    _c("inspect-empty-usda", 11, lambda ctx: not_a_stage(ctx, "inspect", b""), "thing.usda"),
    _c("inspect-garbage-usda", 11, lambda ctx: not_a_stage(ctx, "inspect", b"#usda 1.0\n(((\n"), "thing.usda"),
    _c("inspect-missing", 11, lambda ctx: not_a_stage(ctx, "inspect", None), "thing.usda"),
    _c("inspect-folder", 11, lambda ctx: ["inspect", str(ctx.case)], "case"),
    _c("validate-png", 11, lambda ctx: not_a_stage(ctx, "validate", PNG, "pic.png"), "pic.png"),
    _c("validate-text", 11, lambda ctx: not_a_stage(ctx, "validate", b"hello\n", "notes.txt"), "notes.txt"),
    _c("diff-any-json", 11, lambda ctx: not_a_stage(ctx, "diff", b'{"a": 1}', "other.json"), "other.json"),
    _c("diff-json-list", 11, lambda ctx: not_a_stage(ctx, "diff", b"[1, 2]", "other.json"), "other.json"),
    _c("diff-png", 11, lambda ctx: not_a_stage(ctx, "diff", PNG, "pic.png"), "pic.png"),
    # 12. a video with a depth/ of another length
    _c("video-depth-fewer", 12, lambda ctx: video_depth(ctx, 40), "depth"),
    _c("video-depth-more", 12, lambda ctx: video_depth(ctx, 60), "depth"),
    # 13. a malformed geocalib.json (checked before tracking)
    _c("geocalib-not-json", 13, lambda ctx: geocalib(ctx, "{gravity"), "geocalib.json"),
    _c("geocalib-list", 13, lambda ctx: geocalib(ctx, "[1, 2]"), "geocalib.json"),
    _c("geocalib-gravity-text", 13, lambda ctx: geocalib(ctx, '{"gravity": "up"}'), "geocalib.json"),
    _c("geocalib-gravity-nan", 13, lambda ctx: geocalib(ctx, '{"gravity": [NaN, -1, 0]}'), "geocalib.json"),
    _c("geocalib-rp-text", 13, lambda ctx: geocalib(ctx, '{"gravity": [0, -1, 0], "rp": "flat"}'), "geocalib.json"),
    _c("geocalib-frame-text", 13, lambda ctx: geocalib(ctx, '{"gravity": [0, -1, 0], "frame": "x"}'), "geocalib.json"),
    _c("geocalib-frame-out", 13, lambda ctx: geocalib(ctx, '{"gravity": [0, -1, 0], "frame": 999}'), "geocalib.json"),
    _c("geocalib-K-shape", 13, lambda ctx: geocalib(ctx, '{"gravity": [0, -1, 0], "K": [1, 2]}'), "geocalib.json"),
    _c("geocalib-vfov-neg", 13, lambda ctx: geocalib(ctx, '{"gravity": [0, -1, 0], "vfov": -1}'), "geocalib.json"),
    # 14. out-of-range settings
    _set_case("depth-max-negative", 14, "capture.depth_max_m=-1", "depth_max_m"),
    _set_case("track-width-zero", 14, "capture.rgbd.track_width=0", "track_width"),
    _set_case("keyframe-every-zero", 14, "capture.rgbd.keyframe_every=0", "keyframe_every"),
    _set_case("spp-zero", 14, "gate.spp=0", "spp"),
    _set_case("ssim-threshold-two", 14, "gate.ssim_threshold=2", "ssim_threshold"),
    _set_case("voxel-zero", 14, "scene.tsdf.voxel_m=0", "voxel_m"),
    _set_case("fov-180", 14, "capture.fov_guess_deg=180", "fov_guess_deg"),
    _set_case("stride-negative", 14, "gate.frame_stride=-1", "frame_stride"),
    _set_case("backend-all-typo", 14, "all=oracel", "oracel", flag="--backend"),
    _toml_case("toml-depth-max-negative", 14, "[capture]\ndepth_max_m = -1\n", "depth_max_m"),
    # 15. errors that named the wrong file, or none
    _set_case("set-typo", 15, "capture.depth_max=1", "depth_max"),
    _set_case("prompt-syntax", 15, "0:1,2,3", "0:1,2,3", flag="--prompt"),
    _set_case("prompt-unknown-object", 15, "Mug=0:1,2,30,40", "Mug", flag="--prompt"),
    _c(
        "prompt-static-scene",
        15,
        lambda ctx: (toml(ctx, "objects = []\n"), capture(ctx, "--prompt", "0:1,2,30,40"))[1],
        "--prompt",
    ),
    _c(
        "prompt-half-toml",
        15,
        lambda ctx: (toml(ctx, '[[objects]]\nname = "Ball"\n', keep_object=True), segment(ctx))[1],
        "rose.toml",
        "'Ball' not",
    ),
    _c(
        "prompt-half-flag",
        15,
        lambda ctx: (
            toml(ctx, '[[objects]]\nname = "Box"\n[[objects]]\nname = "Ball"\n'),
            segment(ctx, "--prompt", "Box=0:174,90,208,127"),
        )[1],
        "--prompt",
        "'Ball' not",
    ),
    _toml_case("toml-unknown-backend", 15, '[backends]\ncapture = "colmap"\n', "colmap"),
    _toml_case("category-typo", 15, '[[objects]]\nname = "Box"\ncategory = "boxx"\n', "boxx", keep=False),
    _c("sam2-not-image", 15, lambda ctx: sam2_masks(ctx, b"not a png"), "00005.png"),
    _c("sam2-rgb-mask", 15, lambda ctx: sam2_masks(ctx, mode="RGB"), "00000.png"),
    _set_case("enum-value", 15, "capture.gravity=up", "plane", forbidden=("<GravityMethod", "rose.toml")),
]


def test_corpus_size():
    """At least 60 cases, every one of the issue's 15 classes covered."""
    assert len(CORPUS) >= 60
    assert {c.cls for c in CORPUS} == set(range(1, 16))
    assert len({c.id for c in CORPUS}) == len(CORPUS)


def classify(code: int, err: str, case: Bad, intact: bool) -> str:
    lines = [line for line in err.splitlines() if line.strip()]
    if code == 0:
        return "garbage pass"
    if code == 2 or "Traceback" in err:
        return "traceback"
    if code != 1 or len(lines) != 1 or not lines[0].startswith("error: "):
        return "vague"
    if not intact:
        return "late"
    if not all(n in lines[0] for n in case.needles) or any(f in lines[0] for f in case.forbidden):
        return "wrong file"
    return "clean"


@pytest.mark.parametrize("case", CORPUS, ids=[f"{c.cls:02d}-{c.id}" for c in CORPUS])
def test_bad_input(case, tmp_path, sample_case, oracle_out, capsys, monkeypatch):
    """Exit 1, one line naming the file and the fix, and the earlier output untouched."""
    ctx = Ctx(tmp_path / "case", tmp_path / "out", tmp_path)
    shutil.copytree(sample_case, ctx.case)
    shutil.copytree(oracle_out, ctx.out)
    monkeypatch.setenv("ROSE_USD_CACHE", str(tmp_path / "cache"))
    argv = case.mutate(ctx)
    for key, value in ctx.env.items():
        monkeypatch.setenv(key, value)
    before = {str(p): tree_hash(p) for p in [ctx.out, *ctx.watch]}
    capsys.readouterr()
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse
        code = exc.code
    err = capsys.readouterr().err
    after = {str(p): tree_hash(p) for p in [ctx.out, *ctx.watch]}
    outcome = classify(code, err, case, after == before)
    if os.environ.get("ROSE_CORPUS_LOG"):
        with open(os.environ["ROSE_CORPUS_LOG"], "a") as f:
            f.write(json.dumps({"id": case.id, "class": case.cls, "outcome": outcome, "err": err[-400:]}) + "\n")
    assert outcome == "clean", f"{outcome}: exit {code}\n{err[-3000:]}"


# ----------------------------------------------------------------------------- what should work
def short_case(src: Path, dst: Path, n: int) -> Path:
    """The sample cut to its first ``n`` frames (no ground truth)."""
    shutil.copytree(src, dst, ignore=shutil.ignore_patterns("gt"))
    for folder in ("rgb", "depth"):
        for p in sorted((dst / folder).glob("*.png"))[n:]:
            p.unlink()
    return dst


def test_depth_dropouts_are_skipped(tmp_path, sample_case, capsys):
    """An all-zero and a saturated depth frame (sensor dropouts) are skipped with a warning: capture
    succeeds, records them, and their cameras are interpolated (class 1)."""
    from rose_usd.layers.world import read_cameras
    from rose_usd.usd.stage import open_stage, read_provenance

    case = short_case(sample_case, tmp_path / "case", 12)
    cv2.imwrite(str(case / "depth" / "000004.png"), np.zeros((240, 320), np.uint16))
    cv2.imwrite(str(case / "depth" / "000007.png"), np.full((240, 320), 65535, np.uint16))
    out = tmp_path / "out"
    assert main(["run", "capture", str(case), "-o", str(out)]) == 0, capsys.readouterr().err
    prov = read_provenance(out / "layers" / "world.usda")
    assert prov["results"]["depth_dropouts"] == [4, 7]
    assert any("dropout" in w for w in prov["warnings"])
    cameras = read_cameras(open_stage(out / "rose.usda"), 12)
    centers = cameras.world_from_cv[:, :3, 3]
    assert np.all(np.isfinite(centers))
    # an interpolated camera lies between its neighbours
    assert np.linalg.norm(centers[4] - (centers[3] + centers[5]) / 2) < 0.01


def test_capture_on_another_case_removes_stale_layers(tmp_path, sample_case, oracle_out, capsys):
    """Capture run on a 2-frame copy of the sample into a folder holding the sample's reconstruction
    is refused (another case's stages). The same case cut to 2 frames in place: capture re-run removes
    the masks, scene, object, trajectory and gate it made stale: the folder is that capture alone,
    and validate finds nothing to disagree about (class 2)."""
    from rose_usd.usd.stage import consistency_problems, existing_layers, read_time_info

    case = short_case(sample_case, tmp_path / "case", 2)
    out = tmp_path / "out"
    shutil.copytree(oracle_out, out)
    code = main(["run", "capture", str(case), "-o", str(out)])
    assert code == 1 and "holds the stages of another case" in capsys.readouterr().err  # refused: not its folder
    made_from(out, case)  # as if made from this case's folder before it was cut to 2 frames
    assert main(["run", "capture", str(case), "-o", str(out)]) == 0, capsys.readouterr().err
    assert existing_layers(out) == ["world"]
    assert not any((out / side).exists() for side in ("masks", "textures", "trajectory", "report"))
    assert read_time_info(out).n_frames == 2
    assert consistency_problems(out) == []
    assert [p.name for p in out.rglob(".*")] == []
