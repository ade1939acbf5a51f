"""RGB-D camera tracking that does not drift the way frame-to-frame odometry does.

Every frame is registered to the current keyframe (dense photometric + geometric RGB-D odometry,
Open3D's multi-scale Hybrid method with robust Huber losses), so errors do not accumulate from
frame to frame. Keyframes are also registered to up to ``keyframe_links`` earlier keyframes
(always including the first one while it still overlaps), and a pose graph over the keyframes
(Open3D's global optimization, no loop detection) spreads the remaining error. Non-keyframes ride
on their keyframe's optimized pose.

The photometric term is used only where geometry alone is degenerate (``method = "auto"``):
casual tabletop videos are mostly one big plane, along which point-to-plane ICP slides, while
real RGB-D sensors often have color and depth registered only approximately, which biases a
photometric term. A keyframe's geometry is degenerate when its surface normals do not span all
directions: the smallest eigenvalue of their scatter matrix, relative to the largest, is below
``min_normal_spread`` (typical values: a tabletop, 0.01-0.05; the 7-Scenes kitchen, 0.39-0.47).
The rgbd backend asks for the photometric term on every keyframe (``method = "hybrid"``) where
the colour is registered to the depth (``geometry.registration.edge_alignment``).
Moving parts (the object, the hand) and invalid depth are outliers for the robust losses and the
depth-difference gate; pixels can also be masked out explicitly.

``track_on_one_cpu`` runs the tracking in a fresh process bound to one CPU until Open3D has
started its thread pool: Open3D's odometry sums its normal equations in parallel in an order that
changes from run to run, and the poses differed by about 1e-5 per call, enough to move every
later stage; with one thread they repeat bit for bit. (Binding the running process does not do
it: Open3D's pool keeps the size it started with.) The process then gets its CPUs back, and a
second thread reads and decodes the next frames while Open3D registers this one.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np

from rose_usd.core import se3
from rose_usd.core.pinhole import backproject
from rose_usd.progress import progress


@dataclass(frozen=True)
class TrackingParams:
    downscale: int = 2
    """Track on images downscaled by this factor (2: 640x480 -> 320x240)."""
    keyframe_every: int = 8
    """Start a new keyframe after this many frames at the most."""
    min_fitness: float = 0.55
    """Start a new keyframe when the overlap (fitness) with the current one drops below this."""
    keyframe_links: int = 4
    """Register each keyframe to this many earlier keyframes (the first one included)."""
    depth_max_m: float = 3.0
    """Ignore depth beyond this distance [m]."""
    depth_outlier_m: float = 0.04
    """Depth residuals beyond this are outliers [m]."""
    iterations: tuple[int, int, int] = (30, 20, 10)
    """Odometry iterations per pyramid level."""
    method: str = "auto"
    """"hybrid" (photometric + geometric), "point-to-plane", or "auto": hybrid only where the
    keyframe's geometry is degenerate."""
    min_normal_spread: float = 0.15
    """auto: a keyframe whose normal scatter has a smaller eigenvalue ratio needs the photometric term."""


@dataclass
class TrackResult:
    world_from_camera: np.ndarray
    """Camera poses (OpenCV axes) in the frame of the first camera, (N, 4, 4) [m]."""
    fitness: np.ndarray
    """Overlap of each frame with its keyframe, (N,)."""
    keyframes: list[int]
    keyframe_edges: list[tuple[int, int, float]]
    """(keyframe a, keyframe b, fitness) of every registered keyframe pair."""
    hybrid_keyframes: int = 0
    """Keyframes whose geometry needed the photometric term."""
    normal_spread: float | None = None
    """Median normal spread of the keyframes (auto method)."""


class RgbdTracker:
    """Keyframe RGB-D tracking with a pose graph (see the module docstring)."""

    def __init__(self, K: np.ndarray, width: int, height: int, params: TrackingParams = TrackingParams()):
        import open3d as o3d
        import open3d.core as o3c

        self.o3d, self.o3c = o3d, o3c
        self.params = params
        s = params.downscale
        self.size = (width // s, height // s)
        K_small = np.asarray(K, dtype=float).copy()
        # pixel centers: u_small = (u + 0.5) / s - 0.5
        K_small[0, 0] /= s
        K_small[1, 1] /= s
        K_small[0, 2] = (K[0, 2] + 0.5) / s - 0.5
        K_small[1, 2] = (K[1, 2] + 0.5) / s - 0.5
        self.K = o3c.Tensor(K_small, o3c.Dtype.Float64)
        odo = o3d.t.pipelines.odometry
        self.criteria = [odo.OdometryConvergenceCriteria(i) for i in params.iterations]
        self.loss = odo.OdometryLossParams(params.depth_outlier_m, params.depth_outlier_m * 0.5, 0.1)

    def _image(self, rgb: np.ndarray, depth_m: np.ndarray, mask: np.ndarray | None):
        s = self.params.downscale
        depth = np.where(np.isfinite(depth_m) & (depth_m > 0), depth_m, 0.0).astype(np.float32)
        if mask is not None:
            depth = np.where(mask, 0.0, depth).astype(np.float32)
        if s > 1:
            depth = cv2.resize(depth, self.size, interpolation=cv2.INTER_NEAREST)
            rgb = cv2.resize(rgb, self.size, interpolation=cv2.INTER_AREA)
        o3d, o3c = self.o3d, self.o3c
        return o3d.t.geometry.RGBDImage(
            o3d.t.geometry.Image(o3c.Tensor(np.ascontiguousarray(rgb))), o3d.t.geometry.Image(o3c.Tensor(depth))
        )

    def normal_spread(self, image) -> float:
        """Smallest over largest eigenvalue of the scatter of the surface normals seen in ``image``."""
        o3d = self.o3d
        depth = image.depth.as_tensor().numpy().squeeze()[::2, ::2]
        K = self.K.numpy()
        v, u = np.nonzero((depth > 0) & (depth < self.params.depth_max_m))
        if len(v) < 100:
            return 0.0
        z = depth[v, u]
        u, v = u * 2, v * 2
        points = backproject(u, v, z, K)
        cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
        cloud.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=0.05, max_nn=30))
        normals = np.asarray(cloud.normals)
        ev = np.linalg.eigvalsh(normals.T @ normals / len(normals))
        return float(ev[0] / max(ev[-1], 1e-12))

    def _method_for(self, keyframe_image):
        odo = self.o3d.t.pipelines.odometry
        if self.params.method == "hybrid":
            return odo.Method.Hybrid, None
        if self.params.method == "point-to-plane":
            return odo.Method.PointToPlane, None
        spread = self.normal_spread(keyframe_image)
        return (odo.Method.PointToPlane if spread >= self.params.min_normal_spread else odo.Method.Hybrid), spread

    def _register(self, source, target, init: np.ndarray, method=None) -> tuple[np.ndarray, float, np.ndarray]:
        """T_target<-source, fitness, and the 6x6 information matrix of the registration."""
        odo = self.o3d.t.pipelines.odometry
        o3c = self.o3c
        res = odo.rgbd_odometry_multi_scale(
            source,
            target,
            self.K,
            o3c.Tensor(init),
            1.0,
            self.params.depth_max_m,
            self.criteria,
            method or odo.Method.Hybrid,
            self.loss,
        )
        T = res.transformation.numpy()
        info = odo.compute_odometry_information_matrix(
            source.depth,
            target.depth,
            self.K,
            res.transformation,
            self.params.depth_outlier_m,
            1.0,
            self.params.depth_max_m,
        ).numpy()
        return T, float(res.fitness), info

    def track(
        self, n_frames: int, load: Callable[[int], tuple[np.ndarray, np.ndarray, np.ndarray | None]]
    ) -> TrackResult:
        """Track ``n_frames`` frames; ``load(t)`` returns (rgb uint8, depth [m], mask of pixels to ignore or None)."""
        p = self.params
        images = {}
        rel = np.tile(np.eye(4), (n_frames, 1, 1))  # T_keyframe<-frame
        owner = np.zeros(n_frames, dtype=int)  # keyframe of each frame
        fitness = np.ones(n_frames)
        keyframes = [0]
        kf_pose = {0: np.eye(4)}  # odometry-chained keyframe poses (graph initialization)
        edges: list[tuple[int, int, np.ndarray, np.ndarray, float]] = []
        images[0] = self._image(*load(0))
        methods = {0: self._method_for(images[0])}
        current = 0
        for t in progress(range(1, n_frames), "capture track", total=n_frames - 1):
            image = self._image(*load(t))
            init = rel[t - 1] if owner[t - 1] == current else np.eye(4)
            T, fit, info = self._register(image, images[current], init, methods[current][0])
            rel[t], owner[t], fitness[t] = T, current, fit
            if fit < p.min_fitness or t - current >= p.keyframe_every:
                # t becomes a keyframe: link it to its predecessor and to earlier keyframes
                edges.append((current, t, T, info, fit))
                kf_pose[t] = kf_pose[current] @ T
                earlier = [k for k in keyframes[:-1] if k != current]
                links = ([keyframes[0]] if keyframes[0] != current else []) + earlier[::-1][
                    : max(0, p.keyframe_links - 2)
                ]
                for k in dict.fromkeys(links):
                    guess = se3.invert(kf_pose[k]) @ kf_pose[t]
                    Tk, fk, ik = self._register(image, images[k], guess, methods[k][0])
                    if fk >= p.min_fitness and np.linalg.norm(Tk[:3, 3] - guess[:3, 3]) < 0.05:
                        edges.append((k, t, Tk, ik, fk))
                keyframes.append(t)
                images[t] = image
                methods[t] = self._method_for(image)
                rel[t], owner[t] = np.eye(4), t
                current = t
                # keep only the images the next links can use
                keep = {keyframes[0], *keyframes[-p.keyframe_links :]}
                for k in list(images):
                    if k not in keep:
                        del images[k]
        optimized = self._optimize(keyframes, kf_pose, edges)
        poses = np.array([optimized[owner[t]] @ rel[t] for t in range(n_frames)])
        hybrid = sum(1 for k in keyframes if methods[k][0] == self.o3d.t.pipelines.odometry.Method.Hybrid)
        spreads = [m[1] for m in methods.values() if m[1] is not None]
        return TrackResult(
            poses,
            fitness,
            keyframes,
            [(a, b, f) for a, b, _, _, f in edges],
            hybrid,
            float(np.median(spreads)) if spreads else None,
        )

    def _optimize(self, keyframes: list[int], kf_pose: dict, edges: list) -> dict[int, np.ndarray]:
        reg = self.o3d.pipelines.registration
        if len(keyframes) < 2:
            return kf_pose
        index = {k: i for i, k in enumerate(keyframes)}
        graph = reg.PoseGraph()
        for k in keyframes:
            graph.nodes.append(reg.PoseGraphNode(kf_pose[k]))
        for a, b, T, info, _ in edges:
            # Open3D's edge (source b, target a) holds T_a<-b; consecutive keyframes are certain
            uncertain = index[b] - index[a] > 1
            graph.edges.append(reg.PoseGraphEdge(index[b], index[a], T, info, uncertain=uncertain))
        option = reg.GlobalOptimizationOption(
            max_correspondence_distance=self.params.depth_outlier_m, edge_prune_threshold=0.25, reference_node=0
        )
        reg.global_optimization(
            graph, reg.GlobalOptimizationLevenbergMarquardt(), reg.GlobalOptimizationConvergenceCriteria(), option
        )
        return {k: np.asarray(graph.nodes[index[k]].pose) for k in keyframes}


def can_bind_cpu() -> bool:
    """Whether this platform lets a process choose its CPUs (Linux)."""
    return hasattr(os, "sched_setaffinity")


def track_on_one_cpu(case, frames: list[int], K: np.ndarray, params: TrackingParams) -> TrackResult:
    """``RgbdTracker(K, case.width, case.height, params).track`` over ``frames`` of ``case`` (a
    ``Case``: colour and metric depth as it reads them), in a fresh process whose Open3D thread
    pool starts on the one CPU this process runs on, so that the result repeats bit for bit. The process is ``python -m
    rose_usd.capture.tracking`` (the job pickled on its stdin, the result into a file): unlike a
    multiprocessing child it never imports the caller's script, so a script that calls
    ``rose_usd.reconstruct`` needs no ``if __name__ == "__main__"`` guard."""
    import pickle
    import subprocess
    import sys
    import tempfile

    with tempfile.TemporaryDirectory(prefix="rose-track-") as tmp:
        out = os.path.join(tmp, "result.pickle")
        job = pickle.dumps((os.getpid(), _current_cpu(), case, [int(f) for f in frames], K, params, out))
        # a session of its own: a terminal's Ctrl-C interrupts this process, and subprocess.run
        # then kills it (no second traceback); it dies with this process (die_with_parent)
        command = [sys.executable, "-m", "rose_usd.capture.tracking"]
        done = subprocess.run(command, input=job, check=False, start_new_session=True)
        if done.returncode != 0 or not os.path.isfile(out):
            raise RuntimeError(
                f"the one-CPU tracking process failed (exit status {done.returncode}; its output is above)"
            )
        with open(out, "rb") as f:
            ok, value = pickle.load(f)
    if not ok:
        raise value  # the tracker's own error (an InputError naming a frame, say)
    return value


def _child() -> None:
    """``python -m rose_usd.capture.tracking``: bound to the CPU given, start Open3D's pool (one
    thread), take every CPU back, track, write the result."""
    import pickle
    import sys

    from rose_usd.core.lifetime import die_with_parent

    try:
        parent, cpu, case, frames, K, params, out = pickle.load(sys.stdin.buffer)
    except EOFError:  # the parent ended (Ctrl-C) before it sent the work: nothing to do, nothing to say
        sys.exit(1)
    die_with_parent(parent)
    cpus = os.sched_getaffinity(0)
    _bind_cpu(cpu)  # before Open3D starts its threads
    try:
        _start_open3d_pool()
        os.sched_setaffinity(0, cpus)  # Open3D keeps its one thread; the reader may use another CPU
        result = (True, _track_frames(case, frames, K, params))
    except Exception as exc:  # noqa: BLE001 - handed to the parent, which raises it
        result = (False, exc)
    with open(out, "wb") as f:
        pickle.dump(result, f)


def _current_cpu() -> int | None:
    """The CPU this thread last ran on (Linux: the 39th field of its stat), None if unknown."""
    try:
        with open("/proc/thread-self/stat") as f:
            return int(f.read().rsplit(")", 1)[1].split()[36])
    except (OSError, IndexError, ValueError):
        return None


def _bind_cpu(cpu: int | None) -> None:
    cpus = os.sched_getaffinity(0)
    os.sched_setaffinity(0, {cpu if cpu in cpus else min(cpus)})


def _start_open3d_pool() -> None:
    """One registration of a small textured, wavy surface with itself (a regular system), so that
    Open3D sizes its thread pool now, to the CPUs allowed."""
    rgb = np.random.default_rng(0).integers(0, 255, (32, 32, 3), dtype=np.uint8)
    yy, xx = np.mgrid[0:32, 0:32]
    depth = 1.0 + 0.2 * np.sin(xx / 4.0) + 0.2 * np.cos(yy / 5.0)
    tracker = RgbdTracker(np.array([[32.0, 0, 16], [0, 32.0, 16], [0, 0, 1]]), 32, 32, TrackingParams(downscale=1))
    image = tracker._image(rgb, depth, None)
    tracker._register(image, image, np.eye(4))


def _track_frames(case, frames: list[int], K, params: TrackingParams) -> TrackResult:
    """Track ``frames`` of ``case``, each frame read (on a second thread) while the last registers."""
    from concurrent.futures import ThreadPoolExecutor

    tracker = RgbdTracker(K, case.width, case.height, params)

    def read(i: int):
        return case.rgb(frames[i]), case.depth_m(frames[i]), None

    with ThreadPoolExecutor(max_workers=1) as reader:
        ahead = {0: reader.submit(read, 0)}

        def load(i: int):
            if i + 1 < len(frames):
                ahead[i + 1] = reader.submit(read, i + 1)
            return ahead.pop(i).result()

        return tracker.track(len(frames), load)


if __name__ == "__main__":
    # run the module's own copy (``rose_usd.capture.tracking``), so results pickle under its name
    from rose_usd.capture.tracking import _child as child

    child()
