"""Real recordings (../shared/data/real/): run rose on them as a user would and compare with
what was recorded.

- ``rose-usd bench real 7scenes FOLDER``: capture (cameras, gravity) and, with the segment and
  scene stages, the scene mesh against a fusion of the same depth with the recorded poses.
- ``rose-usd bench real sam2-cups FOLDER``: masks of one cup from a first-frame box through an
  RGB-only video (segment backend ``flow``), shown as a contact sheet (there is no ground truth).
"""

from __future__ import annotations

import json
import shutil
import time
from pathlib import Path

import numpy as np

from rose_usd.core import metrics, se3
from rose_usd.core.pinhole import backproject
from rose_usd.errors import InputError
from rose_usd.pipeline import Options, Pipeline
from rose_usd.usd import paths, tokens
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


def stage_case(case_dir: Path, links: dict[str, Path], rose_toml: str) -> Path:
    """A fresh case folder of symbolic links to a recording's files (name -> file) and the
    rose.toml a user would write beside them (the recordings themselves stay read-only)."""
    shutil.rmtree(case_dir, ignore_errors=True)
    case_dir.mkdir(parents=True)
    for name, target in links.items():
        (case_dir / name).symlink_to(Path(target).resolve())
    (case_dir / "rose.toml").write_text(rose_toml)
    return case_dir


def stage_static_case(folder: Path, case_dir: Path) -> Path:
    """A case folder linking ``folder``'s files, with a rose.toml that declares a static scene
    (``objects = []``): what a user writes next to a recording in which nothing is moved."""
    links = {f.name: f for f in sorted(folder.iterdir()) if f.is_file() and f.name != "rose.toml"}
    return stage_case(case_dir, links, "# a static scene: nothing is moved in this recording\nobjects = []\n")


def evaluate_seven_scenes(folder: Path, out_dir: Path, *, backends: dict | None = None, scene: bool = True) -> dict:
    """Capture (and the scene mesh) on a 7-Scenes sequence: camera APE/RPE after rigid alignment,
    gravity error, and the scene mesh against a TSDF fusion of the same depth with the recorded poses."""
    folder, out_dir = Path(folder), Path(out_dir)
    truth, gravity = read_seven_scenes_truth(folder)
    case_dir = stage_static_case(folder, out_dir / "runs" / "case")
    run_dir = out_dir / "runs" / "out"
    chosen = {"capture": "rgbd", "segment": "classical", "scene": "tsdf"} | (backends or {})
    pipe = Pipeline(case_dir, run_dir, Options(backends=chosen, force=True))
    t0 = time.perf_counter()
    pipe.run("capture")
    wall = time.perf_counter() - t0
    stage = open_stage(run_dir / "rose.usda")
    track = read_camera(stage, paths.CAMERA, len(truth))
    align = metrics.align_poses(track.world_from_cv, truth)
    est = np.einsum("ij,njk->nik", align, track.world_from_cv)
    ape, rpe = metrics.ape(est, truth), metrics.rpe(est, truth)
    up = align[:3, :3] @ np.array([0.0, 0.0, 1.0])
    gravity_err = float(np.degrees(np.arccos(np.clip(up @ -gravity, -1.0, 1.0))))
    prov = read_provenance(layer_file(run_dir, "world")) or {}
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
        "gravity_source": stage.GetPrimAtPath(paths.WORLD).GetAttribute(tokens.WORLD_GRAVITY_SOURCE).Get(),
        "capture_results": prov.get("results"),
        "capture_warnings": prov.get("warnings", []),
    }
    if scene:
        t0 = time.perf_counter()
        pipe.run("scene")
        result["segment_scene_wall_time_s"] = round(time.perf_counter() - t0, 1)
        result |= _scene_against_recorded(folder, run_dir, truth, align, out_dir)
    (out_dir / "real-7scenes.json").write_text(json.dumps(result, indent=1, default=float) + "\n")
    _plot(out_dir, est, truth, ape.translation_m)
    return result


def _scene_against_recorded(
    folder: Path, run_dir: Path, truth: np.ndarray, align: np.ndarray, out_dir: Path, *, every: int = 10
) -> dict:
    """The scene stage's collider, moved into the recorded frame by the camera alignment, against a
    TSDF fusion (same voxel size) of all recorded depth frames with the recorded poses. Per sampled
    frame both surfaces are ray cast through the same pixels and compared as point sets (symmetric
    Chamfer); the reference's points are also measured to the collider's surface."""
    from rose_usd.case.layout import load_case
    from rose_usd.core.watertight import collider_problems
    from rose_usd.geometry.mesh import self_intersects
    from rose_usd.render.lighting import Lighting
    from rose_usd.render.scene import RenderItem, RenderScene
    from rose_usd.scene.config import SceneConfig
    from rose_usd.scene.fused import Fusion
    from rose_usd.usd.geom import MeshData, read_mesh

    case = load_case(folder)
    K = case.K()
    cfg = SceneConfig()
    stage = open_stage(run_dir / "rose.usda")
    col = read_mesh(stage.GetPrimAtPath(paths.SCENE_COLLISION), world=True)
    problems = collider_problems(col.vertices, col.faces)
    intersects = self_intersects(col.vertices, col.faces)
    ours_v = se3.transform_points(align, col.vertices)

    reference = Fusion(cfg.tsdf.voxel_m, cfg.tsdf.depth_max_m)
    for t in range(len(truth)):
        reference.add(case.depth_m(t), case.rgb(t), K, truth[t])
    ref_v, ref_f = reference.mesh()
    ref_pts, _ = reference.points()

    ours = RenderScene([RenderItem("ours", MeshData(ours_v, col.faces, color=(0.5, 0.5, 0.5)))], Lighting.unlit())
    ref = RenderScene([RenderItem("reference", MeshData(ref_v, ref_f, color=(0.5, 0.5, 0.5)))], Lighting.unlit())
    rng = np.random.default_rng(0)
    per_frame, frames = [], list(range(0, len(truth), every))
    for t in frames:
        d_ours, _ = ours.depth_and_labels(truth[t], K, case.width, case.height)
        d_ref, _ = ref.depth_and_labels(truth[t], K, case.width, case.height)
        v, u = np.nonzero(d_ref > 0)
        keep = rng.choice(len(v), size=min(len(v), 40_000), replace=False)
        v, u = v[keep], u[keep]
        hit = d_ours[v, u] > 0
        p_ref = se3.transform_points(truth[t], backproject(u, v, d_ref[v, u], K))
        p_ours = se3.transform_points(truth[t], backproject(u[hit], v[hit], d_ours[v[hit], u[hit]], K))
        per_frame.append(metrics.chamfer_points(p_ours, p_ref))
    to_ours = metrics.SurfaceDistance(ours_v, col.faces)(
        ref_pts[rng.choice(len(ref_pts), size=min(len(ref_pts), 200_000), replace=False)]
    )
    _picture(out_dir, ours, ref, truth[len(truth) // 2], K, case.width, case.height)
    return {
        "scene_collider_problems": problems,
        "scene_self_intersections": intersects,
        "scene_triangles": int(len(col.faces)),
        "scene_chamfer_visible_mean_m": float(np.mean(per_frame)),
        "scene_chamfer_visible_max_m": float(np.max(per_frame)),
        "scene_chamfer_frames": frames,
        "reference_to_scene_mean_m": float(to_ours.mean()),
        "reference_to_scene_p90_m": float(np.percentile(to_ours, 90)),
        "reference_points": int(len(ref_pts)),
    }


def _picture(out_dir: Path, ours, ref, world_from_cv: np.ndarray, K: np.ndarray, width: int, height: int) -> None:
    """Depth of the reconstructed collider and of the reference fusion from one recorded camera."""
    from rose_usd.bench.report import pyplot

    plt = pyplot()

    d_ours, _ = ours.depth_and_labels(world_from_cv, K, width, height)
    d_ref, _ = ref.depth_and_labels(world_from_cv, K, width, height)
    both = (d_ours > 0) & (d_ref > 0)
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.4), dpi=100, layout="constrained")
    hi = float(np.percentile(d_ref[d_ref > 0], 99))
    for ax, d, title in (
        (axes[0], d_ref, "fusion with recorded poses"),
        (axes[1], d_ours, "rose scene collider (aligned)"),
    ):
        ax.imshow(np.where(d > 0, d, np.nan), vmin=0, vmax=hi, cmap="viridis")
        ax.set_title(f"{title}: depth", fontsize=10)
        ax.axis("off")
    diff = np.where(both, 1e3 * (d_ours - d_ref), np.nan)
    im = axes[2].imshow(diff, vmin=-30, vmax=30, cmap="coolwarm")
    axes[2].set_title("collider minus reference (mm)", fontsize=10)
    axes[2].axis("off")
    fig.colorbar(im, ax=axes[2], shrink=0.8)
    fig.savefig(out_dir / "real-7scenes-scene.png")
    plt.close(fig)


def _plot(out_dir: Path, est: np.ndarray, truth: np.ndarray, ape_m: np.ndarray) -> None:
    from rose_usd.bench.report import pyplot

    plt = pyplot()

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


CUPS_PROMPT = "Cup=0:568,290,740,544"
"""The middle cup of 02_cups.mp4's first frame (1280x720), as a user would draw it."""


def evaluate_sam2_cups(folder: Path, out_dir: Path, *, prompt: str = CUPS_PROMPT, every: int = 20) -> dict:
    """The flow segment backend on sam2-cups/02_cups.mp4 from a first-frame box; a contact sheet
    of the cup's (green) and the interactor's (blue) masks every ``every`` frames."""
    folder, out_dir = Path(folder), Path(out_dir)
    video = folder / "02_cups.mp4"
    if not video.is_file():
        raise InputError("no 02_cups.mp4", path=folder, hint="give the sam2-cups folder of ../shared/data/real")
    case_dir = stage_case(
        out_dir / "runs" / "case",
        {"video.mp4": video},
        '# three identical red cups shuffled by hand\n[[objects]]\nname = "Cup"\ncategory = "cup"\n',
    )
    run_dir = out_dir / "runs" / "out"
    pipe = Pipeline(
        case_dir, run_dir, Options(backends={"segment": "flow"}, settings={"segment": {"prompts": prompt}}, force=True)
    )
    t0 = time.perf_counter()
    pipe.run("segment")
    wall = time.perf_counter() - t0
    stage = open_stage(run_dir / "rose.usda")
    prim = stage.GetPrimAtPath(paths.object_mask("Cup"))
    n = pipe.case.n_frames
    conf = np.array([prim.GetAttribute(tokens.MASKS_CONFIDENCE).Get(t) for t in range(n)], dtype=float)
    pixels = np.array([prim.GetAttribute(tokens.MASKS_VISIBLE_PIXELS).Get(t) for t in range(n)], dtype=float)
    prov = read_provenance(layer_file(run_dir, "masks")) or {}
    result = {
        "video": str(video.name),
        "frames": n,
        "size": [pipe.case.width, pipe.case.height],
        "prompt": prompt,
        "segment_wall_time_s": round(wall, 1),
        "frames_per_s": round(n / wall, 2),
        "working_size": (prov.get("results") or {}).get("working_size"),
        "cup_visible_fraction_mean": float(conf.mean()),
        "frames_cup_found": int(np.count_nonzero(pixels > 0)),
        "frames_cup_below_half_visible": [int(t) for t in np.flatnonzero(conf < 0.5)],
    }
    (out_dir / "real-sam2-cups.json").write_text(json.dumps(result, indent=1) + "\n")
    _contact_sheet(pipe.case, run_dir, n, every, conf, out_dir / "real-sam2-cups.png")
    return result


def _contact_sheet(case, run_dir: Path, n: int, every: int, conf: np.ndarray, path: Path, *, tile_w: int = 320) -> None:
    import cv2

    from rose_usd.io.images import read_mask

    tiles = []
    for t in range(0, n, every):
        rgb = case.rgb(t)
        over = rgb.copy()
        over[read_mask(run_dir / "masks" / "Interactor" / f"{t:06d}.png")] = (40, 80, 255)
        over[read_mask(run_dir / "masks" / "Cup" / f"{t:06d}.png")] = (0, 230, 0)
        tile = cv2.addWeighted(rgb, 0.45, over, 0.55, 0)
        tile = cv2.resize(
            tile, (tile_w, int(round(tile_w * rgb.shape[0] / rgb.shape[1]))), interpolation=cv2.INTER_AREA
        )
        cv2.putText(
            tile,
            f"frame {t}  visible {conf[t]:.2f}",
            (6, 20),
            cv2.FONT_HERSHEY_SIMPLEX,
            0.5,
            (255, 255, 0),
            1,
            cv2.LINE_AA,
        )
        tiles.append(tile)
    cols = 4
    while len(tiles) % cols:
        tiles.append(np.zeros_like(tiles[0]))
    sheet = np.vstack([np.hstack(tiles[i : i + cols]) for i in range(0, len(tiles), cols)])
    cv2.imwrite(str(path), cv2.cvtColor(sheet, cv2.COLOR_RGB2BGR))
