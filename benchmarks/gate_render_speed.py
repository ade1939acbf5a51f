"""Time the gate's re-render alone, per Mitsuba variant: every frame of a finished run's composed
stage, rendered from the stage's own cameras exactly as the gate renders it (same scene builder,
spp and per-frame seed), without the SSIM, the physics and the report. It needs only usd-core,
Mitsuba and Dr.Jit, so it runs where the rest of the pipeline's packages are not installed (the
GPU machine). Three frames (first, middle, last) are saved to compare variants pixel by pixel.

    python benchmarks/gate_render_speed.py RUN_OUT [--variant cuda_ad_rgb] [--spp 8] -o result.json
    python benchmarks/gate_render_speed.py RUN_OUT --fixed -o result.json

With ``--fixed`` (a run whose camera does not move) each frame is rendered both ways, in turn:
whole, then by ``render.fixed_view.FixedView`` (only the window the objects are in), with labels
as the gate renders them; the result has both times and how far the two images differ.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("run", type=Path, help="a finished run's output folder (rose.usda, layers/)")
    parser.add_argument("--variant", help="Mitsuba variant (default: rose_usd's automatic choice)")
    parser.add_argument("--spp", type=int, default=None, help="samples per pixel (default: the gate's)")
    parser.add_argument("--frames", type=int, default=None, help="render the first N frames (default all)")
    parser.add_argument("--fixed", action="store_true", help="time whole renders against FixedView's, alternated")
    parser.add_argument("-o", "--output", type=Path, required=True, help="JSON result; frames go beside it (.npz)")
    args = parser.parse_args(argv)
    if args.variant:
        os.environ["ROSE_MITSUBA_VARIANT"] = args.variant

    import numpy as np
    from pxr import Usd

    from rose_usd.gate.config import GateConfig
    from rose_usd.layers.world import read_cameras
    from rose_usd.render.from_usd import StageRenderer
    from rose_usd.usd.stage import layer_file, read_time_info

    spp = args.spp or GateConfig().spp
    t_open = time.perf_counter()
    n = read_time_info(args.run).n_frames
    stage = Usd.Stage.Open(str(args.run / "rose.usda"))
    # the gate runs before collect: render the stage as it saw it, without the robot's layer
    robot = layer_file(args.run, "robot")
    if robot.is_file():
        stage.MuteLayer(str(robot.resolve()))
    camera = read_cameras(stage, n)
    t_build = time.perf_counter()
    renderer = StageRenderer(stage)
    build_s = time.perf_counter() - t_build
    frames = list(range(n if args.frames is None else min(n, args.frames)))
    if args.fixed:
        result = compare_fixed(renderer, camera, frames, spp)
        args.output.parent.mkdir(parents=True, exist_ok=True)
        args.output.write_text(json.dumps(result, indent=1) + "\n")
        print(json.dumps(result))
        return 0
    keep = {frames[0], frames[len(frames) // 2], frames[-1]}
    saved, times = {}, []
    for t in frames:
        t0 = time.perf_counter()
        renderer.pose_at(t)
        img = renderer.scene.render_srgb8(
            camera.world_from_cv[t], camera.K[t], camera.width, camera.height, spp=spp, seed=t
        )
        times.append(time.perf_counter() - t0)
        if t in keep:
            saved[f"frame{t:06d}"] = img
    total = time.perf_counter() - t_open
    result = {
        "variant": renderer.scene.variant,
        "frames": len(frames),
        "size": [camera.width, camera.height],
        "spp": spp,
        "open_s": round(t_build - t_open, 3),
        "scene_build_s": round(build_s, 3),
        "first_frame_s": round(times[0], 3),
        "render_s": round(sum(times), 3),
        "render_after_first_s": round(sum(times[1:]), 3),
        "per_frame_after_first_s": round(sum(times[1:]) / max(1, len(times) - 1), 4),
        "total_s": round(total, 3),
        "cpus": os.cpu_count(),
        "python": sys.version.split()[0],
    }
    args.output.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(args.output.with_suffix(".npz"), **saved)
    args.output.write_text(json.dumps(result, indent=1) + "\n")
    print(json.dumps(result))
    return 0


def compare_fixed(renderer, camera, frames: list[int], spp: int) -> dict:
    """Every frame rendered whole and by FixedView in turn (sRGB and labels, as the gate does):
    the seconds of each, and how the images and labels differ."""
    import numpy as np

    from rose_usd.render.fixed_view import FixedView, fixed_view_applies

    if not fixed_view_applies(renderer.scene, camera.world_from_cv[frames], camera.K[frames]):
        raise SystemExit("--fixed: the run's camera moves, or its scene has point lights")
    args = (camera.world_from_cv[frames[0]], camera.K[frames[0]], camera.width, camera.height)
    view = FixedView(renderer.scene, *args, spp=spp, moving=renderer.animated)
    whole_s, fixed_s, differs, label_differs, shares = [], [], [], [], []
    for t in frames:
        renderer.pose_at(t)
        t0 = time.perf_counter()
        img, labels = renderer.scene.render_srgb8_and_labels(*args, spp=spp, seed=t)
        t1 = time.perf_counter()
        img_f, labels_f = view.render_srgb8_and_labels(seed=t)
        t2 = time.perf_counter()
        whole_s.append(t1 - t0)
        fixed_s.append(t2 - t1)
        shares.append(view.window_share())
        differs.append(float((np.abs(img.astype(int) - img_f).max(axis=-1) > 2).mean()))
        label_differs.append(float((labels != labels_f).mean()))
    return {
        "variant": renderer.scene.variant,
        "frames": len(frames),
        "size": [camera.width, camera.height],
        "spp": spp,
        "whole_s": round(sum(whole_s), 3),
        "fixed_s": round(sum(fixed_s), 3),
        "whole_over_fixed": round(sum(whole_s) / sum(fixed_s), 2),
        "fixed_first_frame_s": round(fixed_s[0], 3),
        "window_share_mean": round(float(np.mean(shares)), 4),
        "pixels_over_2_levels_apart_mean": round(float(np.mean(differs)), 5),
        "labels_apart_mean": round(float(np.mean(label_differs)), 5),
        "cpus": os.cpu_count(),
    }


if __name__ == "__main__":
    sys.exit(main())
