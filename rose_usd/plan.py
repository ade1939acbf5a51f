"""The plan: which backend runs each stage on a case, and a check that their inputs exist.

Every stage's default backend is ``auto``, resolved here from what the case holds:

=========== ===================================================================================
capture     ``rgbd`` with ``depth/``, else ``megasam`` with MegaSaM's npz, else ``sfm`` (RGB only)
segment     ``sam2`` with SAM 2's masks, else ``classical`` with depth (a sensor's or MegaSaM's),
            else ``flow``
scene       ``tsdf`` with depth, else ``stereo`` (which builds ``plane``'s scene when the camera
            moves too little for stereo)
object      with depth: ``imported`` when every object has a mesh (rose.toml ``mesh``,
            ``perception/<Name>.glb``, FoundationPose's ``mesh/``), else ``fusion``; without:
            ``silhouette`` (the mesh, or a category primitive, fitted to the masks)
trajectory  ``foundationpose`` when every object has ``ob_in_cam`` poses, else ``tracker`` with
            depth, else ``silhouette``
gate        ``mitsuba-newton``
collect     ``newton``
=========== ===================================================================================

``oracle`` is never chosen by ``auto``: it reads ground truth and runs only when named.

Each backend declares what it requires (``StageDef.requires``); :func:`preflight` checks all of it
for the stages about to run, before any of them writes anything, and raises one InputError naming
the missing file and the fix.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping
from pathlib import Path

import numpy as np

from rose_usd.case.layout import Case
from rose_usd.errors import ConfigError, InputError

AUTO = "auto"
DEPTH_CAPTURES = ("rgbd", "megasam", "oracle")
"""Capture backends whose world layer gives later stages metric depth (oracle: the case's depth/)."""


def _capture(case: Case) -> str:
    if case.has_depth:
        return "rgbd"
    if case.megasam_file() is not None:
        return "megasam"
    return "sfm"


def _segment(case: Case) -> str:
    if case.has_sam2_masks():
        return "sam2"
    return "classical" if _has_depth(case) else "flow"


def _object(case: Case) -> str:
    if not _has_depth(case):
        return "silhouette"
    objects = case.config.objects
    return "imported" if objects and all(case.mesh_file(o) is not None for o in objects) else "fusion"


def _trajectory(case: Case) -> str:
    objects = case.config.objects
    if objects and all(case.has_poses(o.name) for o in objects):
        return "foundationpose"
    return "tracker" if _has_depth(case) else "silhouette"


AUTO_RULES: dict[str, Callable[[Case], str]] = {
    "capture": _capture,
    "segment": _segment,
    "scene": lambda case: "tsdf" if _has_depth(case) else "stereo",
    "object": _object,
    "trajectory": _trajectory,
    "gate": lambda case: "mitsuba-newton",
    "collect": lambda case: "newton",
}
"""stage -> the backend ``auto`` stands for on a case."""


def resolve_auto(stage: str, case: Case) -> str:
    return AUTO_RULES[stage](case)


# ----------------------------------------------------------------------------- requirements
def _has_depth(case: Case) -> bool:
    return case.has_depth or case.megasam_file() is not None


def _need_gt(case: Case, plan: Mapping[str, str], stage: str) -> None:
    if not case.has_gt:
        raise InputError(
            f"the {stage} stage's oracle backend reads ground truth, and this case has none",
            path=case.folder / "gt" / "scene.json",
            hint=f"oracle backends are for benchmark cases: drop --backend {stage}=oracle (auto picks a real one)",
        )


def _need_sensor_depth(case: Case, plan: Mapping[str, str], stage: str) -> None:
    if not case.has_depth:
        if case.root.is_file():  # a video given as a file reads no depth/, not even one beside it
            raise InputError(
                f"the {stage} stage's {plan[stage]} backend needs depth maps, and a video given as a file has none",
                path=case.root,
                hint=f"{case.as_folder('depth/ (one map per frame)')}; or pick another backend",
            )
        raise InputError(
            f"the {stage} stage's {plan[stage]} backend needs depth maps, and this case has none",
            path=case.folder / "depth",
            hint="put one depth map per frame there (uint16 PNG in mm, or .npy in m), or pick another backend",
        )
    case.check_depth()


def _need_megasam(case: Case, plan: Mapping[str, str], stage: str) -> None:
    if case.megasam_file() is None:
        raise InputError(
            "the capture stage's megasam backend needs MegaSaM's output, and this case has none",
            path=case.perception_dir / "<scene>_sgd_cvd_hr.npz",
            hint="run MegaSaM and copy its npz there, or pick another capture backend",
        )
    from rose_usd.io.megasam import read_megasam
    from rose_usd.io.unidepth import read_unidepth

    read_megasam(case.megasam_file())
    for path in sorted((case.perception_dir / "unidepth").glob("*.npz")):
        read_unidepth(path)


def _need_metric_depth(case: Case, plan: Mapping[str, str], stage: str) -> None:
    """Metric depth through the world layer: the capture backend must give it."""
    capture = plan.get("capture")
    if capture in DEPTH_CAPTURES and (capture == "megasam" or case.has_depth):
        return
    raise InputError(
        f"the {stage} stage's {plan[stage]} backend needs metric depth, and this case gives none "
        f"(no depth/, no MegaSaM output{', capture=sfm' if capture == 'sfm' else ''})",
        path=case.folder / "depth",
        hint="add depth maps there or MegaSaM's npz under perception/, or use the RGB-only backends"
        " (scene=stereo, object=silhouette, trajectory=silhouette)",
    )


def _need_sam2_masks(case: Case, plan: Mapping[str, str], stage: str) -> None:
    if not case.has_sam2_masks():
        raise InputError(
            "the segment stage's sam2 backend needs SAM 2's masks, and this case has none",
            path=case.sam2_dir,
            hint="put SAM 2's PNG masks there (DAVIS paletted, or one folder per object id)",
        )
    from rose_usd.io.sam2 import check_mask_file, read_masks

    for frame, entries in sorted(read_masks(case.sam2_dir).items()):
        for object_id, path in sorted(entries.items()):
            size = check_mask_file(path, paletted=object_id == 0)
            if size != (case.width, case.height):
                raise InputError(
                    f"mask is {size[0]}x{size[1]}, the frames are {case.width}x{case.height}",
                    path=path,
                    hint="give SAM 2 masks at the frames' size",
                )
            if frame >= case.n_frames:
                raise InputError(
                    f"mask of frame {frame}, the video has frames 0..{case.n_frames - 1}",
                    path=path,
                    hint="give masks of this video's frames only",
                )


def _need_meshes(case: Case, plan: Mapping[str, str], stage: str) -> None:
    from rose_usd.io.meshfile import read_mesh_file

    for spec in case.config.objects:
        if case.mesh_file(spec) is not None:
            read_mesh_file(case.mesh_file(spec))
        if case.mesh_file(spec) is None:
            raise InputError(
                f"the object stage's imported backend needs a mesh of object {spec.name!r}, and there is none",
                path=case.perception_dir / f"{spec.name}.glb",
                hint='put it there, set mesh = "..." in its [[objects]] entry of rose.toml,'
                " or drop --backend object=imported",
            )


def _need_poses(case: Case, plan: Mapping[str, str], stage: str) -> None:
    from rose_usd.io.foundationpose import read_track

    for spec in case.config.objects:
        if not case.has_poses(spec.name):
            raise InputError(
                f"the trajectory stage's foundationpose backend needs FoundationPose's poses of object {spec.name!r}",
                path=case.pose_dir(spec.name),
                hint="put ob_in_cam/*.txt there (one folder per object when there are several),"
                " or pick another backend",
            )
        read_track(case.pose_dir(spec.name), [case.frame_name(t) for t in range(case.n_frames)])


REQUIREMENTS: dict[str, Callable[[Case, Mapping[str, str], str], None]] = {
    "gt": _need_gt,
    "sensor-depth": _need_sensor_depth,
    "megasam": _need_megasam,
    "metric-depth": _need_metric_depth,
    "sam2-masks": _need_sam2_masks,
    "meshes": _need_meshes,
    "poses": _need_poses,
}
"""What a backend may require (``StageDef.requires``), and the check that it is there."""


def _check_gravity_inputs(case: Case) -> None:
    """The IMU's and GeoCalib's files, where the case has them (the capture's gravity reads them)."""
    from rose_usd.io.geocalib import read_geocalib
    from rose_usd.io.imu import read_gravity

    imu = case.folder / "imu" / "gravity.txt"
    if imu.is_file():
        read_gravity(imu, case.n_frames)
    geocalib = case.perception_dir / "geocalib.json"
    if geocalib.is_file():
        calib = read_geocalib(geocalib)
        if calib.frame >= case.n_frames:
            raise InputError(
                f"geocalib.json is for frame {calib.frame}, the video has frames 0..{case.n_frames - 1}",
                path=geocalib,
                hint="calibrate a frame of this video",
            )


def check_categories(case: Case) -> None:
    """Every object's category is known (a near miss of a known one is an error, naming rose.toml)."""
    from rose_usd.object.priors import lookup

    for spec in case.config.objects:
        try:
            lookup(spec.category)
        except ConfigError as exc:
            raise ConfigError(f"object {spec.name!r}: {exc.message}", path=case.config.path, hint=exc.hint) from None


def check_prompts(case: Case, prompts, where: str) -> None:
    """The objects' prompts, rose.toml's and ``prompts`` (segment.prompts, from ``where``), against
    the objects and the video: every prompt names an object, lies on a frame and inside the image."""
    from rose_usd.errors import ConfigError
    from rose_usd.segment.prompts import check_prompts as check_inside
    from rose_usd.segment.prompts import parse_prompts

    specs = list(case.config.objects)
    if prompts and not specs:
        raise ConfigError(
            f"prompt {str(prompts[0])!r} has no object to point at: rose.toml says objects = [] (a static scene)",
            path=where,
            hint="drop the prompt, or declare the object in rose.toml ([[objects]] name = ...)",
        )
    names = [s.name for s in specs]
    for item in prompts:
        name = item.name or (names[0] if len(names) == 1 else "")
        if name not in names:
            raise ConfigError(
                f"prompt {str(item)!r} names no object of the case (its objects: {', '.join(names)})",
                path=where,
                hint=f"write e.g. {names[0]}=0:120,80,200,170",
            )
    specs = parse_prompts(prompts, specs)
    from_cli = {p.name or specs[0].name for p in prompts} if prompts and specs else set()
    for spec in specs:
        source = where if spec.name in from_cli else case.settings_file
        check_inside([spec], case.width, case.height, case.n_frames, source)


def check_prompted(case: Case, prompts, where: str) -> None:
    """Every object has a prompt (rose.toml's, or one of ``prompts``, from ``where``): the flow
    segment backend, for videos without depth, has no other way to find it."""
    from rose_usd.segment.prompts import parse_prompts

    missing = [s.name for s in parse_prompts(prompts, list(case.config.objects)) if s.prompt is None]
    if missing:
        raise InputError(
            f"object(s) {', '.join(repr(n) for n in missing)} have no prompt, and the flow segment backend"
            " (a video without depth) needs one for every object",
            path=where,
            hint=_prompt_hint(case),
        )


def check_collect_object(case: Case, name: str, where: str) -> None:
    """``collect.object_name`` (from ``where``), where given, is one of the case's objects: known
    before any stage runs, not once the stages before collect have."""
    names = [o.name for o in case.config.objects]
    if name and name not in names:
        raise ConfigError(
            f"collect.object_name = {name!r} is not an object of this case",
            path=where,
            hint=f"the objects of {case.settings_file.name}: {', '.join(names) or 'none'}",
        )


def check_all_or_none(case: Case, prompts, where: str) -> None:
    """Either every object has a prompt (rose.toml's, or one of ``prompts``, from ``where``) or none
    has: the classical segment backend prompts them all or finds them all (``segment.prompts``)."""
    from rose_usd.segment.prompts import all_or_none, parse_prompts

    all_or_none(parse_prompts(prompts, list(case.config.objects)), where)


def _prompt_hint(case: Case) -> str:
    """Where a missing prompt goes: the case's settings file (``Case.settings_file``: rose.toml, or
    a video's <name>.toml beside it), one in a folder of the user's own when the case's folder is
    read-only (a dataset's), or ``--prompt``."""
    toml = "prompt = { frame = 0, box = [x0, y0, x1, y1] }"
    if case.config.path:
        where = f"add {toml} to each [[objects]] of {case.config.path.name}"
    elif os.access(case.folder, os.W_OK) and case.folder.stat().st_mode & 0o222:  # no write bit: root too
        where = f'write {case.settings_file} with [[objects]] name = "..." and {toml}'
        if case.root.is_file() and (case.folder / "rose.toml").is_file():  # a video's settings are its own
            where += " (rose.toml beside it is not read for a video)"
    else:
        where = (
            f"{case.folder} is read-only: make a folder of your own with a link video.mp4 -> the video (or rgb ->"
            f' the frames) and a rose.toml with [[objects]] name = "..." and {toml}'
        )
    names = [o.name for o in case.config.objects]
    named = "" if len(names) == 1 else f"{names[0] if names else 'NAME'}="
    return where + f", or pass --prompt {named}FRAME:x0,y0,x1,y1 (or a point, {named}FRAME:x,y)"


PLAUSIBLE_SIZE_M = (0.002, 10.0)
"""The sizes [m] outside which an object's mesh, read in the ``mesh_units`` given, is refused: no
tabletop video shows such an object, its file is in other units."""


def _check_mesh_units(case: Case, spec, path: Path) -> None:
    """Refuse a mesh whose largest side, in the ``mesh_units`` rose.toml gives, is no object's size
    (``PLAUSIBLE_SIZE_M``), naming the unit ``io.meshfile.file_unit`` would guess for it."""
    from rose_usd.io.meshfile import UNIT_NAMES, file_unit, read_mesh_file

    v = np.asarray(read_mesh_file(path).vertices, float)
    extent = float(np.max(v.max(axis=0) - v.min(axis=0))) if len(v) else 0.0
    given = spec.overrides["mesh_units"]
    size = extent * file_unit(extent, False, given).meters
    low, high = PLAUSIBLE_SIZE_M
    if low <= size <= high:
        return
    guess = file_unit(extent, False)
    key = {name: key for key, name in UNIT_NAMES.items()}.get(guess.name)
    raise InputError(
        f"object {spec.name!r}: its mesh {path.name} is {size:.4g} m across in mesh_units = {given!r}",
        path=case.settings_file,
        hint=(f"is it in {key!r} ({extent * guess.meters:.3g} m)? " if key else "")
        + 'fix mesh_units, or write mesh_units = "auto"',
    )


def preflight(case: Case, plan: Mapping[str, str], requires: Mapping[str, tuple[str, ...]]) -> None:
    """Check every requirement of the planned backends (stage -> backend), in run order, and
    every imported file they read, and that every mesh rose.toml names exists.

    Args:
        case: the case.
        plan: stage -> the backend that will run it (``auto`` already resolved).
        requires: stage -> what its planned backend requires (names in :data:`REQUIREMENTS`).

    Raises:
        InputError: the first thing missing, naming its file and the fix.
    """
    for spec in case.config.objects:  # a mesh rose.toml names must exist, whichever stage reads it
        path = case.mesh_file(spec)
        if path is not None and spec.overrides.get("mesh_units", "auto") != "auto":
            _check_mesh_units(case, spec, path)
    for stage, needs in requires.items():
        for need in needs:
            REQUIREMENTS[need](case, plan, stage)
    if plan.get("capture") in ("rgbd", "megasam"):
        _check_gravity_inputs(case)
