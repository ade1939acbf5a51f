"""A strip of frames of the collect stage's robot following the object's path, rendered with
Mitsuba from the reconstructed camera (top row) and from the same camera moved back along its
view (bottom row), with the robot's proxy geometry drawn (the gate's re-render leaves it out).

    python benchmarks/collect_strip.py OUT/rose.usda -o strip.png [--frames 6] [--back-m 0.8]
"""

from __future__ import annotations

import argparse

import numpy as np
from PIL import Image
from pxr import Usd, UsdGeom

from rose_usd.layers.world import read_cameras
from rose_usd.render.from_usd import _animated, read_lighting
from rose_usd.render.scene import RenderItem, RenderScene
from rose_usd.usd.geom import read_mesh
from rose_usd.usd.stage import open_stage


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("stage")
    ap.add_argument("-o", "--output", required=True)
    ap.add_argument("--frames", type=int, default=6)
    ap.add_argument("--back-m", type=float, default=0.8, help="how far the second row's camera is moved back [m]")
    ap.add_argument("--spp", type=int, default=8)
    args = ap.parse_args()
    picture, frames = strip(args.stage, frames=args.frames, back_m=args.back_m, spp=args.spp)
    Image.fromarray(picture).save(args.output)
    print(f"wrote {args.output}: frames {frames}")


def strip(stage_path, *, frames: int = 6, back_m: float = 0.8, spp: int = 8) -> tuple[np.ndarray, list[int]]:
    """The strip (H, W, 3) uint8 of ``frames`` frames spread over the stage's time codes, and which."""
    stage = open_stage(stage_path)
    n = int(stage.GetEndTimeCode()) + 1
    items, animated = [], {}
    purposes = {UsdGeom.Tokens.default_, UsdGeom.Tokens.render, UsdGeom.Tokens.proxy}
    for prim in stage.Traverse():
        if not prim.IsA(UsdGeom.Mesh) or UsdGeom.Imageable(prim).ComputePurpose() not in purposes:
            continue
        name = f"m{len(items)}"
        if _animated(prim):
            pose = np.asarray(UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(Usd.TimeCode(0)), dtype=float).T
            items.append(RenderItem(name, read_mesh(prim, world=False), pose=pose))
            animated[name] = prim
        else:
            items.append(RenderItem(name, read_mesh(prim, world=True), moves=False))
    scene = RenderScene(items, read_lighting(stage))
    camera = read_cameras(stage, n)
    rows = [[], []]
    picked = np.linspace(0, n - 1, frames).round().astype(int)
    for t in picked:
        for name, prim in animated.items():
            pose = UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(Usd.TimeCode(int(t)))
            scene.set_pose(name, np.asarray(pose, dtype=float).T)
        near = camera.world_from_cv[t]
        far = near.copy()
        far[:3, 3] -= back_m * near[:3, 2]  # back along the optical axis (OpenCV +z looks forward)
        for row, pose in zip(rows, (near, far), strict=True):
            row.append(scene.render_srgb8(pose, camera.K[t], camera.width, camera.height, spp=spp, seed=int(t)))
    return np.concatenate([np.concatenate(row, axis=1) for row in rows], axis=0), picked.tolist()


if __name__ == "__main__":
    main()
