"""Rigid transforms as 4x4 numpy matrices acting on column vectors.

Names carry the convention: ``world_from_camera`` maps camera coordinates to world coordinates.
Quaternions are named by their order: ``quat_wxyz`` (scalar first, as USD's GfQuat) or
``quat_xyzw`` (scalar last, as TUM files and scipy).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from rose_usd.errors import InputError


def make_pose(rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
    """Stack rotations (..., 3, 3) and translations (..., 3) [m] into poses (..., 4, 4)."""
    rotation = np.asarray(rotation, dtype=float)
    translation = np.asarray(translation, dtype=float)
    shape = np.broadcast_shapes(rotation.shape[:-2], translation.shape[:-1])
    pose = np.zeros(shape + (4, 4))
    pose[..., :3, :3] = rotation
    pose[..., :3, 3] = translation
    pose[..., 3, 3] = 1.0
    return pose


def invert(pose: np.ndarray) -> np.ndarray:
    """Inverse of rigid poses (..., 4, 4) without a general matrix inverse."""
    pose = np.asarray(pose, dtype=float)
    rot_t = np.swapaxes(pose[..., :3, :3], -1, -2)
    return make_pose(rot_t, -np.einsum("...ij,...j->...i", rot_t, pose[..., :3, 3]))


def transform_points(pose: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply one pose (4, 4) to points (N, 3)."""
    return np.asarray(points, dtype=float) @ pose[:3, :3].T + pose[:3, 3]


def quat_xyzw_from_matrix(rotation: np.ndarray) -> np.ndarray:
    """Unit quaternions (..., 4), scalar last, with non-negative w (q and -q are the same rotation)."""
    q = Rotation.from_matrix(np.asarray(rotation, dtype=float)).as_quat()
    return np.where(q[..., 3:4] < 0, -q, q)


def matrix_from_quat_xyzw(quat_xyzw: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) from quaternions (..., 4), scalar last; normalizes them."""
    return Rotation.from_quat(np.asarray(quat_xyzw, dtype=float)).as_matrix()


def quat_wxyz_from_matrix(rotation: np.ndarray) -> np.ndarray:
    """Unit quaternions (..., 4), scalar first, with non-negative w."""
    return np.roll(quat_xyzw_from_matrix(rotation), 1, axis=-1)


def matrix_from_quat_wxyz(quat_wxyz: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) from quaternions (..., 4), scalar first."""
    return matrix_from_quat_xyzw(np.roll(np.asarray(quat_wxyz, dtype=float), -1, axis=-1))


def rotation_angle_deg(rotation: np.ndarray) -> np.ndarray:
    """Angle of rotations (..., 3, 3) about their axis [deg], in [0, 180]."""
    rotation = np.asarray(rotation, dtype=float)
    cos = (np.trace(rotation, axis1=-2, axis2=-1) - 1.0) / 2.0
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def rotation_about(axis: np.ndarray, angle_rad: float) -> np.ndarray:
    """Rotation matrix (3, 3) about a unit axis by an angle [rad]."""
    axis = np.asarray(axis, dtype=float)
    return Rotation.from_rotvec(axis / np.linalg.norm(axis) * angle_rad).as_matrix()


def rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The smallest rotation (3, 3) taking direction ``a`` to direction ``b``."""
    a = np.asarray(a, dtype=float) / np.linalg.norm(a)
    b = np.asarray(b, dtype=float) / np.linalg.norm(b)
    axis = np.cross(a, b)
    s, c = np.linalg.norm(axis), float(np.dot(a, b))
    if s < 1e-12:
        if c > 0:
            return np.eye(3)
        # opposite: rotate by pi about any axis perpendicular to a
        perp = np.cross(a, [1.0, 0.0, 0.0] if abs(a[0]) < 0.9 else [0.0, 1.0, 0.0])
        return rotation_about(perp, np.pi)
    return rotation_about(axis, np.arctan2(s, c))


def turn_down(normal: np.ndarray, *, tiny: float) -> np.ndarray:
    """The rotation (3, 3) turning the unit vector ``normal`` onto -z, Rodrigues' formula written
    out; the identity where the sine of the angle between them is under ``tiny`` (``normal`` along
    -z, or along +z). Not ``rotation_between``: the same rotation to 1e-16, but the pose searches
    that start from a set-down are that sensitive (a difference in the last bits changes their fit)."""
    axis = np.cross(normal, [0.0, 0.0, -1.0])
    s, c = np.linalg.norm(axis), float(-normal[2])
    if s < tiny:
        return np.eye(3)
    k = axis / s
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + s * kx + (1 - c) * kx @ kx


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray = (0.0, 0.0, 1.0)) -> np.ndarray:
    """``world_from_camera`` (4, 4) of an OpenCV camera (x right, y down, z forward) at ``eye``
    looking at ``target`` with the world direction ``up`` appearing up in the image."""
    eye, target, up = (np.asarray(v, dtype=float) for v in (eye, target, up))
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    if np.linalg.norm(x) < 1e-9:
        raise ValueError("look_at: viewing direction is parallel to up")
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return make_pose(np.stack([x, y, z], axis=1), eye)


def orthonormalize(rotation: np.ndarray) -> np.ndarray:
    """The nearest proper rotation(s) (..., 3, 3) to slightly non-orthonormal matrices (SVD)."""
    u, _, vt = np.linalg.svd(np.asarray(rotation, dtype=float))
    d = np.sign(np.linalg.det(u @ vt))
    u[..., :, 2] *= d[..., None]
    return u @ vt


def check_rotation(rotation: np.ndarray, *, tol: float = 1e-4, what: str = "pose", path=None) -> None:
    """Raise InputError unless ``rotation`` (..., 3, 3) is a proper rotation within ``tol``."""
    rotation = np.asarray(rotation, dtype=float)
    if not np.all(np.isfinite(rotation)):
        raise InputError(f"{what} contains NaN or infinite values", path=path, hint="fix or remove that file")
    eye = np.einsum("...ji,...jk->...ik", rotation, rotation)
    ortho_err = float(np.max(np.abs(eye - np.eye(3)))) if rotation.size else 0.0
    det = np.linalg.det(rotation) if rotation.size else np.ones(1)
    if ortho_err > tol or np.any(det < 0):
        raise InputError(
            f"{what} is not a rotation (|R^T R - I| = {ortho_err:.2g}, det = {np.min(det):.3g})",
            path=path,
            hint="write a proper rigid transform (orthonormal rotation, det +1)",
        )


def slerp_poses(pose_a: np.ndarray, pose_b: np.ndarray, s: float) -> np.ndarray:
    """Interpolate between two poses: linear in translation, spherical in rotation, s in [0, 1]."""
    from scipy.spatial.transform import Slerp

    rots = Rotation.from_matrix(np.stack([pose_a[:3, :3], pose_b[:3, :3]]))
    rot = Slerp([0.0, 1.0], rots)([s]).as_matrix()[0]
    return make_pose(rot, (1.0 - s) * pose_a[:3, 3] + s * pose_b[:3, 3])
