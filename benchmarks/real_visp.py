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


def _pair_residuals(k_from_ref: np.ndarray, ref: int, k: int, clip: Path, K: np.ndarray) -> tuple[float, float]:
    """Frame ``ref``'s depth moved into frame ``k`` by ``k_from_ref`` (4, 4): the median depth
    difference there [mm] and the median gray-level difference on ``ref``'s strong edges."""
    import cv2

    def depth(i):
        return cv2.imread(str(clip / "depth" / f"{i:06d}.png"), cv2.IMREAD_UNCHANGED).astype(float) / 1000.0

    def gray(i):
        return cv2.cvtColor(cv2.imread(str(clip / "rgb" / f"{i:06d}.png")), cv2.COLOR_BGR2GRAY).astype(float)

    d0, dk, g0, gk = depth(ref), depth(k), gray(ref), gray(k)
    v, u = np.nonzero((d0 > 0.1) & (d0 < 1.5))
    z = d0[v, u]
    pts = np.stack([(u - K[0, 2]) * z / K[0, 0], (v - K[1, 2]) * z / K[1, 1], z], axis=1)
    q = se3.transform_points(k_from_ref, pts)
    uu = np.round(K[0, 0] * q[:, 0] / np.maximum(q[:, 2], 1e-6) + K[0, 2]).astype(int)
    vv = np.round(K[1, 1] * q[:, 1] / np.maximum(q[:, 2], 1e-6) + K[1, 2]).astype(int)
    ok = (uu >= 0) & (uu < d0.shape[1]) & (vv >= 0) & (vv < d0.shape[0]) & (q[:, 2] > 0.1)
    ok[ok] &= dk[vv[ok], uu[ok]] > 0
    dz = np.abs(dk[vv[ok], uu[ok]] - q[ok, 2])
    edges = np.hypot(cv2.Sobel(g0, cv2.CV_64F, 1, 0), cv2.Sobel(g0, cv2.CV_64F, 0, 1))[v[ok], u[ok]] > 100
    di = np.abs(gk[vv[ok], uu[ok]] - g0[v[ok], u[ok]])[edges]
    return float(np.median(dz) * 1000.0), float(np.median(di))


def image_consistency(ours: np.ndarray, truth: np.ndarray, clip: Path, step: int = 10, gaps=(10, 30)) -> dict:
    """How well each set of camera poses explains the images themselves: for frame pairs (every
    ``step``-th frame and the frames ``gaps`` later), the depth and the strong edges of the first
    moved into the second by the pair's relative pose. A correct pose leaves only sensor noise;
    the board's poses carry their PnP jitter. Medians over the pairs, and in how many pairs our
    poses leave the smaller residual."""
    K = np.loadtxt(clip / "cam_K.txt").reshape(3, 3)
    pairs = [(r, r + g) for r in range(0, len(truth), step) for g in gaps if r + g < len(truth)]
    rows = {"ours": [], "truth": []}
    for ref, k in pairs:
        for key, poses in (("ours", ours), ("truth", truth)):
            rows[key].append(_pair_residuals(se3.invert(poses[k]) @ poses[ref], ref, k, clip, K))
    a, b = np.array(rows["ours"]), np.array(rows["truth"])
    return {
        "pairs": len(pairs),
        "depth_residual_median_mm": {
            "ours": round(float(np.median(a[:, 0])), 2),
            "truth": round(float(np.median(b[:, 0])), 2),
        },
        "edge_gray_residual_median": {
            "ours": round(float(np.median(a[:, 1])), 1),
            "truth": round(float(np.median(b[:, 1])), 1),
        },
        "pairs_ours_lower": {"depth": int((a[:, 0] < b[:, 0]).sum()), "edges": int((a[:, 1] < b[:, 1]).sum())},
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
        "image_consistency": image_consistency(cams, truth, args.clip),
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
