"""The plan: which backend runs each stage on a case, and a check that their inputs exist.

Every stage's default backend is ``auto``, resolved here from what the case holds:

=========== ===================================================================================
capture     ``rgbd`` with ``depth/``, else ``megasam`` with MegaSaM's npz, else ``sfm`` (RGB only)
segment     ``sam2`` with SAM 2's masks, else ``classical`` with depth (a sensor's or MegaSaM's),
            else ``flow``
scene       ``tsdf`` with depth, else ``plane``
object      with depth: ``imported`` when every object has a mesh (rose.toml ``mesh``,
            ``perception/<Name>.glb``, FoundationPose's ``mesh/``), else ``fusion``; without:
            ``silhouette`` (the mesh, or a category primitive, fitted to the masks)
trajectory  ``foundationpose`` when every object has ``ob_in_cam`` poses, else ``tracker`` with
            depth, else ``silhouette``
gate        ``mitsuba-newton``
=========== ===================================================================================

``oracle`` is never chosen by ``auto``: it reads ground truth and runs only when named.

Each backend declares what it requires (``StageDef.requires``); :func:`preflight` checks all of it
for the stages about to run, before any of them writes anything, and raises one InputError naming
the missing file and the fix.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping

from rose_usd.case.layout import Case
from rose_usd.errors import InputError

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
    "scene": lambda case: "tsdf" if _has_depth(case) else "plane",
    "object": _object,
    "trajectory": _trajectory,
    "gate": lambda case: "mitsuba-newton",
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
        raise InputError(
            f"the {stage} stage's {plan[stage]} backend needs depth maps, and this case has none",
            path=case.folder / "depth",
            hint="put one depth map per frame there (uint16 PNG in mm, or .npy in m), or pick another backend",
        )


def _need_megasam(case: Case, plan: Mapping[str, str], stage: str) -> None:
    if case.megasam_file() is None:
        raise InputError(
            "the capture stage's megasam backend needs MegaSaM's output, and this case has none",
            path=case.perception_dir / "<scene>_sgd_cvd_hr.npz",
            hint="run MegaSaM and copy its npz there, or pick another capture backend",
        )


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
        " (scene=plane, object=silhouette, trajectory=silhouette)",
    )


def _need_sam2_masks(case: Case, plan: Mapping[str, str], stage: str) -> None:
    if not case.has_sam2_masks():
        raise InputError(
            "the segment stage's sam2 backend needs SAM 2's masks, and this case has none",
            path=case.sam2_dir,
            hint="put SAM 2's PNG masks there (DAVIS paletted, or one folder per object id)",
        )


def _need_meshes(case: Case, plan: Mapping[str, str], stage: str) -> None:
    for spec in case.config.objects:
        if case.mesh_file(spec) is None:
            raise InputError(
                f"the object stage's imported backend needs a mesh of object {spec.name!r}, and there is none",
                path=case.perception_dir / f"{spec.name}.glb",
                hint='put it there, set mesh = "..." in its [[objects]] entry of rose.toml,'
                " or drop --backend object=imported",
            )


def _need_poses(case: Case, plan: Mapping[str, str], stage: str) -> None:
    for spec in case.config.objects:
        if not case.has_poses(spec.name):
            raise InputError(
                f"the trajectory stage's foundationpose backend needs FoundationPose's poses of object {spec.name!r}",
                path=case.pose_dir(spec.name),
                hint="put ob_in_cam/*.txt there (one folder per object when there are several),"
                " or pick another backend",
            )


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


def preflight(case: Case, plan: Mapping[str, str], requires: Mapping[str, tuple[str, ...]]) -> None:
    """Check every requirement of the planned backends (stage -> backend), in run order.

    Args:
        case: the case.
        plan: stage -> the backend that will run it (``auto`` already resolved).
        requires: stage -> what its planned backend requires (names in :data:`REQUIREMENTS`).

    Raises:
        InputError: the first thing missing, naming its file and the fix.
    """
    for stage, needs in requires.items():
        for need in needs:
            REQUIREMENTS[need](case, plan, stage)
