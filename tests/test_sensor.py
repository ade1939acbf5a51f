"""The rgbd mode's depth sensor model: noise that grows with depth as the Kinect model says, holes
at discontinuities and on dark or specular surfaces, quantization, misregistration."""

import numpy as np
import pytest

from rose_usd.render.scene import Surface
from rose_usd.synth.sensor import DepthSensor, axial_sigma_m, sensor_depth


def two_planes(h=200, w=300, near=1.0, far=3.0):
    depth = np.full((h, w), near, np.float32)
    depth[:, w // 2 :] = far
    return Surface(
        depth=depth,
        labels=np.zeros((h, w), np.uint8),
        albedo=np.full((h, w, 3), 0.5, np.float32),
        cos_incidence=np.ones((h, w), np.float32),
    )


def test_noise_grows_with_depth_like_the_model():
    """Away from edges, the spread at 1 m and 3 m matches sigma(z) of the model within 25 %."""
    surf = two_planes()
    out = sensor_depth(surf, np.random.default_rng(0), sensor=DepthSensor(random_drop_probability=0.0))
    for z, cols in ((1.0, slice(10, 130)), (3.0, slice(170, 290))):
        patch = out[20:180, cols]
        patch = patch[patch > 0] - z
        expected = axial_sigma_m(np.array(z), np.array(1.0))
        assert np.std(patch) == pytest.approx(expected * np.sqrt(1 + 0.25**2), rel=0.25)
    assert np.allclose(out * 1000, np.round(out * 1000))  # whole millimeters


def test_holes_at_discontinuities_dark_and_specular_surfaces():
    """The depth edge loses most readings; dark albedo and specular surfaces facing the sensor lose many."""
    surf = two_planes()
    surf.albedo[:50] = 0.01  # dark band
    surf.labels[150:] = 7  # a specular object
    out = sensor_depth(surf, np.random.default_rng(1), specular_labels=frozenset({7}))
    edge = out[60:140, 148:153]
    assert np.mean(edge == 0) > 0.5
    assert np.mean(out[:50, 10:130] == 0) > 0.4
    assert np.mean(out[150:, 10:130] == 0) > 0.35
    assert np.mean(out[60:140, 10:130] == 0) < 0.02  # plain surface: few dropouts


def test_depth_camera_misregistration_is_a_few_pixels():
    """The sampled color-from-depth calibration error moves depth edges 1-5 px at 640x480, 1 m."""
    from rose_usd.core import se3
    from rose_usd.synth.sensor import sample_depth_extrinsic

    K = np.array([[550.0, 0, 320], [0, 550.0, 240], [0, 0, 1]])
    shifts = []
    for seed in range(20):
        x = sample_depth_extrinsic(np.random.default_rng(seed))
        p = se3.transform_points(x, np.array([[0.1, -0.05, 1.0]]))[0]
        shifts.append(np.linalg.norm(K[:2, :2] @ (p[:2] / p[2] - np.array([0.1, -0.05]))))
    assert 1.0 < np.median(shifts) < 5.0 and max(shifts) < 6.0
