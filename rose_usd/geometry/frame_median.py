"""The median colour of surface points over the video frames that see them, in one Warp kernel.

Each point is projected into every frame of a ``FrameStack`` and sampled (bilinear, linear colour)
where that frame sees it: in front of the camera and inside the image, on a pixel the frame marks
static, the frame's depth there within ``tol_m + rel_tol * z`` of the point's, and the surface
facing the camera (cos > ``min_cos``). The colour is the per-channel median of those samples,
as ``np.nanmedian`` takes it (the two middle values averaged in float32). One thread a point, on
the CPU (a thread a core, each on its own points) or, where Warp finds one, a CUDA GPU; on the
CPU the result repeats bit for bit. ``median_over_frames`` takes the same median of samples
already taken (8-bit colours and which frames saw each texel: the plane scene's backdrop)."""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from rose_usd.core import se3
from rose_usd.sim.engine import in_chunks


@dataclass(frozen=True)
class FrameStack:
    """The frames a point can be seen in, stacked: camera poses ``world_from_cv`` (F, 4, 4), ``K``
    (F, 3, 3), metric ``depth`` (F, H, W) [m], ``static`` (F, H, W) bool and linear ``rgb``
    (F, H, W, 3)."""

    world_from_cv: np.ndarray
    K: np.ndarray
    depth: np.ndarray
    static: np.ndarray
    rgb: np.ndarray


@functools.cache
def _median():
    from rose_usd.sim.engine import warp

    wp = warp()

    @wp.func
    def median(scratch: wp.array3d(dtype=wp.float32), i: int, c: int):
        """Per channel, the median of point i's c samples (sorted in place)."""
        med = wp.vec3f()
        for ch in range(3):
            for j in range(1, c):  # insertion sort
                x = scratch[i, ch, j]
                m = j - 1
                while m >= 0 and scratch[i, ch, m] > x:
                    scratch[i, ch, m + 1] = scratch[i, ch, m]
                    m -= 1
                scratch[i, ch, m + 1] = x
            hi = scratch[i, ch, c // 2]
            lo = hi
            if c % 2 == 0:
                lo = scratch[i, ch, c // 2 - 1]
            med[ch] = (lo + hi) / wp.float32(2.0)
        return med

    return wp, median


@functools.cache
def _kernel():
    wp, median = _median()

    @wp.kernel
    def frame_median(
        points: wp.array(dtype=wp.vec3d),
        normals: wp.array(dtype=wp.vec3d),
        rot: wp.array(dtype=wp.mat33d),
        trans: wp.array(dtype=wp.vec3d),
        center: wp.array(dtype=wp.vec3d),
        intr: wp.array(dtype=wp.vec4d),
        depth: wp.array3d(dtype=wp.float32),
        still: wp.array3d(dtype=wp.uint8),  # not 'static': a C++ keyword in Warp's generated code
        rgb: wp.array3d(dtype=wp.vec3f),
        tol_m: wp.float64,
        rel_tol: wp.float64,
        min_cos: wp.float64,
        min_z: wp.float64,
        scratch: wp.array3d(dtype=wp.float32),
        out: wp.array(dtype=wp.vec3f),
        count: wp.array(dtype=wp.int32),
    ):
        i = wp.tid()
        p = points[i]
        nrm = normals[i]
        h = depth.shape[1]
        w = depth.shape[2]
        one = wp.float64(1.0)
        c = int(0)  # noqa: UP018 (a Warp variable that the loop mutates is declared typed)
        for k in range(rot.shape[0]):
            cam = rot[k] * p + trans[k]
            z = cam[2]
            if z <= min_z:
                continue
            fu = intr[k][0] * cam[0] / z + intr[k][2]
            fv = intr[k][1] * cam[1] / z + intr[k][3]
            ru = wp.rint(fu)  # the nearest pixel, halves to even as numpy rounds
            rv = wp.rint(fv)
            if ru < wp.float64(0.0) or ru > wp.float64(w - 1) or rv < wp.float64(0.0) or rv > wp.float64(h - 1):
                continue
            u = int(ru)
            v = int(rv)
            if still[k, v, u] == wp.uint8(0):
                continue
            if wp.abs(wp.float64(depth[k, v, u]) - z) > tol_m + rel_tol * z:
                continue
            ray = center[k] - p
            if wp.dot(nrm, ray) <= min_cos * wp.length(ray):
                continue
            uc = wp.clamp(fu, wp.float64(0.0), wp.float64(w - 1))
            vc = wp.clamp(fv, wp.float64(0.0), wp.float64(h - 1))
            u0 = wp.min(int(uc), w - 2)
            v0 = wp.min(int(vc), h - 2)
            a = uc - wp.float64(u0)
            b = vc - wp.float64(v0)
            c00 = rgb[k, v0, u0]
            c01 = rgb[k, v0, u0 + 1]
            c10 = rgb[k, v0 + 1, u0]
            c11 = rgb[k, v0 + 1, u0 + 1]
            for ch in range(3):
                top = wp.float64(c00[ch]) * (one - a) + wp.float64(c01[ch]) * a
                bottom = wp.float64(c10[ch]) * (one - a) + wp.float64(c11[ch]) * a
                scratch[i, ch, c] = wp.float32(top * (one - b) + bottom * b)
            c += 1
        count[i] = c
        if c > 0:
            out[i] = median(scratch, i, c)

    return wp, frame_median


class FrameMedian:
    """``FrameStack`` uploaded once to the device; called on points (N, 3) and their unit normals
    (N, 3), it returns their median linear colours (N, 3) and whether any frame saw them (N,)."""

    def __init__(
        self,
        frames: FrameStack,
        *,
        tol_m: float,
        rel_tol: float,
        min_cos: float,
        min_z: float,
        chunk: int = 200_000,
        device: str | None = None,
    ):
        wp, self._kernel = _kernel()
        self._wp = wp
        self.device = wp.get_device(device) if device else wp.get_preferred_device()
        cv_from_world = se3.invert(frames.world_from_cv)
        K = np.asarray(frames.K, float)

        def up(array, dtype):  # on the CPU, the frames' arrays are used where they lie, not copied
            return wp.array(np.ascontiguousarray(array), dtype=dtype, device=self.device, copy=not self.device.is_cpu)

        self._frames = (
            up(cv_from_world[:, :3, :3], wp.mat33d),
            up(cv_from_world[:, :3, 3], wp.vec3d),
            up(np.asarray(frames.world_from_cv, float)[:, :3, 3], wp.vec3d),
            up(np.stack([K[:, 0, 0], K[:, 1, 1], K[:, 0, 2], K[:, 1, 2]], axis=1), wp.vec4d),
            up(np.asarray(frames.depth, np.float32), wp.float32),
            up(np.ascontiguousarray(frames.static, bool).view(np.uint8), wp.uint8),
            up(np.asarray(frames.rgb, np.float32), wp.vec3f),
        )
        self._limits = (float(tol_m), float(rel_tol), float(min_cos), float(min_z))
        self.n_frames = len(cv_from_world)
        self.chunk = chunk

    def __call__(self, points: np.ndarray, normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        out = np.zeros((len(points), 3))
        seen = np.zeros(len(points), bool)

        def run(a: int, b: int) -> None:
            colors, count = self._launch(points[a:b], normals[a:b])
            got = count > 0
            out[a:b][got] = colors[got]
            seen[a:b] = got

        in_chunks(len(points), self.chunk, self.device, run)
        return out, seen

    def _launch(self, points: np.ndarray, normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        wp, n = self._wp, len(points)
        pts = wp.array(np.ascontiguousarray(points, float), dtype=wp.vec3d, device=self.device)
        nrm = wp.array(np.ascontiguousarray(normals, float), dtype=wp.vec3d, device=self.device)
        scratch = wp.empty((n, 3, max(self.n_frames, 1)), dtype=wp.float32, device=self.device)
        colors = wp.zeros(n, dtype=wp.vec3f, device=self.device)
        count = wp.zeros(n, dtype=wp.int32, device=self.device)
        wp.launch(
            self._kernel,
            dim=n,
            inputs=[pts, nrm, *self._frames, *self._limits],
            outputs=[scratch, colors, count],
            device=self.device,
        )
        return colors.numpy(), count.numpy()


@functools.cache
def _samples_kernel():
    wp, median = _median()

    @wp.kernel
    def samples_median(
        samples: wp.array3d(dtype=wp.uint8),
        seen: wp.array2d(dtype=wp.uint8),
        scratch: wp.array3d(dtype=wp.float32),
        out: wp.array(dtype=wp.vec3f),
        count: wp.array(dtype=wp.int32),
    ):
        i = wp.tid()
        c = int(0)  # noqa: UP018 (a Warp variable that the loop mutates is declared typed)
        for k in range(samples.shape[0]):
            if seen[k, i] != wp.uint8(0):
                for ch in range(3):
                    scratch[i, ch, c] = wp.float32(samples[k, i, ch])
                c += 1
        count[i] = c
        if c > 0:
            out[i] = median(scratch, i, c)

    return wp, samples_median


def median_over_frames(
    samples: np.ndarray, seen: np.ndarray, *, chunk: int = 200_000, device: str | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Per texel, the per-channel median of its 8-bit ``samples`` (F, N, 3) over the frames that
    ``seen`` (F, N) marks, as ``np.nanmedian`` takes it (float32; 0 where none), and that count (N,)."""
    wp, kernel = _samples_kernel()
    dev = wp.get_device(device) if device else wp.get_preferred_device()
    frames, n = seen.shape
    out, count = np.zeros((n, 3), np.float32), np.zeros(n, np.int32)

    def run(a: int, b: int) -> None:
        args = [
            wp.array(np.ascontiguousarray(samples[:, a:b], np.uint8), dtype=wp.uint8, device=dev),
            wp.array(np.ascontiguousarray(seen[:, a:b], bool).view(np.uint8), dtype=wp.uint8, device=dev),
            wp.empty((b - a, 3, max(frames, 1)), dtype=wp.float32, device=dev),
        ]
        med, got = wp.zeros(b - a, dtype=wp.vec3f, device=dev), wp.zeros(b - a, dtype=wp.int32, device=dev)
        wp.launch(kernel, dim=b - a, inputs=args, outputs=[med, got], device=dev)
        out[a:b], count[a:b] = med.numpy(), got.numpy()

    in_chunks(n, chunk, dev, run)
    return out, count
