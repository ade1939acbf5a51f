"""Would the tracked frames improve the fused object? For each object of a classical (``fusion``
object backend, ``tracker`` or any trajectory) run, the object stage's cleaning and completion are
run twice on the same masked depth: on the resting frames the stage fused, and on those plus every
``--stride``-th frame after them, each mapped into the frame-0 pose by the run's own trajectory
(W_0 W_t^-1, points and their directions to the camera). Both meshes are scored by the shape
Chamfer of the evaluation (rigid ICP onto the true mesh). Prints a table and draws the two side
by side.

    python benchmarks/tracked_fusion.py RESULTS_DIR -o tracked-fusion.png [--cases CASES] [--stride 3]

RESULTS_DIR is a ``rose-usd bench run`` output whose ``runs/`` were kept, in a mode with sensor
depth (rgbd); CASES the generated cases it ran on (default benchmarks/cases). This is the
measurement behind the object stage not fusing tracked frames (issue 7, item 4)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from rose_usd import registry
from rose_usd.bench.evaluate import prim_poses, register_mesh
from rose_usd.bench.report import pyplot
from rose_usd.bench.runner import kept_runs, kept_runs_parser
from rose_usd.case.gt import GroundTruth
from rose_usd.case.layout import load_case
from rose_usd.core import metrics, se3
from rose_usd.io.images import read_mask
from rose_usd.layers.world import metric_depth_reader
from rose_usd.object.config import ObjectConfig
from rose_usd.object.fusion import complete
from rose_usd.object.rest import clean_cloud, free_space_carve, masked_points
from rose_usd.usd import paths
from rose_usd.usd.camera import read_camera
from rose_usd.usd.stage import layer_file, open_stage, read_provenance


class RunView:
    """What both completions of a run's objects read, read once: its stage's cameras, the camera
    registration onto the true world, and the metric depth."""

    def __init__(self, case_dir: Path, run: Path):
        self.run, self.gt = run, GroundTruth(case_dir / "gt")
        self.case = load_case(case_dir, registry.STAGE_NAMES)
        self.stage = open_stage(run / "rose.usda")
        self.cams = read_camera(self.stage, paths.CAMERA, self.gt.n_frames)
        self.align = metrics.align_poses(self.cams.world_from_cv, self.gt.camera_poses())
        self.depth_of = metric_depth_reader(self.stage, self.case)


def fused_shape_chamfer(
    view: RunView, name: str, frames: list[int], last_rest: int, support: float, cfg: ObjectConfig
) -> float:
    """The shape Chamfer [m] of the object completed from ``frames``, each mapped into the
    frame-0 pose by the run's trajectory; the resting frames (up to ``last_rest``) carve."""
    cams, depth_of = view.cams, view.depth_of
    poses = prim_poses(view.stage, paths.object_path(name), view.gt.n_frames)
    parts, views = [], []
    for t in frames:
        mask = read_mask(view.run / "masks" / name / f"{t:06d}.png") > 0
        if mask.sum() < 50:
            continue
        to_rest = poses[0] @ se3.invert(poses[t])  # the object's motion since frame 0, undone
        pts, cols = masked_points(depth_of(t), mask, view.case.rgb(t), cams.K[t], cams.world_from_cv[t])
        pts = se3.transform_points(to_rest, pts)
        toward = se3.transform_points(to_rest, cams.world_from_cv[t][None, :3, 3])[0] - pts
        parts.append((pts, cols, (toward / np.linalg.norm(toward, axis=1, keepdims=True)).astype(np.float32)))
        if t <= last_rest:
            views.append((depth_of(t), cams.K[t], cams.world_from_cv[t]))
    pts, cols, toward = (np.concatenate(p) for p in zip(*parts))
    pts, cols, toward, often = clean_cloud(pts, cols, toward, cfg.voxel_m, support + cfg.support_gap_m)
    keep = free_space_carve(pts, views[:: max(1, len(views) // 16)])
    vertices, faces, _, _ = complete(pts[keep], toward[keep], often[keep], support, cfg)
    return register_mesh(
        se3.transform_points(view.align, vertices), faces, view.gt, name, np.random.default_rng(0)
    ).shape_chamfer()


def compare(case_dir: Path, run: Path, stride: int, cfg: ObjectConfig = ObjectConfig()):
    """Per fused object: (name, resting frames, tracked frames added, shape Chamfer [m] from the
    resting frames, from those and the tracked frames)."""
    view = RunView(case_dir, run)
    facts = read_provenance(layer_file(run, "object"))["results"]["objects"]
    for obj in view.gt.objects:
        if "completion" not in facts.get(obj.name, {}):
            continue  # not fused (an imported mesh)
        first, last = facts[obj.name]["rest_frames"]
        support = facts[obj.name]["support_height_m"]
        rest, after = list(range(first, last + 1)), list(range(last + 1, view.gt.n_frames, stride))
        only = fused_shape_chamfer(view, obj.name, rest, last, support, cfg)
        both = fused_shape_chamfer(view, obj.name, rest + after, last, support, cfg) if after else float("nan")
        yield obj.name, len(rest), len(after), only, both


def main() -> None:
    ap = kept_runs_parser(__doc__, cases=Path(__file__).resolve().parent / "cases")
    ap.add_argument("--stride", type=int, default=3, help="every this many frames after the rest (default 3)")
    args = ap.parse_args()
    plt = pyplot()
    rows = []
    print("| case | object | resting frames | tracked frames added | shape Chamfer mm, resting | with tracked |")
    print("|---|---|---|---|---|---|")
    for entry, case_dir, run in kept_runs(args.results, args.cases):
        for name, n_rest, n_after, rest, both in compare(case_dir, run, args.stride):
            rows.append((f"{entry['case'].rsplit('-', 1)[0]}\n{name}", rest, both))
            print(
                f"| {entry['case']} | {name} | {n_rest} | {n_after} | {1e3 * rest:.2f} | {1e3 * both:.2f} |", flush=True
            )
    x = np.arange(len(rows))
    fig, ax = plt.subplots(figsize=(max(6, 0.8 * len(rows)), 3.6))
    ax.bar(x - 0.2, [1e3 * r[1] for r in rows], 0.4, label="resting frames (what the object stage fuses)")
    ax.bar(x + 0.2, [1e3 * r[2] for r in rows], 0.4, label=f"+ tracked frames (one in {args.stride})")
    ax.set_xticks(x, [r[0] for r in rows], fontsize=7)
    ax.set_ylabel("shape Chamfer [mm]")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(args.output, dpi=120)


if __name__ == "__main__":
    main()
