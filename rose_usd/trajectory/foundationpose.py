"""The ``foundationpose`` trajectory backend: FoundationPose's ``ob_in_cam/<frame>.txt`` (T_cam<-object
in the mesh FoundationPose was given, meters, OpenCV axes: formats.md) composed with the recovered
cameras into the world.

- Folders: ``perception/ob_in_cam/`` for a case with one object, ``perception/ob_in_cam/<Name>/``
  for several (architecture amendment 10). Frame ids are the stems of the RGB files.
- The object frame: the imported object backend keeps the mesh's own frame (amendment 17), so
  the poses compose as they are; the track is then moved rigidly so that frame 0 is the object
  stage's default pose (which rested the object on the scene), as every backend does.
- Frames without a file are interpolated on SE(3) between the nearest frames with one
  (confidence 0.5) or hold the nearest pose before the first / after the last (confidence 0);
  each gap is a warning. Frames with a file have confidence 1 (FoundationPose gives no score).
- A file that is not a rigid transform (bad shape, last row, or a rotation that is not one) is an
  error naming the file, before anything is written.
"""

from __future__ import annotations

import numpy as np

from rose_usd.core.runs import true_runs
from rose_usd.errors import InputError
from rose_usd.io import foundationpose
from rose_usd.layers.world import read_cameras
from rose_usd.stage_api import StageContext
from rose_usd.trajectory.author import author_trajectory, fill_gaps, from_default_pose
from rose_usd.trajectory.rests import rest_poses


def _gaps(missing: np.ndarray) -> str:
    """Runs of missing frames as "3-7, 12"."""
    runs = [f"{a}" if a == b else f"{a}-{b}" for a, b in true_runs(missing)]
    return ", ".join(runs[:6]) + (" ..." if len(runs) > 6 else "")


def run(ctx: StageContext) -> None:
    case, n = ctx.case, ctx.time_info.n_frames
    cameras = read_cameras(ctx.stage, n)
    specs = case.config.objects
    frame_ids = [case.frame_name(t) for t in range(n)]
    tracks = {}
    for spec in specs:  # every file read and checked before anything is written
        folder = case.pose_dir(spec.name)
        if not folder.is_dir():
            raise InputError(
                f"no FoundationPose poses of object {spec.name!r}",
                path=folder,
                hint="put FoundationPose's ob_in_cam/ there (one folder per object when there are several)",
            )
        cam_from_object, present = foundationpose.read_track(folder, frame_ids)
        if not present.any():
            raise InputError(
                f"no pose file of object {spec.name!r} matches a frame (expected e.g. {frame_ids[0]}.txt)",
                path=folder,
                hint="name the files by the RGB frames' stems",
            )
        poses, confidence = fill_gaps(np.einsum("nij,njk->nik", cameras.world_from_cv, cam_from_object), present)
        if not present.all():
            ctx.warn(
                f"object {spec.name!r}: no FoundationPose pose for {int((~present).sum())} of {n} frames "
                f"({_gaps(~present)}): interpolated between neighbors (confidence 0.5) or held at the ends (0)"
            )
        tracks[spec.name] = (poses, confidence, int(present.sum()))
    final = {name: from_default_pose(ctx, name, poses) for name, (poses, _, _) in tracks.items()}
    rests = rest_poses(ctx, final)
    facts = {}
    for name, (_, confidence, read) in tracks.items():
        author_trajectory(ctx, name, final[name], confidence, "foundationpose")
        facts[name] = {"frames_read": read, "frames_filled": n - read, "rests": rests[name]}
    ctx.record(objects=facts)
