"""Real RGB-only clips through every stage, as a user runs them (auto backends, a prompt, a size or
a mesh where known), with pictures; and 7-Scenes' colour frames alone against its recorded poses.

    python benchmarks/real_rgb.py clip ../shared/data/real/r2r2r-mug-rgb/rgb/mug_demo.mp4 \\
        --name Mug --category mug --box 450,695,765,1010 -o benchmarks/results/real-rgb-mug
        [--size 0.12] [--mesh PATH] [--cam-k PATH] [--truth OB_IN_CAM_DIR] [--every 12]
        [--set STAGE.FIELD=VALUE ...] [--runs /tmp/real-rgb-runs]
    python benchmarks/real_rgb.py 7scenes ../shared/data/real/7scenes-redkitchen-600-799 \\
        -o benchmarks/results/real-rgb-7scenes [--no-k]

``clip`` links the clip (and cam_K.txt, the mesh) into ``--runs``/cases/<OUT's name> with a
rose.toml (name, category, size_m, mesh, prompt), runs ``rose-usd reconstruct CASE -o
--runs/<OUT's name> --no-validate`` and then ``rose-usd validate`` on it (two processes, as a user
types them; their output in ``<run>.reconstruct.log`` and ``<run>.validate.log``), and writes into
OUT: ``masks.jpg`` (the masks over the video), ``object.jpg`` (the fitted object at its trajectory
pose, shaded, with its mask's outline in red), ``gate.jpg`` (the gate's input / re-render / SSIM
map, downscaled) and ``result.json``: the command, its exit status and error line, each stage's
backend and wall time (from its layer), validation, the gate, the world's scale and its cues, the
object's shape, and (``--truth``: FoundationPose-style ob_in_cam poses) the pose error per frame;
the silhouette IoU of the object against its masks over every frame and while it is off its
frame-0 pose (``held``). A stage that fails leaves what ran before it reported. ``7scenes`` runs
capture alone on the colour frames (given K, or none with ``--no-k``) and reports the camera error
after a similarity alignment (the map has no metric scale) and the gravity error. Nothing under
``--runs`` is committed (the clip's frames and masks).
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np

from rose_usd import registry
from rose_usd.bench.coverage import CARRIED_WINDOW, silhouette_ious
from rose_usd.case.layout import load_case
from rose_usd.core import se3
from rose_usd.layers.objects import object_paths
from rose_usd.layers.trajectory import object_poses
from rose_usd.layers.world import read_cameras, read_scale
from rose_usd.render.sheets import mask_sheet, object_sheet
from rose_usd.usd import paths
from rose_usd.usd.stage import layer_file, open_stage, read_provenance


def stage_clip(clip: Path, folder: Path, args) -> Path:
    """A case folder linking the clip (a video file or an rgb/ folder), with cam_K.txt, the mesh
    and a rose.toml."""
    if folder.exists():
        shutil.rmtree(folder)
    folder.mkdir(parents=True)
    clip = clip.resolve()
    if clip.is_dir():
        (folder / "rgb").symlink_to(clip)
    else:
        (folder / f"video{clip.suffix.lower()}").symlink_to(clip)
    if args.cam_k:
        (folder / "cam_K.txt").symlink_to(Path(args.cam_k).resolve())
    lines = ["[[objects]]", f'name = "{args.name}"', f'category = "{args.category}"']
    if args.size:
        lines.append(f"size_m = {args.size}")
    if args.mesh:
        mesh = Path(args.mesh).resolve()
        (folder / "mesh").mkdir()
        (folder / "mesh" / mesh.name).symlink_to(mesh)
        lines.append(f'mesh = "mesh/{mesh.name}"')
    box = ", ".join(args.box.split(","))
    lines.append(f"prompt = {{ frame = {args.frame}, box = [{box}] }}")
    (folder / "rose.toml").write_text("\n".join(lines) + "\n")
    return folder


def pose_errors(stage, case, name: str, truth_dir: Path) -> dict:
    """Per frame, the object's camera-frame pose against FoundationPose-style truth (the mesh's frame)."""
    n = case.n_frames
    poses, cams = object_poses(stage, name, n), read_cameras(stage, n)
    trans, rot = [], []
    for t in range(n):
        path = truth_dir / f"{case.frame_name(t)}.txt"
        if not path.is_file():
            continue
        est = se3.invert(cams.world_from_cv[t]) @ poses[t]
        gt = np.loadtxt(path)
        trans.append(float(np.linalg.norm(est[:3, 3] - gt[:3, 3])))
        rot.append(float(se3.rotation_angle_deg(est[:3, :3].T @ gt[:3, :3])))
    trans, rot = np.array(trans), np.array(rot)
    return {
        "frames": len(trans),
        "translation_mm": {"mean": 1e3 * trans.mean(), "median": 1e3 * np.median(trans), "max": 1e3 * trans.max()},
        "rotation_deg": {"mean": rot.mean(), "median": np.median(rot), "max": rot.max()},
        "within_1cm_5deg": int(np.sum((trans <= 0.01) & (rot <= 5.0))),
        "per_frame_mm_deg": [[round(1e3 * a, 1), round(b, 2)] for a, b in zip(trans, rot)],
    }


def _cli(command: list[str], log: Path) -> tuple[int, float, str]:
    """Run a rose-usd command as a user would: (exit status, wall time [s], its last error line)."""
    t0 = time.perf_counter()
    with log.open("w") as out:
        rc = subprocess.run(command, stdout=out, stderr=subprocess.STDOUT).returncode
    wall = time.perf_counter() - t0
    lines = [line for line in log.read_text().splitlines() if line.strip()]
    errors = [line for line in lines if line.lower().startswith(("error", "traceback"))]
    return rc, wall, (errors[-1] if errors else (lines[-1] if lines else "")) if rc else ""


def _small_jpeg(src: Path, dst: Path, width: int) -> None:
    """A copy of an image at most ``width`` wide, as JPEG (the committed pictures stay small)."""
    image = cv2.imread(str(src))
    if image.shape[1] > width:
        image = cv2.resize(image, (width, round(width * image.shape[0] / image.shape[1])), interpolation=cv2.INTER_AREA)
    cv2.imwrite(str(dst), image, [cv2.IMWRITE_JPEG_QUALITY, 85])


def run_clip(args) -> dict:
    """``rose-usd reconstruct CASE -o RUN --no-validate`` then ``rose-usd validate RUN`` (the
    user's path, auto backends), then what the layers say, and pictures."""
    out, run_dir = args.output, args.runs / args.output.name
    out.mkdir(parents=True, exist_ok=True)
    exe = str(Path(sys.executable).with_name("rose-usd"))
    if args.no_run:
        # the pictures and numbers again from the earlier run, its command's record kept
        case_dir = args.runs / "cases" / args.output.name
        earlier = json.loads((out / "result.json").read_text())
        keys = ("clip", "rose_toml", "command", "exit_status", "error", "wall_time_s")
        result = {k: earlier[k] for k in keys}
        rc = result["exit_status"]
    else:
        case_dir = stage_clip(args.clip, args.runs / "cases" / args.output.name, args)
        if run_dir.exists() and not args.keep:
            shutil.rmtree(run_dir)
        command = [exe, "reconstruct", str(case_dir), "-o", str(run_dir), "--no-validate"]
        for item in args.set or []:
            command += ["--set", item]
        rc, wall, error = _cli(command, run_dir.with_suffix(".reconstruct.log"))
        result = {
            "clip": str(args.clip),
            "rose_toml": (case_dir / "rose.toml").read_text(),
            "command": " ".join(["rose-usd"] + command[1:]),
            "exit_status": rc,
            "error": error or None,
            "wall_time_s": round(wall, 1),
        }
    case = load_case(case_dir, registry.STAGE_NAMES)
    result.update(frames=case.n_frames, size=[case.width, case.height])
    stages = {}
    for layer in reversed(paths.LAYER_ORDER):
        prov = read_provenance(layer_file(run_dir, layer)) if layer_file(run_dir, layer).is_file() else None
        if prov:
            stages[prov.get("stage", layer)] = {
                "backend": prov.get("backend"),
                "wall_time_s": round(float(prov.get("wall_time_s", 0.0)), 1),
            }
    result["stages"] = stages
    result["complete"] = rc == 0 and all(name in stages for name in registry.STAGE_NAMES if name != "collect")
    if (run_dir / "rose.usda").is_file():
        vrc, vwall, verror = _cli([exe, "validate", str(run_dir / "rose.usda")], run_dir.with_suffix(".validate.log"))
        result["validate"] = {
            "exit_status": vrc,
            "ok": vrc == 0,
            "error": verror or None,
            "wall_time_s": round(vwall, 1),
        }
    gate_json = run_dir / "report" / "gate.json"
    if gate_json.is_file():
        g = json.loads(gate_json.read_text())
        result["gate"] = {
            "passed": g["passed"],
            "ssim_mean": round(g["ssim_mean"], 4),
            "ssim_min": round(g["ssim_min"], 4),
            "ssim_threshold": g.get("ssim_threshold"),
            "frames_rendered": g.get("frames_rendered"),
            "physics": g.get("physics"),
            "physics_passed": g.get("physics_passed"),
            "geometry_problems": g.get("geometry_problems"),
        }
        _small_jpeg(run_dir / "report" / "compare.png", out / "gate.jpg", 1600)
    if not (run_dir / "rose.usda").is_file():
        (out / "result.json").write_text(json.dumps(result, indent=1, default=float) + "\n")
        return result
    stage = open_stage(run_dir / "rose.usda")
    if "capture" in stages:
        world = read_provenance(layer_file(run_dir, "world")) or {}
        scale = read_scale(stage)
        result["world"] = {
            "scale_source": scale.source,
            "scale_uncertainty": round(scale.uncertainty, 4),
            "cues": {k: {"meters_per_unit": round(v[0], 5), "sigma": round(v[1], 4)} for k, v in scale.cues.items()},
            "results": {k: v for k, v in (world.get("results") or {}).items() if k != "scale_cues"},
            "warnings": world.get("warnings", []),
        }
    if "object" in stages:
        obj = read_provenance(layer_file(run_dir, "object")) or {}
        result["object"] = (obj.get("results") or {}).get("objects", {}).get(args.name)
    if "trajectory" in stages:
        traj = read_provenance(layer_file(run_dir, "trajectory")) or {}
        result["trajectory"] = (traj.get("results") or {}).get("objects", {}).get(args.name)
        if args.name in object_paths(stage):
            result["silhouette_iou"] = silhouette_ious(stage, case, args.name)
            if args.truth:
                result["pose_error"] = pose_errors(stage, case, args.name, Path(args.truth))
    if "segment" in stages:
        mask_sheet(case, run_dir, run_dir / "masks.png", every=args.every, tile_w=320, cols=6)
        _small_jpeg(run_dir / "masks.png", out / "masks.jpg", 1920)
    if "trajectory" in stages:
        object_sheet(case, run_dir, run_dir / "object.png", every=args.every, tile_w=320, cols=6)
        _small_jpeg(run_dir / "object.png", out / "object.jpg", 1920)
    (out / "result.json").write_text(json.dumps(result, indent=1, default=float) + "\n")
    return result


def _shown(argv: list[str]) -> list[str]:
    """The command line as the README shows it: without --no-run, and without --note's paragraph
    (it is the README's first)."""
    out, skip = [], False
    for a in argv:
        if skip or a == "--no-run":
            skip = False
            continue
        if a == "--note":
            skip = True
            continue
        out.append(a)
    return out


def write_readme(result: dict, out: Path, argv: list[str], note: str | None) -> None:
    """OUT/README.md: the commands, the per-stage times, validation, the gate and the pictures."""
    clip = Path(result["clip"])
    folder = clip.parent if clip.suffix else clip
    folder = folder.parent if folder.name == "rgb" else folder
    lines = [f"# {out.name}: {folder.name} ({clip.name}), RGB only", ""]
    if note:
        lines += [note, ""]
    lines += [
        "Made by (from the repository root, the run folder is not committed):",
        "",
        "```sh",
        "python " + " ".join(_shown(argv)),
        "```",
        "",
        "which wrote this rose.toml beside links to the clip (and cam_K.txt, the mesh where given):",
        "",
        "```toml",
        result["rose_toml"].rstrip(),
        "```",
        "",
        "and ran, as a user would:",
        "",
        "```sh",
        result["command"],
        f"rose-usd validate {result['command'].split(' -o ')[1].split()[0]}/rose.usda",
        "```",
        "",
        f"{result.get('frames')} frames, {result.get('size', ['?', '?'])[0]}x{result.get('size', ['?', '?'])[1]};"
        f" reconstruct exit status {result['exit_status']}, {result['wall_time_s']} s wall on 2 CPU cores"
        " shared with another job.",
        "",
    ]
    if result.get("error"):
        lines += [f"Error: `{result['error']}`", ""]
    lines += ["| stage | backend | wall time [s] |", "|---|---|---|"]
    for stage, info in result.get("stages", {}).items():
        lines.append(f"| {stage} | {info['backend']} | {info['wall_time_s']} |")
    lines.append("")
    complete = "yes" if result.get("complete") else "no"
    v = result.get("validate")
    valid = "not run" if v is None else ("pass" if v["ok"] else f"FAIL: {v['error']}")
    lines += [f"- complete stage: {complete}; `rose-usd validate`: {valid}"]
    g = result.get("gate")
    if g:
        checks = g.get("physics") or []
        rest = ", ".join(f"{p['name']} {1e3 * p['max_displacement_m']:.2f} mm from frame {p['frame']}" for p in checks)
        rest = rest or "none checked (no object is seen at rest)"
        lines.append(
            f"- gate SSIM mean {g['ssim_mean']:.3f} (min {g['ssim_min']:.3f}, {g['frames_rendered']} frames;"
            f" issue 27's bar 0.60, the gate's own threshold {g['ssim_threshold']}); rest drift {rest};"
            f" gate {'passed' if g['passed'] else 'failed'}"
        )
    w = result.get("world")
    if w:
        r = w["results"]
        lines.append(
            f"- capture: {r.get('camera_motion')} camera, gravity from {r.get('gravity')}"
            f" (+-{r.get('gravity_uncertainty_deg')} deg), scale from {w['scale_source']}"
            f" (+-{100 * w['scale_uncertainty']:.0f} %), camera {r.get('camera_height_m')} m above the support"
        )
    o = result.get("object")
    if o:
        lines.append(
            f"- object: {o.get('shape')} ({o.get('primitive') or 'mesh'}), size {o.get('size_m')} m,"
            f" silhouette IoU {o.get('silhouette_iou')}"
        )
    t = result.get("trajectory")
    if t and t.get("tracked") == 0:
        lines.append(
            "- trajectory: never tracked (no frame's fit reached the IoU floor, min_iou): held where it started"
        )
    elif t:
        lines.append(
            f"- trajectory: held {t.get('held')}, fitted {t.get('fitted')}, lost {t.get('lost')} frames,"
            f" {t.get('too_fast', 0)} too fast, turn searches {t.get('turn_searches')},"
            f" mean confidence {t.get('confidence_mean')}"
        )
    iou = result.get("silhouette_iou")
    if iou:
        a, h = iou["all"], iou["held"]
        fmt = lambda x: "-" if x is None else f"{x:.3f}"  # noqa: E731
        carry = iou.get("carried")
        lines.append(
            f"- object silhouette vs its masks (outside the hand): mean IoU {fmt(a['mean'])} over {a['frames']}"
            f" frames; {fmt(h['mean'])} over the {h['frames']} frames it is off its first pose"
            + (
                f"; {fmt(carry['mean'])} (median {fmt(carry['median'])}) over the {carry['frames']} frames"
                f" within {CARRIED_WINDOW} of one where it moves (carried)"
                if carry
                else ""
            )
        )
    pe = result.get("pose_error")
    if pe:
        lines.append(
            f"- pose vs ground truth ({pe['frames']} frames): translation mean {pe['translation_mm']['mean']:.1f} mm,"
            f" median {pe['translation_mm']['median']:.1f} mm; rotation mean {pe['rotation_deg']['mean']:.1f} deg,"
            f" median {pe['rotation_deg']['median']:.1f} deg; within 1 cm and 5 deg: {pe['within_1cm_5deg']} frames"
        )
    warnings = (w or {}).get("warnings") or []
    if warnings:
        lines += ["", "Warnings in the world layer:", ""] + [f"- {x}" for x in warnings]
    pictures = [
        ("masks.jpg", "the object's mask (green) and the hand's (blue) over the video"),
        ("object.jpg", "the fitted object at its trajectory pose (shaded), its mask's outline in red"),
        ("gate.jpg", "the gate: input, Mitsuba re-render of the stage, SSIM map"),
    ]
    present = [(f, d) for f, d in pictures if (out / f).is_file()]
    if present:
        lines += ["", "Pictures:", ""] + [f"- `{f}`: {d}" for f, d in present]
    lines += ["", "All numbers: `result.json`."]
    (out / "README.md").write_text("\n".join(lines) + "\n")


def run_seven_scenes(args) -> dict:
    """Capture (sfm) on 7-Scenes' colour frames alone: camera error after a similarity alignment, gravity."""
    from rose_usd.bench.real import read_seven_scenes_truth
    from rose_usd.pipeline import Options, Pipeline

    folder = args.clip.resolve()
    truth, gravity = read_seven_scenes_truth(folder)
    case_dir = args.runs / args.output.name / ("case-no-k" if args.no_k else "case")
    if case_dir.exists():
        shutil.rmtree(case_dir)
    (case_dir / "rgb").mkdir(parents=True)
    for f in sorted(folder.glob("frame-*.color.jpg")):
        (case_dir / "rgb" / f.name).symlink_to(f)
    if not args.no_k:
        (case_dir / "cam_K.txt").symlink_to(folder / "camera-intrinsics.txt")
    (case_dir / "rose.toml").write_text("# a static scene: nothing is moved in this recording\nobjects = []\n")
    run_dir = case_dir.parent / ("out-no-k" if args.no_k else "out")
    t0 = time.perf_counter()
    from rose_usd.cli import _parse_assignments

    settings = _parse_assignments(args.set or [], "--set")
    Pipeline(case_dir, run_dir, Options(force=True, settings=settings)).run("capture")
    wall = time.perf_counter() - t0
    stage = open_stage(run_dir / "rose.usda")
    cams = read_cameras(stage, len(truth))
    est = cams.world_from_cv
    a, b = est[:, :3, 3], truth[:, :3, 3]
    ma, mb = a.mean(axis=0), b.mean(axis=0)
    u, s, vt = np.linalg.svd((b - mb).T @ (a - ma))
    d = np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))])
    rot = u @ d @ vt
    scale = float((s * np.diag(d)).sum() / ((a - ma) ** 2).sum())
    err = np.linalg.norm((scale * (rot @ (a - ma).T)).T + mb - b, axis=1)
    rot_err = [se3.rotation_angle_deg((rot @ e[:3, :3]).T @ g[:3, :3]) for e, g in zip(est, truth)]
    up = rot @ np.array([0.0, 0.0, 1.0])
    gravity_err = float(np.degrees(np.arccos(np.clip(up @ -gravity, -1.0, 1.0))))
    # the same through the rotation that best maps our cameras' orientations onto the recording's
    # (the positions' Sim(3) tilts with any bend of a nearly flat path)
    u, _, vt = np.linalg.svd(np.einsum("nij,nkj->ik", truth[:, :3, :3], est[:, :3, :3]))
    rot_only = u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt
    up_r = rot_only @ np.array([0.0, 0.0, 1.0])
    gravity_err_r = float(np.degrees(np.arccos(np.clip(up_r @ -gravity, -1.0, 1.0))))
    rot_err_r = [se3.rotation_angle_deg((rot_only @ e[:3, :3]).T @ g[:3, :3]) for e, g in zip(est, truth)]
    # the same without the alignment: gravity seen from each camera, ours against the recording's
    down_ours = np.einsum("nji,j->ni", est[:, :3, :3], [0.0, 0.0, -1.0])
    down_true = np.einsum("nji,j->ni", truth[:, :3, :3], gravity)
    in_camera = np.degrees(np.arccos(np.clip((down_ours * down_true).sum(axis=1), -1.0, 1.0)))
    prov = read_provenance(layer_file(run_dir, "world")) or {}
    scenes = {}
    if args.scene:
        from rose_usd.bench.real import _scene_against_recorded

        # our world into the recording's: the similarity that maps our camera centres onto its
        align = np.eye(4)
        align[:3, :3] = scale * rot
        align[:3, 3] = mb - scale * rot @ ma
        for backend in args.scene:
            t1 = time.perf_counter()
            Pipeline(case_dir, run_dir, Options(settings=settings, backends={"scene": backend})).run("scene")
            seconds = round(time.perf_counter() - t1, 1)
            out = args.output / f"scene-{backend}"
            out.mkdir(parents=True, exist_ok=True)
            score = _scene_against_recorded(folder, run_dir, truth, align, out)
            scene_prov = read_provenance(layer_file(run_dir, "scene")) or {}
            results = {k: v for k, v in (scene_prov.get("results") or {}).items() if k != "reference_frames"}
            scenes[backend] = {"wall_time_s": seconds, **score, "scene_results": results}
    result = {
        "sequence": folder.name,
        "frames": len(truth),
        "intrinsics": "self-calibrated from a 60 deg guess" if args.no_k else "camera-intrinsics.txt",
        "capture_wall_time_s": round(wall, 1),
        "camera_error_after_sim3_m": {"mean": err.mean(), "rmse": float(np.sqrt((err**2).mean())), "max": err.max()},
        "camera_rotation_error_deg": {"mean": float(np.mean(rot_err)), "max": float(np.max(rot_err))},
        "sim3_scale": scale,
        "gravity_error_deg": gravity_err,
        "gravity_error_rotation_aligned_deg": gravity_err_r,
        "camera_rotation_error_rotation_aligned_deg": {
            "mean": float(np.mean(rot_err_r)),
            "max": float(np.max(rot_err_r)),
        },
        "alignments_apart_deg": se3.rotation_angle_deg(rot.T @ rot_only),
        "path_spread_m": np.sqrt(np.linalg.svd(b - mb, compute_uv=False) ** 2 / len(b)).tolist(),
        "gravity_in_camera_error_deg": {
            "frame_0": float(in_camera[0]),
            "mean": float(in_camera.mean()),
            "max": float(in_camera.max()),
        },
        "capture_results": {k: v for k, v in (prov.get("results") or {}).items() if k != "scale_cues"},
        "capture_warnings": prov.get("warnings", []),
        "scenes": scenes,
    }
    args.output.mkdir(parents=True, exist_ok=True)
    name = "result-no-k.json" if args.no_k else "result.json"
    (args.output / name).write_text(json.dumps(result, indent=1, default=float) + "\n")
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("what", choices=("clip", "7scenes"))
    parser.add_argument("clip", type=Path)
    parser.add_argument("-o", "--output", type=Path, required=True)
    parser.add_argument("--name", default="Object")
    parser.add_argument("--category", default="generic")
    parser.add_argument("--box", help="x0,y0,x1,y1 on the prompt frame [px]")
    parser.add_argument("--frame", type=int, default=0)
    parser.add_argument("--size", type=float, help="the object's largest dimension [m]")
    parser.add_argument("--mesh", help="the object's mesh file")
    parser.add_argument("--cam-k", help="cam_K.txt")
    parser.add_argument("--truth", help="a folder of ob_in_cam poses (NNNN.txt, the mesh's frame)")
    parser.add_argument("--every", type=int, default=12)
    parser.add_argument("--set", action="append")
    parser.add_argument("--no-k", action="store_true", help="7scenes: no intrinsics (self-calibrated)")
    parser.add_argument(
        "--scene",
        action="append",
        help="7scenes: also run the scene stage with this backend (stereo, plane; repeatable) and score"
        " its collider against a fusion of the recorded depth",
    )
    parser.add_argument("--keep", action="store_true", help="keep an earlier run (current layers are skipped)")
    parser.add_argument(
        "--no-run", action="store_true", help="clip: only read the earlier run again (OUT's result.json)"
    )
    parser.add_argument("--runs", type=Path, default=Path("/tmp/real-rgb-runs"))
    parser.add_argument("--note", help="clip: a paragraph for OUT/README.md (what the clip is, what failed)")
    args = parser.parse_args()
    result = run_clip(args) if args.what == "clip" else run_seven_scenes(args)
    if args.what == "clip":
        write_readme(result, args.output, sys.argv, args.note)
    print(json.dumps(result, indent=1, default=float)[:4000])


if __name__ == "__main__":
    main()
