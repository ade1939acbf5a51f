"""sRGB <-> linear RGB (IEC 61966-2-1). Images on disk are sRGB; colors in USD are linear."""

from __future__ import annotations

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
    """Linear RGB -> 8-bit sRGB (round to nearest)."""
    return np.round(linear_to_srgb(linear) * 255.0).astype(np.uint8)


def srgb8_to_linear(srgb8: np.ndarray) -> np.ndarray:
    """8-bit sRGB -> linear RGB in [0, 1]."""
    return srgb_to_linear(np.asarray(srgb8, dtype=np.float64) / 255.0)
