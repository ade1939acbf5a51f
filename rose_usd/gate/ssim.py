"""SSIM of a re-render against a video frame (Wang et al. 2004: 11x11 Gaussian window, sigma 1.5,
K1 = 0.01, K2 = 0.03), averaged over RGB channels and over the pixels that are not excluded."""

from __future__ import annotations

import numpy as np

_SIGMA = 1.5
_PAD = 5  # half the 11-pixel window: border pixels have no full window and are left out


def masked_ssim(
    original: np.ndarray, rendered: np.ndarray, exclude: np.ndarray | None = None
) -> tuple[float, np.ndarray]:
    """Mean SSIM over non-excluded pixels and the per-pixel SSIM map (H, W).

    Args:
        original, rendered: 8-bit RGB (H, W, 3).
        exclude: boolean (H, W), True where pixels do not count (e.g. the interactor), or None.
    """
    from skimage.metrics import structural_similarity

    if original.shape != rendered.shape:
        raise ValueError(f"masked_ssim: shapes differ {original.shape} vs {rendered.shape}")
    _, full = structural_similarity(
        original,
        rendered,
        channel_axis=2,
        gaussian_weights=True,
        sigma=_SIGMA,
        use_sample_covariance=False,
        data_range=255,
        full=True,
    )
    ssim_map = full.mean(axis=2)
    valid = np.zeros(ssim_map.shape, dtype=bool)
    valid[_PAD:-_PAD, _PAD:-_PAD] = True
    if exclude is not None:
        valid &= ~exclude
    if not valid.any():
        return float("nan"), ssim_map
    return float(ssim_map[valid].mean()), ssim_map
