"""sRGB <-> linear RGB (IEC 61966-2-1). Images on disk are sRGB; colors in USD are linear."""

from __future__ import annotations

import functools

import numpy as np


def srgb_to_linear(srgb: np.ndarray) -> np.ndarray:
    """sRGB values in [0, 1] -> linear values in [0, 1]."""
    c = np.asarray(srgb, dtype=np.float64)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(linear: np.ndarray) -> np.ndarray:
    """Linear values (clipped to [0, 1]) -> sRGB values in [0, 1]."""
    c = np.clip(np.asarray(linear, dtype=np.float64), 0.0, 1.0)
    return np.where(c <= 0.0031308, c * 12.92, 1.055 * c ** (1.0 / 2.4) - 0.055)


def linear_to_srgb8(linear: np.ndarray) -> np.ndarray:
    """Linear RGB -> 8-bit sRGB (round to nearest; NaN -> 0): ``linear_to_srgb`` in float64,
    rounded. A float32 image (a render) goes through one Warp kernel on the CPU, a thread a core,
    with the same result: NumPy's 7 passes took 34-55 ms at 640x480, every frame the gate
    re-renders, the kernel 24-32 ms."""
    if np.asarray(linear).dtype != np.float32:
        return np.nan_to_num(np.round(linear_to_srgb(linear) * 255.0), nan=0.0).astype(np.uint8)
    flat = np.ascontiguousarray(linear).reshape(-1)
    out = np.empty(flat.shape, np.uint8)
    wp, to_srgb8 = _srgb8_kernel()

    def run(a: int, b: int) -> None:
        wp.launch(
            to_srgb8,
            dim=b - a,
            inputs=[wp.array(flat[a:b], dtype=wp.float32, device="cpu", copy=False)],
            outputs=[wp.array(out[a:b], dtype=wp.uint8, device="cpu", copy=False)],
            device="cpu",
        )

    from rose_usd.sim.engine import in_chunks

    in_chunks(len(flat), 1 << 18, wp.get_device("cpu"), run)
    return out.reshape(np.shape(linear))


@functools.cache
def _srgb8_kernel():
    from rose_usd.sim.engine import warp

    wp = warp()
    f64 = wp.float64

    @wp.kernel
    def to_srgb8(linear: wp.array(dtype=wp.float32), out: wp.array(dtype=wp.uint8)):
        i = wp.tid()
        x = f64(linear[i])
        if wp.isnan(x):
            out[i] = wp.uint8(0)
            return
        c = wp.clamp(x, f64(0.0), f64(1.0))
        s = c * f64(12.92)
        if c > f64(0.0031308):
            s = f64(1.055) * wp.pow(c, f64(1.0) / f64(2.4)) - f64(0.055)
        out[i] = wp.uint8(int(wp.round(s * f64(255.0))))

    return wp, to_srgb8


def srgb8_to_linear(srgb8: np.ndarray) -> np.ndarray:
    """8-bit sRGB -> linear RGB in [0, 1]."""
    return srgb_to_linear(np.asarray(srgb8, dtype=np.float64) / 255.0)
