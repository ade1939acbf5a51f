"""Vertical sections of reconstructed objects against the true ones: for each run and object, the
mesh registered onto the true mesh as the shape Chamfer registers it (rigid ICP, no scale) and
cut by the plane through the true object's vertical axis and its x axis (a mug's handle side),
the true section in black, the reconstruction's in red. Shows what a Chamfer number hides: a
closed top, a missing cavity, a wall too thin.

    python benchmarks/object_section.py RESULTS_DIR -o sections.png [--cases CASES] [--only mug]

RESULTS_DIR is a ``rose-usd bench run`` output whose ``runs/`` were kept; CASES the generated
cases it ran on (default benchmarks/cases)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

from rose_usd.bench.evaluate import register_object
from rose_usd.bench.report import pyplot
from rose_usd.bench.runner import kept_runs, kept_runs_parser
from rose_usd.case.gt import GroundTruth
from rose_usd.core import metrics, se3
from rose_usd.usd import paths
from rose_usd.usd.camera import read_camera
from rose_usd.usd.stage import open_stage


def section_mm(vertices: np.ndarray, faces: np.ndarray) -> list[np.ndarray]:
    """The mesh's section by the plane y = 0, as polylines of (x, z) in mm."""
    cut = trimesh.Trimesh(vertices, faces, process=False).section(plane_origin=[0, 0, 0], plane_normal=[0, 1, 0])
    return [] if cut is None else [1e3 * d[:, [0, 2]] for d in cut.discrete]


def sections(case_dir: Path, run: Path, seed: int = 0):
    """Per object: (name, true polylines, reconstructed polylines), both in the true object frame."""
    rng = np.random.default_rng(seed)
    gt = GroundTruth(case_dir / "gt")
    stage = open_stage(run / "rose.usda")
    align = metrics.align_poses(read_camera(stage, paths.CAMERA, gt.n_frames).world_from_cv, gt.camera_poses())
    for obj in gt.objects:
        if not stage.GetPrimAtPath(paths.object_path(obj.name)):
            continue
        reg = register_object(stage, gt, align, obj.name, rng)
        true_pose, true_mesh = gt.object_poses(obj.name)[0], gt.object_mesh(obj.name)
        local = se3.transform_points(se3.invert(true_pose) @ reg.correction, reg.rec_world0)
        yield obj.name, section_mm(true_mesh.vertices, true_mesh.faces), section_mm(local, reg.rec_faces)


def main() -> None:
    ap = kept_runs_parser(__doc__, cases=Path(__file__).resolve().parent / "cases")
    ap.add_argument("--only", default=None, help="only cases whose name contains this")
    args = ap.parse_args()
    plt = pyplot()
    panels = []
    for case, case_dir, run in kept_runs(args.results, args.cases, args.only):
        name = case["case"]
        scores = {o["name"]: o for o in (case.get("score") or {}).get("objects") or []}
        for obj, true_lines, rec_lines in sections(case_dir, run):
            panels.append((f"{name} {obj}", true_lines, rec_lines, scores.get(obj, {}).get("shape_chamfer_m")))
    if not panels:
        raise SystemExit(f"{args.results}: no run with an object to draw")
    cols = min(4, len(panels))
    rows = (len(panels) + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(3.6 * cols, 3.4 * rows), squeeze=False)
    for ax, (title, true_lines, rec_lines, shape) in zip(axes.flat, panels):
        for line in true_lines:
            ax.plot(line[:, 0], line[:, 1], "k-", lw=1.2)
        for line in rec_lines:
            ax.plot(line[:, 0], line[:, 1], "r-", lw=0.9)
        ax.set_aspect("equal")
        ax.set_title(title + ("" if shape is None else f"\nshape Chamfer {1e3 * shape:.2f} mm"), fontsize=8)
        ax.tick_params(labelsize=7)
    for ax in axes.flat[len(panels) :]:
        ax.axis("off")
    fig.suptitle("section through the true axis, x-z plane, mm: true (black), reconstructed (red)", fontsize=9)
    fig.tight_layout()
    args.output.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.output, dpi=110)
    print(f"wrote {args.output} ({len(panels)} objects)")


if __name__ == "__main__":
    main()
