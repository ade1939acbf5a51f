"""Re-render a reconstructed scene from the recovered cameras next to the video.

    python benchmarks/scene_rerender.py CASE OUT -o picture.png [--frames 0,60,120]

CASE is the case folder, OUT the output folder of a run that reached the scene stage. Each row:
the input frame, the scene layer rendered by Mitsuba from that frame's recovered camera (only the
static scene: objects and the hand are not in it), and the SSIM map over the static pixels
(objects and interactor masks left out, as the gate does).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np


def main() -> int:
    from rose_usd.bench.report import pyplot
    from rose_usd.case.layout import load_case
    from rose_usd.gate.ssim import masked_ssim
    from rose_usd.io.images import read_mask
    from rose_usd.render.from_usd import StageRenderer
    from rose_usd.usd import paths
    from rose_usd.usd.camera import read_camera
    from rose_usd.usd.stage import open_stage

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("case")
    ap.add_argument("out")
    ap.add_argument("-o", "--output", required=True)
    ap.add_argument("--frames", default="", help="comma-separated frames (default: 3 spread over the video)")
    ap.add_argument("--spp", type=int, default=16)
    args = ap.parse_args()
    plt = pyplot()
    case, out = load_case(args.case), Path(args.out)
    stage = open_stage(out / "rose.usda")
    n = case.n_frames
    frames = [int(f) for f in args.frames.split(",")] if args.frames else [0, n // 2, n - 1]
    cams = read_camera(stage, paths.CAMERA, n)
    renderer = StageRenderer(stage)
    fig, axes = plt.subplots(
        len(frames), 3, figsize=(12, 3.1 * len(frames)), dpi=100, layout="constrained", squeeze=False
    )
    for row, t in zip(axes, frames):
        original = case.rgb(t)
        rendered = renderer.scene.render_srgb8(cams.world_from_cv[t], cams.K[t], case.width, case.height, spp=args.spp)
        moving = np.zeros(original.shape[:2], bool)
        for track in sorted(p for p in (out / "masks").iterdir() if p.is_dir()):  # sheet.jpg beside them
            moving |= read_mask(track / f"{t:06d}.png")
        score, ssim_map = masked_ssim(original, rendered, moving)
        row[0].imshow(original)
        row[0].set_title(f"input, frame {t}", fontsize=9)
        row[1].imshow(rendered)
        row[1].set_title("scene layer re-rendered (Mitsuba, recovered camera)", fontsize=9)
        row[2].imshow(np.where(moving, np.nan, ssim_map), vmin=0, vmax=1, cmap="magma")
        row[2].set_title(f"SSIM over static pixels: {score:.3f}", fontsize=9)
        for ax in row:
            ax.axis("off")
    fig.savefig(args.output)
    print(f"wrote {args.output}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
