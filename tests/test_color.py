"""sRGB conversions: a float32 image's 8-bit sRGB (the Warp kernel) is the float64 formula's,
rounded, on every value; round trips through 8 bits hold every level."""

from __future__ import annotations

import numpy as np

from rose_usd.core.color import linear_to_srgb, linear_to_srgb8, srgb8_to_linear


def _reference(linear: np.ndarray) -> np.ndarray:
    return np.round(linear_to_srgb(linear) * 255.0).astype(np.uint8)


def test_the_kernel_rounds_as_the_formula_does():
    rng = np.random.default_rng(5)
    edges = np.float32([0.0, 1.0, -1.0, 2.0, 0.0031308, 1e-9, np.inf, -np.inf])
    x = np.concatenate([rng.random(2_000_000, dtype=np.float32) ** 2.2, rng.random(500_000, dtype=np.float32) * 0.004])
    x = np.concatenate([x, edges]).astype(np.float32)
    assert np.array_equal(linear_to_srgb8(x), _reference(x))
    image = x[: 480 * 640 * 3].reshape(480, 640, 3)
    assert linear_to_srgb8(image).shape == (480, 640, 3)
    assert linear_to_srgb8(np.float32([np.nan]))[0] == 0


def test_every_8_bit_level_comes_back():
    levels = np.arange(256, dtype=np.uint8)
    linear = srgb8_to_linear(levels)
    assert np.array_equal(linear_to_srgb8(linear), levels)  # float64: NumPy
    assert np.array_equal(linear_to_srgb8(linear.astype(np.float32)), levels)  # float32: the kernel
