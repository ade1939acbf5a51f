"""Rigid-transform math against analytic answers."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rose_usd.core import se3
from rose_usd.errors import InputError


def random_poses(n, seed=0):
    rng = np.random.default_rng(seed)
    return se3.make_pose(Rotation.random(n, random_state=seed).as_matrix(), rng.normal(size=(n, 3)))


def test_invert_is_inverse():
    """invert(T) @ T is the identity for random rigid poses."""
    poses = random_poses(20)
    np.testing.assert_allclose(se3.invert(poses) @ poses, np.broadcast_to(np.eye(4), poses.shape), atol=1e-12)


def test_quaternion_sign_is_canonical():
    """q and -q are one rotation: conversion returns w >= 0 and round-trips the matrix."""
    rot = Rotation.random(50, random_state=1).as_matrix()
    q = se3.quat_wxyz_from_matrix(rot)
    assert np.all(q[:, 0] >= 0)
    np.testing.assert_allclose(se3.matrix_from_quat_wxyz(q), rot, atol=1e-12)
    np.testing.assert_allclose(se3.matrix_from_quat_wxyz(-q), rot, atol=1e-12)


def test_rotation_angle_and_axis():
    """A rotation of 37 degrees about any axis measures 37 degrees."""
    r = se3.rotation_about([1.0, 2.0, 3.0], np.radians(37.0))
    assert se3.rotation_angle_deg(r) == pytest.approx(37.0)


@pytest.mark.parametrize(
    "a,b", [([1, 0, 0], [0, 1, 0]), ([0, 0, 1], [0, 0, -1]), ([1, 1, 0], [1, 1, 0]), ([0.3, -2, 1], [-1, 0.5, 0.2])]
)
def test_rotation_between_maps_a_to_b(a, b):
    """rotation_between(a, b) takes direction a onto direction b, also for opposite directions."""
    r = se3.rotation_between(a, b)
    np.testing.assert_allclose(r @ (np.array(a) / np.linalg.norm(a)), np.array(b) / np.linalg.norm(b), atol=1e-12)
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-12)


def test_look_at_is_an_opencv_camera():
    """look_at puts the target on the optical axis (+Z) with world up pointing to image -Y."""
    eye, target = np.array([1.0, -2.0, 1.5]), np.array([0.1, 0.2, 0.0])
    pose = se3.look_at(eye, target)
    cam = se3.transform_points(se3.invert(pose), target[None])[0]
    assert cam[0] == pytest.approx(0, abs=1e-12) and cam[1] == pytest.approx(0, abs=1e-12) and cam[2] > 0
    up_in_cam = pose[:3, :3].T @ np.array([0.0, 0.0, 1.0])
    assert up_in_cam[1] < 0


def test_check_rotation_rejects_non_rotations():
    """A scaled or reflected matrix is not a rotation and gets a clear error."""
    se3.check_rotation(np.eye(3))
    with pytest.raises(InputError, match="not a rotation"):
        se3.check_rotation(2 * np.eye(3))
    with pytest.raises(InputError, match="not a rotation"):
        se3.check_rotation(np.diag([1.0, 1.0, -1.0]))
    with pytest.raises(InputError, match="NaN"):
        se3.check_rotation(np.full((3, 3), np.nan))
