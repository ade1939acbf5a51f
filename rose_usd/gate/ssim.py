"""SSIM of a re-render against a video frame (Wang et al. 2004: 11x11 Gaussian window, sigma 1.5,
K1 = 0.01, K2 = 0.03), averaged over RGB channels and over the pixels that are not excluded.

The local means, variances and covariance are Gaussian-filtered with OpenCV in float64 (the same
11-tap kernel and population covariance as scikit-image's ``structural_similarity`` with
``gaussian_weights=True, use_sample_covariance=False``; tests/test_ssim.py checks the map against
it to 1e-9)."""

from __future__ import annotations

import cv2
import numpy as np

_SIGMA = 1.5
_PAD = 5  # half the 11-pixel window: border pixels have no full window and are left out
_C1 = (0.01 * 255) ** 2
_C2 = (0.03 * 255) ** 2


def _blur(image: np.ndarray) -> np.ndarray:
    return cv2.GaussianBlur(image, (2 * _PAD + 1, 2 * _PAD + 1), _SIGMA, borderType=cv2.BORDER_REFLECT_101)


def ssim_map(original: np.ndarray, rendered: np.ndarray) -> np.ndarray:
    """Per-pixel SSIM (H, W) of two 8-bit RGB images (H, W, 3), averaged over the channels."""
    x = original.astype(np.float64)
    y = rendered.astype(np.float64)
    mx, my = _blur(x), _blur(y)
    vx = _blur(x * x) - mx * mx
    vy = _blur(y * y) - my * my
    cxy = _blur(x * y) - mx * my
    s = ((2 * mx * my + _C1) * (2 * cxy + _C2)) / ((mx * mx + my * my + _C1) * (vx + vy + _C2))
    return s.mean(axis=2)


def masked_ssim(
    original: np.ndarray, rendered: np.ndarray, exclude: np.ndarray | None = None
) -> tuple[float, np.ndarray]:
    """Mean SSIM over non-excluded pixels and the per-pixel SSIM map (H, W).

    Args:
        original, rendered: 8-bit RGB (H, W, 3).
        exclude: boolean (H, W), True where pixels do not count (e.g. the interactor), or None.
    """
    if original.shape != rendered.shape:
        raise ValueError(f"masked_ssim: shapes differ {original.shape} vs {rendered.shape}")
    full = ssim_map(original, rendered)
    valid = np.zeros(full.shape, dtype=bool)
    valid[_PAD:-_PAD, _PAD:-_PAD] = True
    if exclude is not None:
        valid &= ~exclude
    if not valid.any():
        return float("nan"), full
    return float(full[valid].mean()), full
