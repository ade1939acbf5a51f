"""Score a reconstruction of visp-desk-rgbd-static against its ground truth: the cameras against
the AprilTag board's poses (``cam_in_grid/``) and each object's pose against ``ob_in_cam_<name>/``.

    python benchmarks/real_visp.py RUN_DIR ../shared/data/real/visp-desk-rgbd-static \\
        --object Cube=cube --object Dragon=dragon [-o result.json]

Cameras: the rigid transform (no scale: both are metric) that best maps our cameras (centres and
axis tips 10 cm out) onto the board's, then the RMSE of the centres and the mean rotation error. Objects, per frame: our
mesh at its trajectory pose and the clip's mesh at its true pose, both in that frame's camera;
point-to-point ICP (2 cm reach) from ours onto the truth gives the rotation error (the angle of
its correction, symmetric shapes resolved to the nearest equivalent pose) and the translation
error (the distance of the surface centroids after ICP's rotation is undone).

The truth's own noise: the board's camera poses jitter (AprilTag PnP on blurred frames), and the
objects' per-frame poses are derived from them (``grid_t grid_0^-1 cMo_0``), so they carry that
jitter too. Two figures see past it: the cameras against the truth smoothed over
``SMOOTH_FRAMES`` frames (``cameras_vs_smoothed_truth``, with the raw truth's distance from its
own smoothing, ``truth_jitter``), and each object at frame 0 alone, where the truth is the
clip's given initial pose ``cMo_0`` and no board pose enters (``frame0``).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from rose_usd.core import se3
from rose_usd.layers.objects import default_pose, object_paths, visual_mesh
from rose_usd.layers.trajectory import object_poses
from rose_usd.layers.world import read_cameras
from rose_usd.usd.stage import open_stage


def rigid_fit(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """The rotation and translation (4, 4) minimizing |R src + t - dst| (Kabsch)."""
    ms, md = src.mean(axis=0), dst.mean(axis=0)
    u, _, vt = np.linalg.svd((src - ms).T @ (dst - md))
    d = np.sign(np.linalg.det(vt.T @ u.T))
    rot = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    return se3.make_pose(rot, md - rot @ ms)


def angle_deg(rot: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(rot) - 1.0) / 2.0, -1.0, 1.0))))


def surface_points(vertices: np.ndarray, faces: np.ndarray, n: int = 3000) -> np.ndarray:
    import trimesh

    pts, _ = trimesh.sample.sample_surface_even(trimesh.Trimesh(vertices, faces, process=False), n, seed=0)
    return np.asarray(pts)


def _frame_points(poses: np.ndarray, arm_m: float = 0.1) -> np.ndarray:
    """Each camera's centre and the tips of its axes ``arm_m`` out: a hand-held path can be
    nearly straight, and centres alone leave the turn about it free."""
    tips = [poses[:, :3, 3] + arm_m * poses[:, :3, k] for k in range(3)]
    return np.concatenate([poses[:, :3, 3], *tips])


SMOOTH_FRAMES = 7


def smoothed(poses: np.ndarray, frames: int = SMOOTH_FRAMES) -> np.ndarray:
    """The poses with their positions averaged over ``frames`` consecutive frames (rotations kept)."""
    from scipy.ndimage import uniform_filter1d

    out = np.array(poses, dtype=float, copy=True)
    out[:, :3, 3] = uniform_filter1d(out[:, :3, 3], frames, axis=0, mode="nearest")
    return out


def score_cameras(ours: np.ndarray, truth: np.ndarray) -> dict:
    align = rigid_fit(_frame_points(ours), _frame_points(truth))
    moved = np.einsum("ij,njk->nik", align, ours)
    err = np.linalg.norm(moved[:, :3, 3] - truth[:, :3, 3], axis=1)
    rot = [angle_deg(a[:3, :3].T @ b[:3, :3]) for a, b in zip(moved, truth)]
    return {
        "camera_ape_rmse_m": round(float(np.sqrt(np.mean(err**2))), 4),
        "camera_ape_max_m": round(float(err.max()), 4),
        "camera_rotation_mean_deg": round(float(np.mean(rot)), 2),
        "camera_path_length_m": round(float(np.linalg.norm(np.diff(truth[:, :3, 3], axis=0), axis=1).sum()), 3),
    }


def score_object(stage, name: str, clip: Path, folder: str, cams: np.ndarray) -> dict:
    import open3d as o3d
    import trimesh

    n = len(cams)
    mesh = visual_mesh(stage, name)
    poses = object_poses(stage, name, n)
    ours0 = surface_points(mesh.vertices, mesh.faces)  # at the default pose
    rest = se3.invert(default_pose(stage, name))
    truth_mesh = trimesh.load(clip / "mesh" / folder / f"{folder}.obj", force="mesh")
    truth0 = surface_points(np.asarray(truth_mesh.vertices), np.asarray(truth_mesh.faces))
    t_err, r_err = [], []
    for t in range(n):
        truth_pose = np.loadtxt(clip / f"ob_in_cam_{folder}" / f"{t:06d}.txt")
        gt = se3.transform_points(truth_pose, truth0)
        ours = se3.transform_points(se3.invert(cams[t]) @ poses[t] @ rest, ours0)
        src = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(ours))
        dst = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(gt))
        fit = o3d.pipelines.registration.registration_icp(
            src, dst, 0.02, np.eye(4), o3d.pipelines.registration.TransformationEstimationPointToPoint()
        )
        corr = np.asarray(fit.transformation)
        r_err.append(angle_deg(corr[:3, :3]))
        t_err.append(float(np.linalg.norm(ours.mean(axis=0) - gt.mean(axis=0))))
    t_err, r_err = np.array(t_err), np.array(r_err)
    return {
        "translation_mean_m": round(float(t_err.mean()), 4),
        "translation_max_m": round(float(t_err.max()), 4),
        "rotation_mean_deg": round(float(r_err.mean()), 2),
        "rotation_max_deg": round(float(r_err.max()), 2),
        "frame0": {"translation_m": round(float(t_err[0]), 4), "rotation_deg": round(float(r_err[0]), 2)},
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("run", type=Path)
    parser.add_argument("clip", type=Path)
    parser.add_argument("--object", action="append", default=[], metavar="NAME=FOLDER")
    parser.add_argument("-o", "--output", type=Path)
    args = parser.parse_args()
    stage = open_stage(args.run / "rose.usda")
    truth = np.array([np.loadtxt(f) for f in sorted((args.clip / "cam_in_grid").glob("*.txt"))])
    cams = read_cameras(stage, len(truth)).world_from_cv
    result = {
        "cameras": score_cameras(cams, truth),
        "cameras_vs_smoothed_truth": score_cameras(cams, smoothed(truth)),
        "truth_jitter": score_cameras(smoothed(truth), truth),
        "objects": {},
    }
    present = object_paths(stage)
    for item in args.object:
        name, folder = item.split("=")
        if name not in present:
            result["objects"][name] = "not in the stage (the object stage did not write it)"
            continue
        result["objects"][name] = score_object(stage, name, args.clip, folder, cams)
    text = json.dumps(result, indent=1)
    if args.output:
        args.output.parent.mkdir(parents=True, exist_ok=True)
        args.output.write_text(text + "\n")
    print(text)


if __name__ == "__main__":
    main()
