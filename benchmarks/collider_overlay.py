"""The scene collider drawn over the video: its triangles projected through the recovered cameras,
those standing above the support (a vertex over ``--above`` m) in yellow, the rest in blue.

    python benchmarks/collider_overlay.py --run OUT CASE [--run OUT CASE ...] -o PNG
        [--frames 0,40] [--above 0.01]

OUT is a run's output folder (its ``rose.usda``), CASE the case it was made from: a row per run,
a tile per frame.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np

from rose_usd.case.layout import load_case
from rose_usd.core import se3
from rose_usd.core.pinhole import project
from rose_usd.layers.scene import scene_collider
from rose_usd.layers.world import read_cameras
from rose_usd.usd.stage import open_stage

BLUE, YELLOW = (255, 128, 0), (0, 255, 255)


def tiles(out: Path, case_dir: Path, frames: list[int], above_m: float) -> np.ndarray:
    """One row: the collider over each of ``frames`` (BGR)."""
    case = load_case(case_dir)
    stage = open_stage(out / "rose.usda")
    vertices, faces = scene_collider(stage)
    cameras = read_cameras(stage, case.n_frames)
    standing = (vertices[faces][:, :, 2] > above_m).any(axis=1)
    row = []
    for t in frames:
        img = cv2.cvtColor(case.rgb(t), cv2.COLOR_RGB2BGR)
        cam = se3.transform_points(se3.invert(cameras.world_from_cv[t]), vertices)
        front = cam[:, 2] > 0.05
        u, v = project(np.where(front[:, None], cam, 1.0), cameras.K[t])
        uv = np.column_stack([u, v])
        for tri, up in zip(faces, standing, strict=True):
            if front[tri].all():
                cv2.polylines(img, [np.round(uv[tri]).astype(np.int32)], True, YELLOW if up else BLUE, 1, cv2.LINE_AA)
        row.append(img)
    return np.concatenate(row, axis=1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--run", nargs=2, action="append", metavar=("OUT", "CASE"), required=True)
    parser.add_argument("-o", "--output", type=Path, required=True)
    parser.add_argument("--frames", default="0")
    parser.add_argument("--above", type=float, default=0.01)
    args = parser.parse_args()
    frames = [int(f) for f in args.frames.split(",")]
    rows = [tiles(Path(out), Path(case), frames, args.above) for out, case in args.run]
    width = max(r.shape[1] for r in rows)
    rows = [cv2.copyMakeBorder(r, 0, 0, 0, width - r.shape[1], cv2.BORDER_CONSTANT) for r in rows]
    args.output.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(args.output), np.concatenate(rows, axis=0), [cv2.IMWRITE_JPEG_QUALITY, 75])


if __name__ == "__main__":
    main()
