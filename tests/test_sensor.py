"""The rgbd mode's depth sensor model: noise that grows with depth as the Kinect model says, holes
at discontinuities and on dark or specular surfaces, quantization, misregistration."""

import numpy as np
import pytest

from rose_usd.render.scene import Surface
from rose_usd.synth.sensor import DepthSensor, axial_sigma_m, sensor_depth


def two_planes(h=200, w=300, near=1.0, far=3.0):
    depth = np.full((h, w), near, np.float32)
    depth[:, w // 2 :] = far
    return Surface(depth=depth, labels=np.zeros((h, w), np.uint8), albedo=np.full((h, w, 3), 0.5, np.float32), cos_incidence=np.ones((h, w), np.float32))


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


def test_misregistration_shifts_the_depth_image():
    """A (dx, dy) misregistration moves the depth edge by dx pixels."""
    surf = two_planes()
    clean = DepthSensor(edge_drop_probability=0.0, random_drop_probability=0.0)
    a = sensor_depth(surf, np.random.default_rng(2), sensor=clean)
    b = sensor_depth(surf, np.random.default_rng(2), misregistration_px=(3, 0), sensor=clean)
    edge_a = np.argmax(a[100] > 2.0)
    edge_b = np.argmax(b[100] > 2.0)
    assert edge_b - edge_a == 3
