"""A depth sensor's errors, applied to clean rendered depth (the benchmark's ``rgbd`` mode).

The model follows structured-light / time-of-flight RGB-D cameras of the Kinect and RealSense class:

- axial noise growing with depth and at grazing angles (Nguyen, Izadi, Lovell 2012, Kinect):
  sigma(z, theta) = 1.2 mm + 1.9 mm * (z - 0.4 m)^2 / 1 m^2 + 0.1 mm / sqrt(z) * theta^2 / (pi/2 - theta)^2,
  plus a low-frequency wobble of a quarter of that (depth calibration residue);
- quantization to whole millimeters (uint16 PNG);
- holes where the sensor sees no return: at depth discontinuities (flying pixels removed), on
  dark surfaces, on specular surfaces facing the sensor, at grazing angles, beyond the working
  range, and a sprinkle of random dropouts;
- RGB-to-depth misregistration: the depth camera sits where the color camera's calibration says
  it does only up to a small rigid error (0.1-0.3 deg, 1-3 mm), so depth edges fall a few
  pixels off the color edges while the geometry stays rigid (``sample_depth_extrinsic``; the
  generator renders depth from the color camera moved by it).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.ndimage import gaussian_filter

from rose_usd.render.scene import Surface


@dataclass(frozen=True)
class DepthSensor:
    """Parameters of the depth error model (defaults: a Kinect-class sensor)."""

    min_range_m: float = 0.25
    max_range_m: float = 4.0
    edge_relative_jump: float = 0.04
    """A neighbor farther by this fraction of the depth marks a discontinuity."""
    edge_drop_probability: float = 0.75
    dark_luminance: float = 0.03
    """Linear albedo luminance under which the surface returns too little light."""
    dark_drop_probability: float = 0.6
    specular_drop_probability: float = 0.55
    """Dropout on specular surfaces facing the sensor (cos > 0.85)."""
    grazing_cos: float = 0.17
    grazing_drop_probability: float = 0.5
    random_drop_probability: float = 0.003


def sample_depth_extrinsic(rng: np.random.Generator) -> np.ndarray:
    """color_from_depth (4, 4): the depth camera's pose in the color camera, as an uncorrected
    calibration error of 0.1-0.3 deg and 1-3 mm (a few pixels at 640x480)."""
    from rose_usd.core import se3

    axis = rng.normal(size=3)
    direction = rng.normal(size=3)
    return se3.make_pose(
        se3.rotation_about(axis, np.radians(rng.uniform(0.1, 0.3))),
        direction / np.linalg.norm(direction) * rng.uniform(0.001, 0.003),
    )


def axial_sigma_m(depth_m: np.ndarray, cos_incidence: np.ndarray) -> np.ndarray:
    """Axial noise sigma [m] of the Kinect model at depth z and incidence angle theta."""
    theta = np.arccos(np.clip(cos_incidence, 1e-3, 1.0))
    z = np.maximum(depth_m, 1e-3)
    angle_term = 0.0001 / np.sqrt(z) * theta**2 / np.maximum(np.pi / 2 - theta, 1e-2) ** 2
    return 0.0012 + 0.0019 * (z - 0.4) ** 2 + angle_term


def sensor_depth(
    surface: Surface,
    rng: np.random.Generator,
    *,
    specular_labels: frozenset[int] = frozenset(),
    sensor: DepthSensor = DepthSensor(),
) -> np.ndarray:
    """Depth [m] as the sensor would report it for a clean ``surface`` rendered from the depth
    camera (0 = no reading)."""
    if surface.albedo is None or surface.cos_incidence is None:
        raise ValueError("sensor_depth needs surface buffers rendered with_albedo=True")
    z = surface.depth.astype(np.float64)
    valid = (z > sensor.min_range_m) & (z < sensor.max_range_m)
    h, w = z.shape

    # discontinuities: compare with the 8 neighbors
    padded = np.pad(z, 1, mode="edge")
    jump = np.zeros_like(z, dtype=bool)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            if dx == 0 and dy == 0:
                continue
            neighbor = padded[1 + dy : 1 + dy + h, 1 + dx : 1 + dx + w]
            jump |= np.abs(neighbor - z) > sensor.edge_relative_jump * np.maximum(z, 1e-3)
    jump = cv2.dilate(jump.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
    u = rng.random(z.shape)
    drop = jump & (u < sensor.edge_drop_probability)

    luminance = surface.albedo @ np.array([0.2126, 0.7152, 0.0722])
    drop |= (luminance < sensor.dark_luminance) & (rng.random(z.shape) < sensor.dark_drop_probability)
    if specular_labels:
        specular = np.isin(surface.labels, list(specular_labels))
        facing = surface.cos_incidence > 0.85
        drop |= specular & facing & (rng.random(z.shape) < sensor.specular_drop_probability)
    drop |= (surface.cos_incidence < sensor.grazing_cos) & (rng.random(z.shape) < sensor.grazing_drop_probability)
    drop |= rng.random(z.shape) < sensor.random_drop_probability

    sigma = axial_sigma_m(z, surface.cos_incidence)
    wobble = gaussian_filter(rng.normal(size=z.shape), sigma=max(h, w) / 16.0)
    wobble /= max(float(wobble.std()), 1e-9)
    noisy = z + sigma * rng.normal(size=z.shape) + 0.25 * sigma * wobble
    out = np.where(valid & ~drop, noisy, 0.0)
    return np.round(out * 1000.0) / 1000.0  # whole millimeters, as the uint16 PNG stores it
