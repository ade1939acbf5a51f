"""A real RGB-D clip through every stage, as a user runs it (auto backends, a prompt at most), with
pictures: the masks over the video, the fitted object over the video and the gate's compare.

    python benchmarks/real_rgbd.py ../shared/data/real/cups-rgbd-upside-down \\
        --name Ball --box 268,136,308,180 -o benchmarks/results/real-cups-rgbd/ball \\
        [--category cup] [--crop x0,y0,x1,y1] [--every 12] [--runs /tmp/real-runs]

Without ``--box`` the object is unprompted (found where the hand goes); ``--name`` given more
than once names several unprompted objects. Writes into OUT:
``masks.png``, ``masks-count.jpg`` (the object's mask outline, enlarged, every 6th frame: what
its masks are judged on), ``object.png``, ``gate.png`` (the gate's compare picture),
``collect.jpg`` (the best robot rollout, ``collect_strip.py``, half size) and ``result.json`` (plan,
per-stage times, gate, validation, the object's size, volume, mass and watertightness, the
largest jump of its trajectory between frames, the frames its mask is empty, collect's outcome). The
reconstruction itself goes to ``--runs``/<OUT's name> (not committed: it holds the clip's masks).
"""

from __future__ import annotations

import argparse
import json
import shutil
from pathlib import Path

import numpy as np
from collect_strip import strip
from PIL import Image

from rose_usd import reconstruct, registry
from rose_usd.bench.coverage import silhouette_ious
from rose_usd.case.layout import load_case
from rose_usd.layers.masks import read_masks
from rose_usd.layers.objects import object_paths, visual_mesh
from rose_usd.layers.trajectory import object_poses
from rose_usd.render.sheets import mask_sheet, object_sheet, outline_sheet
from rose_usd.usd import paths


def stage_case(clip: Path, folder: Path, names: list[str], category: str, box: list[int] | None) -> Path:
    """A case folder linking the clip's rgb/ and depth/ (and cam_K.txt if any), with a rose.toml
    naming ``names`` (the box prompts the first)."""
    if folder.exists():
        shutil.rmtree(folder)
    folder.mkdir(parents=True)
    for part in ("rgb", "depth", "cam_K.txt"):
        if (clip / part).exists():
            (folder / part).symlink_to((clip / part).resolve())
    prompt = f"\nprompt = {{ frame = 0, box = [{', '.join(str(v) for v in box)}] }}" if box else ""
    entries = [
        f'[[objects]]\nname = "{name}"\ncategory = "{category}"{prompt if k == 0 else ""}\n'
        for k, name in enumerate(names)
    ]
    (folder / "rose.toml").write_text("\n".join(entries))
    return folder


def describe(run_dir: Path, case, name: str) -> dict:
    """The object's mesh, mass, trajectory and mask figures from the written stage."""
    from rose_usd.usd.stage import open_stage

    stage = open_stage(run_dir / "rose.usda")
    n = case.n_frames
    out: dict = {}
    if name in object_paths(stage):
        import trimesh

        mesh = visual_mesh(stage, name)
        tm = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)
        body = stage.GetPrimAtPath(paths.object_path(name))
        mass = body.GetAttribute("physics:mass").Get()
        poses = object_poses(stage, name, n)
        steps = np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1)
        out.update(
            watertight=bool(tm.is_watertight),
            extent_m=[round(float(v), 4) for v in tm.bounding_box_oriented.primitive.extents],
            volume_cm3=round(float(tm.volume) * 1e6, 2) if tm.is_watertight else None,
            mass_kg=None if mass is None else round(float(mass), 4),
            trajectory_max_step_m=round(float(steps.max()), 4),
            trajectory_max_step_frame=int(np.argmax(steps)) + 1,
            trajectory_travel_m=round(float(steps.sum()), 3),
            silhouette_iou=silhouette_ious(stage, case, name),
        )
    masks = read_masks(stage, n, (case.height, case.width))
    if name in masks.names:
        px = masks.visible_pixels(name)
        out.update(
            mask_frames_empty=int(np.sum(px == 0)), mask_px_median=int(np.median(px[px > 0])) if np.any(px) else 0
        )
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("clip", type=Path)
    parser.add_argument("-o", "--output", type=Path, required=True)
    parser.add_argument(
        "--name", action="append", help="object name (default Object); repeat it for several unprompted objects"
    )
    parser.add_argument("--category", default="generic")
    parser.add_argument("--box", help="x0,y0,x1,y1 on frame 0 [px] (none: unprompted)")
    parser.add_argument("--crop", help="x0,y0,x1,y1 of the pictures [px]")
    parser.add_argument("--every", type=int, default=12)
    parser.add_argument("--count-every", type=int, default=6, help="frames between masks-count.jpg's windows")
    parser.add_argument("--runs", type=Path, default=Path("/tmp/real-runs"))
    args = parser.parse_args()
    box = [int(v) for v in args.box.split(",")] if args.box else None
    crop = tuple(int(v) for v in args.crop.split(",")) if args.crop else None
    work = args.runs / args.output.name
    names = args.name or ["Object"]
    if box and len(names) > 1:
        parser.error("--box prompts one object: give one --name with it")
    case_dir = stage_case(args.clip, work / "case", names, args.category, box)
    run_dir = work / "out"
    if run_dir.exists():
        shutil.rmtree(run_dir)
    rec = reconstruct(case_dir, run_dir, check=False)
    ran = {o.name for o in rec.outcomes if o.status == "ran"}
    case = load_case(case_dir, registry.STAGE_NAMES)
    out = args.output
    out.mkdir(parents=True, exist_ok=True)
    result = {
        "clip": args.clip.name,
        "prompt": {"frame": 0, "box": box} if box else None,
        "plan": rec.plan,
        "stages": {o.name: {"status": o.status, "wall_time_s": round(o.wall_time_s, 1)} for o in rec.outcomes},
        "wall_time_s": round(rec.wall_time_s, 1),
        "error": rec.error,
        "validation_ok": None if rec.validation is None else rec.validation.ok,
    }
    if rec.gate is not None and "gate" in ran:
        g = rec.gate
        result["gate"] = {
            "passed": g.passed,
            "ssim_mean": round(g.ssim_mean, 4),
            "ssim_min": round(g.ssim_min, 4),
            "rest_displacement_mm": {k: round(1e3 * v, 2) for k, v in g.rest_displacement_m.items()},
        }
        shutil.copyfile(run_dir / "report" / "compare.png", out / "gate.png")
    for stale in ("masks.png", "masks-count.jpg", "object.png", "gate.png", "collect.jpg"):
        if stale == "gate.png" and "gate" in ran:
            continue
        (out / stale).unlink(missing_ok=True)
    if "segment" in ran:
        mask_sheet(case, run_dir, out / "masks.png", every=args.every, crop=crop, tile_w=320, cols=6)
        outline_sheet(case, run_dir, out / "masks-count.jpg", names[0], every=args.count_every)
        if len(names) == 1:
            result["object"] = describe(run_dir, case, names[0])
        else:
            result["objects"] = {name: describe(run_dir, case, name) for name in names}
    if "trajectory" in ran:
        object_sheet(case, run_dir, out / "object.png", every=args.every, crop=crop, tile_w=320, cols=6)
    if "collect" in ran and rec.collect is not None:
        c = rec.collect
        result["collect"] = {
            "object": c.object_name,
            "status": c.status,
            "rollouts": c.rollouts,
            "successes": c.successes,
            "failures": sorted({r for r, ok in zip(c.rollout_reason, c.rollout_success, strict=True) if not ok}),
        }
        if c.best_rollout >= 0:  # the robot along the path, through the camera and from 0.8 m behind it
            picture, _ = strip(run_dir / "rose.usda")
            Image.fromarray(picture).resize((picture.shape[1] // 2, picture.shape[0] // 2)).save(
                out / "collect.jpg", quality=85
            )
    (out / "result.json").write_text(json.dumps(result, indent=1) + "\n")
    print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
