"""A contact sheet of reconstructed objects over the video: for each run, its first frame with the
object layer's meshes projected through the recovered camera (green outline) and the segment
stage's masks (red outline), cropped around the objects.

    python benchmarks/object_fit.py RESULTS_DIR -o sheet.png [--frame 0]

RESULTS_DIR is a ``rose-usd bench run`` output whose ``runs/`` were kept (each run's rose.usda
names its case in the world layer's provenance)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import cv2
import numpy as np

from rose_usd.core.pinhole import silhouette
from rose_usd.io.images import read_mask
from rose_usd.usd import paths
from rose_usd.usd.camera import read_camera
from rose_usd.usd.geom import read_mesh
from rose_usd.usd.stage import layer_file, open_stage, read_provenance


def panel(run: Path, t: int, size: int = 320) -> np.ndarray:
    case = Path(read_provenance(layer_file(run, "world"))["case"])
    stage = open_stage(run / "rose.usda")
    n = len(list((case / "rgb").glob("*.png")))
    cams = read_camera(stage, paths.CAMERA, n)
    image = cv2.imread(str(case / "rgb" / f"{t:06d}.png"))
    h, w = image.shape[:2]
    box = [w, h, 0, 0]
    objects = stage.GetPrimAtPath(paths.OBJECTS)
    for prim in objects.GetChildren() if objects else []:
        mesh = read_mesh(stage.GetPrimAtPath(paths.object_visual(prim.GetName())), world=True)
        sil = silhouette(mesh.vertices, mesh.faces, cams.world_from_cv[t], cams.K[t], w, h)
        mask_file = run / "masks" / prim.GetName() / f"{t:06d}.png"
        for m, color in ((read_mask(mask_file) if mask_file.is_file() else None, (0, 0, 255)), (sil, (0, 220, 0))):
            if m is None or not m.any():
                continue
            contours, _ = cv2.findContours(m.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
            cv2.drawContours(image, contours, -1, color, 1)
            ys, xs = np.nonzero(m)
            box = [min(box[0], xs.min()), min(box[1], ys.min()), max(box[2], xs.max()), max(box[3], ys.max())]
    cx, cy = (box[0] + box[2]) // 2, (box[1] + box[3]) // 2
    half = int(max(box[2] - box[0], box[3] - box[1]) * 0.75) + 10
    x0, y0 = max(cx - half, 0), max(cy - half, 0)
    crop = cv2.resize(
        image[y0 : min(cy + half, h), x0 : min(cx + half, w)], (size, size), interpolation=cv2.INTER_CUBIC
    )
    cv2.putText(crop, run.name, (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1, cv2.LINE_AA)
    return crop


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("results", type=Path)
    parser.add_argument("-o", "--output", type=Path, required=True)
    parser.add_argument("--frame", type=int, default=0)
    parser.add_argument("--columns", type=int, default=5)
    args = parser.parse_args()
    runs = sorted(p for p in (args.results / "runs").iterdir() if (p / "rose.usda").is_file())
    if not runs:
        raise SystemExit(f"{args.results}/runs holds no kept run")
    panels = [panel(r, args.frame) for r in runs]
    while len(panels) % args.columns:
        panels.append(np.zeros_like(panels[0]))
    rows = [np.hstack(panels[i : i + args.columns]) for i in range(0, len(panels), args.columns)]
    cv2.imwrite(str(args.output), np.vstack(rows))
    print(json.dumps({"runs": len(runs), "output": str(args.output)}))


if __name__ == "__main__":
    main()
