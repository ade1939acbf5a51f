"""The gate's SSIM (OpenCV filters) against scikit-image's reference implementation, with the
paper's settings: the same map to 1e-9 on noise, on a blurred copy and on a shifted copy."""

from __future__ import annotations

import cv2
import numpy as np
from skimage.metrics import structural_similarity

from rose_usd.gate.ssim import masked_ssim, ssim_map


def _reference(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    _, full = structural_similarity(
        a, b, channel_axis=2, gaussian_weights=True, sigma=1.5, use_sample_covariance=False, data_range=255, full=True
    )
    return full.mean(axis=2)


def test_the_map_equals_scikit_image():
    rng = np.random.default_rng(3)
    a = cv2.GaussianBlur(rng.integers(0, 256, (120, 160, 3), dtype=np.uint8), (0, 0), 2.0)
    pairs = [
        (a, rng.integers(0, 256, a.shape, dtype=np.uint8)),
        (a, cv2.GaussianBlur(a, (0, 0), 1.2)),
        (a, np.roll(a, (2, -3), axis=(0, 1))),
        (a, a),
    ]
    for x, y in pairs:
        ours, ref = ssim_map(x, y), _reference(x, y)
        inner = (slice(5, -5), slice(5, -5))  # the gate leaves the border out: its windows are cut
        assert np.max(np.abs(ours[inner] - ref[inner])) < 1e-9


def test_the_mean_leaves_out_the_excluded_pixels():
    rng = np.random.default_rng(4)
    a = rng.integers(0, 256, (60, 80, 3), dtype=np.uint8)
    b = a.copy()
    b[:, 40:] = 255 - b[:, 40:]
    exclude = np.zeros(a.shape[:2], bool)
    exclude[:, 35:] = True
    score, full = masked_ssim(a, b, exclude)
    assert score == float(full[5:-5, 5:35].mean())
    assert score > 0.99
    assert np.isnan(masked_ssim(a, b, np.ones(a.shape[:2], bool))[0])
