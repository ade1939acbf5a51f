"""Time the scene texture's kernel (``geometry.frame_median``) on each device Warp finds, in one
run: a table plane sampled at ``--texels`` points, seen by ``--frames`` cameras circling above it
at ``--size``, every point's median colour over the frames that see it.

    python benchmarks/frame_median_speed.py [--texels 2600000] [--frames 24] [--size 640x480] [-o OUT.json]

Prints and writes, per device: the first call (Warp's kernel load, compiled once into its cache)
and the best of ``--repeat`` calls, and whether every device gave the CPU's colours."""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

import numpy as np


def scene(texels: int, frames: int, width: int, height: int):
    from rose_usd.core import se3
    from rose_usd.geometry.frame_median import FrameStack

    rng = np.random.default_rng(0)
    points = np.column_stack([rng.uniform(-0.6, 0.6, (texels, 2)), np.zeros(texels)])
    normals = np.tile([0.0, 0.0, 1.0], (texels, 1))
    f = 0.9 * width
    K = np.array([[f, 0.0, width / 2], [0.0, f, height / 2], [0.0, 0.0, 1.0]])
    poses, depth = [], np.zeros((frames, height, width), np.float32)
    v, u = np.mgrid[0:height, 0:width]
    for k, yaw in enumerate(np.linspace(0, 2 * np.pi, frames, endpoint=False)):
        eye = np.array([0.7 * np.cos(yaw), 0.7 * np.sin(yaw), 0.8])
        forward = -eye / np.linalg.norm(eye)
        right = np.cross(forward, [0.0, 0.0, 1.0])
        right /= np.linalg.norm(right)
        pose = se3.make_pose(np.column_stack([right, np.cross(forward, right), forward]), eye)
        rays = np.stack([u, v, np.ones_like(u)], axis=-1) @ np.linalg.inv(K).T @ pose[:3, :3].T
        t = -pose[2, 3] / rays[..., 2]
        depth[k] = np.where(t > 0, t, 0.0)  # the camera ray has z = 1, so t is the depth
        poses.append(pose)
    static = rng.uniform(size=(frames, height, width)) > 0.1
    rgb = rng.uniform(size=(frames, height, width, 3)).astype(np.float32)
    stack = FrameStack(np.stack(poses), np.repeat(K[None], frames, axis=0), depth, static, rgb)
    return stack, points, normals


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--texels", type=int, default=2_600_000)
    parser.add_argument("--frames", type=int, default=24)
    parser.add_argument("--size", default="640x480")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("-o", "--output", default=None)
    args = parser.parse_args(argv)
    width, height = (int(x) for x in args.size.split("x"))

    from rose_usd.geometry.frame_median import FrameMedian
    from rose_usd.sim.engine import warp

    wp = warp()
    stack, points, normals = scene(args.texels, args.frames, width, height)
    limits = {"tol_m": 0.01, "rel_tol": 0.02, "min_cos": 0.15, "min_z": 0.05}
    result = {"texels": args.texels, "frames": args.frames, "size": [width, height], "cpus": os.cpu_count()}
    result["devices"] = {}
    reference = None
    for device in [str(d) for d in wp.get_devices()]:
        t0 = time.perf_counter()
        median = FrameMedian(stack, **limits, device=device)
        colors, seen = median(points, normals)
        first = time.perf_counter() - t0
        best = np.inf
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            median(points, normals)
            best = min(best, time.perf_counter() - t0)
        if reference is None:
            reference = (colors, seen)
        row = {
            "first_call_s": round(first, 3),
            "best_s": round(best, 3),
            "seen": int(seen.sum()),
            "same_seen_as_cpu": bool(np.array_equal(seen, reference[1])),
            "max_colour_diff_vs_cpu": float(np.abs(colors - reference[0]).max()),
            "name": wp.get_device(device).name,
        }
        result["devices"][device] = row
        print(device, row, flush=True)
    if args.output:
        with open(args.output, "w") as f:
            json.dump(result, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
