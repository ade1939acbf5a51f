"""Real recordings with known poses (../shared/data/real/): run rose on them as a user would and
compare with what was recorded. ``rose-usd bench real 7scenes FOLDER``."""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from rose_usd.core import metrics, se3
from rose_usd.errors import InputError
from rose_usd.pipeline import Options, Pipeline
from rose_usd.usd import paths
from rose_usd.usd.camera import read_camera
from rose_usd.usd.stage import layer_file, open_stage, read_provenance


def read_seven_scenes_truth(folder: Path) -> tuple[np.ndarray, np.ndarray]:
    """Recorded camera-to-world poses (N, 4, 4) of the ``*.color.*`` frames, and the unit gravity (down)."""
    frames = sorted(folder.glob("frame-*.pose.txt"))
    if not frames:
        raise InputError("no frame-*.pose.txt files", path=folder, hint="give a 7-Scenes sequence folder")
    poses = np.array([np.loadtxt(p) for p in frames])
    # KinectFusion's rotations drift off orthonormal (R^T R = 0.9997 I here): a 1.5 deg "rotation"
    # between identical orientations by the trace formula. Project them back onto SO(3).
    poses[:, :3, :3] = se3.orthonormalize(poses[:, :3, :3])
    gravity = np.loadtxt(folder / "gravity-direction.txt").reshape(3)
    return poses, gravity / np.linalg.norm(gravity)


def evaluate_seven_scenes(folder: Path, out_dir: Path, *, backends: dict | None = None) -> dict:
    """Capture on a 7-Scenes sequence; camera APE/RPE after rigid alignment and gravity error."""
    folder, out_dir = Path(folder), Path(out_dir)
    t0 = time.perf_counter()
    Pipeline(folder, out_dir, Options(backends=backends or {"capture": "rgbd"}, force=True)).run("capture")
    wall = time.perf_counter() - t0
    truth, gravity = read_seven_scenes_truth(folder)
    stage = open_stage(out_dir / "rose.usda")
    track = read_camera(stage, paths.CAMERA, len(truth))
    align = metrics.align_poses(track.world_from_cv, truth)
    est = np.einsum("ij,njk->nik", align, track.world_from_cv)
    ape, rpe = metrics.ape(est, truth), metrics.rpe(est, truth)
    up = align[:3, :3] @ np.array([0.0, 0.0, 1.0])
    gravity_err = float(np.degrees(np.arccos(np.clip(up @ -gravity, -1.0, 1.0))))
    prov = read_provenance(layer_file(out_dir, "world")) or {}
    result = {
        "sequence": folder.name,
        "frames": len(truth),
        "backend": prov.get("backend"),
        "capture_wall_time_s": round(wall, 1),
        "camera_ape_translation_rmse_m": ape.translation.rmse,
        "camera_ape_translation_max_m": ape.translation.max,
        "camera_ape_rotation_rmse_deg": ape.rotation.rmse,
        "camera_rpe_translation_rmse_m": rpe.translation.rmse,
        "camera_rpe_rotation_rmse_deg": rpe.rotation.rmse,
        "gravity_error_deg": gravity_err,
        "gravity_source": stage.GetPrimAtPath(paths.WORLD).GetAttribute("rose:world:gravitySource").Get(),
        "capture_results": prov.get("results"),
        "capture_warnings": prov.get("warnings", []),
    }
    (out_dir / "real-7scenes.json").write_text(json.dumps(result, indent=1, default=float) + "\n")
    _plot(out_dir, est, truth, ape.translation_m)
    return result


def _plot(out_dir: Path, est: np.ndarray, truth: np.ndarray, ape_m: np.ndarray) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 3.6), dpi=100, layout="constrained")
    a.plot(truth[:, 0, 3], truth[:, 1, 3], label="recorded (KinectFusion)", lw=2)
    a.plot(est[:, 0, 3], est[:, 1, 3], label="rose rgbd capture (aligned)", lw=1)
    a.set_aspect("equal")
    a.set_xlabel("x (m)")
    a.set_ylabel("y (m)")
    a.legend(fontsize=8)
    a.set_title("camera path, top view", fontsize=10)
    b.plot(1e3 * ape_m)
    b.set_xlabel("frame")
    b.set_ylabel("APE translation (mm)")
    b.grid(alpha=0.3)
    b.set_title("camera error over time", fontsize=10)
    fig.savefig(out_dir / "real-7scenes.png")
    plt.close(fig)
