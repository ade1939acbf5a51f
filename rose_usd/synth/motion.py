"""Seeded motions of a synthetic case: the object's task trajectory, the interactor that moves it,
and a casual hand-held camera path (narrow baseline, slow drift, small shake) at video rate."""

from __future__ import annotations

import enum
from dataclasses import dataclass

import numpy as np
from scipy.ndimage import gaussian_filter1d
from scipy.spatial.transform import Rotation

from rose_usd.core import se3


class Task(enum.Enum):
    """The paper's five manipulation tasks."""

    UNSTACK = "unstack"  # two objects: the top one is lifted off the other and set down on the table
    PLACE = "place"  # pick an object up, carry it, set it down elsewhere
    LIFT = "lift"  # lift an object and set it back down about where it was
    PUSH = "push"  # slide an object across the table
    ROTATE = "rotate"  # turn an object in place about the vertical


@dataclass(frozen=True)
class Phases:
    """Frame indices of the interaction: approach [0, contact), move [contact, release),
    retreat [release, gone), rest [gone, N)."""

    contact: int
    release: int
    gone: int


def phases(n_frames: int) -> Phases:
    contact = max(2, int(round(0.18 * n_frames)))
    release = max(contact + 2, int(round(0.72 * n_frames)))
    gone = min(n_frames - 1, max(release + 2, int(round(0.90 * n_frames))))
    return Phases(contact, release, gone)


def min_jerk(s: np.ndarray) -> np.ndarray:
    """Minimum-jerk profile 10s^3 - 15s^4 + 6s^5 on s in [0, 1] (zero velocity and acceleration at the ends)."""
    s = np.clip(s, 0.0, 1.0)
    return s**3 * (10 - 15 * s + 6 * s**2)


def _progress(n_frames: int, start: float, end: float) -> np.ndarray:
    """Min-jerk progress from 0 (at frame ``start``) to 1 (at frame ``end``) for every frame."""
    t = np.arange(n_frames, dtype=float)
    return min_jerk((t - start) / max(end - start, 1e-9))


@dataclass(frozen=True)
class TaskMotion:
    world_from_object: np.ndarray
    """Poses of the manipulated object per frame (N, 4, 4)."""
    object_from_hand: np.ndarray
    """Where the palm sits on the object while in contact (4, 4)."""
    approach_dir: np.ndarray
    """Unit world direction the hand comes from and leaves to (3,)."""


@dataclass(frozen=True)
class _Carry:
    """A task as one carry: horizontal displacement, lift, end height, yaw and mid-air tilt."""

    displacement: np.ndarray  # (2,) [m]
    lift_m: float  # peak height above the higher of start and end [m]; 0 slides on the support
    end_z: float  # height of the resting face at the end [m]
    yaw_rad: float
    tilt_rad: float = 0.0


def _carry_poses(carry: _Carry, n_frames: int, start_pose: np.ndarray) -> np.ndarray:
    ph = phases(n_frames)
    t0, t1 = float(ph.contact), float(ph.release)
    span = t1 - t0
    z0 = start_pose[2, 3]
    if carry.lift_m > 0:
        peak = max(z0, carry.end_z) + carry.lift_m
        up = _progress(n_frames, t0, t0 + 0.35 * span)
        down = _progress(n_frames, t1 - 0.35 * span, t1)
        z = z0 + (peak - z0) * up - (peak - carry.end_z) * down
        horizontal = _progress(n_frames, t0 + 0.2 * span, t1 - 0.2 * span)
    else:
        z = np.full(n_frames, z0)
        horizontal = _progress(n_frames, t0, t1)
    airborne = np.sin(np.pi * _progress(n_frames, t0, t1)) if carry.lift_m > 0 else np.zeros(n_frames)
    poses = np.empty((n_frames, 4, 4))
    for t in range(n_frames):
        rot = (
            se3.rotation_about([0, 0, 1], carry.yaw_rad * horizontal[t])
            @ se3.rotation_about([1, 0, 0], carry.tilt_rad * airborne[t])
            @ start_pose[:3, :3]
        )
        pos = start_pose[:3, 3] + np.array(
            [carry.displacement[0] * horizontal[t], carry.displacement[1] * horizontal[t], 0.0]
        )
        pos[2] = z[t]
        poses[t] = se3.make_pose(rot, pos)
    return poses


def _direction_on_table(rng, start_xy, dist_range, table_center, table_half_extent, margin, avoid=None):
    """A displacement of random direction and length that keeps the end on the table (and away from ``avoid``)."""
    for _ in range(200):
        heading = rng.uniform(-np.pi, np.pi)
        dist = rng.uniform(*dist_range)
        d = dist * np.array([np.cos(heading), np.sin(heading)])
        end = np.asarray(start_xy) + d
        inside = np.all(np.abs(end - table_center) < np.asarray(table_half_extent) - margin)
        if inside and (avoid is None or np.linalg.norm(end - avoid[0]) > avoid[1]):
            return d
    raise RuntimeError("no displacement keeps the object on the table")


def task_motion(
    task: Task,
    n_frames: int,
    start_pose: np.ndarray,
    size_m,
    rng: np.random.Generator,
    *,
    table_center=(0.0, 0.0),
    table_half_extent=(0.5, 0.3),
    support: tuple[np.ndarray, float] | None = None,
) -> TaskMotion:
    """The manipulated object's trajectory for ``task``, starting at rest at ``start_pose``.

    Args:
        size_m: the object's bounding-box extents (x, y, z) [m].
        support: for UNSTACK, (xy center, radius) of the object it starts on; it must land clear of it.
    """
    sx, sy, sz = size_m
    radius = 0.5 * float(np.hypot(sx, sy))
    margin = radius + 0.06
    xy = start_pose[:2, 3]
    center = np.asarray(table_center, dtype=float)
    if task is Task.PUSH:
        d = _direction_on_table(rng, xy, (0.12, 0.22), center, table_half_extent, margin)
        carry = _Carry(d, 0.0, start_pose[2, 3], np.radians(rng.uniform(-20, 20)))
    elif task is Task.LIFT:
        d = rng.uniform(-0.03, 0.03, size=2)
        carry = _Carry(
            d,
            rng.uniform(0.08, 0.14),
            start_pose[2, 3],
            np.radians(rng.uniform(-10, 10)),
            np.radians(rng.uniform(-8, 8)),
        )
    elif task is Task.PLACE:
        d = _direction_on_table(rng, xy, (0.15, 0.25), center, table_half_extent, margin)
        carry = _Carry(
            d,
            rng.uniform(0.06, 0.10),
            start_pose[2, 3],
            np.radians(rng.uniform(-30, 30)),
            np.radians(rng.uniform(-5, 5)),
        )
    elif task is Task.ROTATE:
        carry = _Carry(
            rng.uniform(-0.015, 0.015, size=2),
            0.0,
            start_pose[2, 3],
            np.radians(rng.choice([-1, 1]) * rng.uniform(60, 120)),
        )
    elif task is Task.UNSTACK:
        if support is None:
            raise ValueError("UNSTACK needs the support object's position and radius")
        avoid = (np.asarray(support[0]), support[1] + radius + 0.03)
        d = _direction_on_table(rng, xy, (0.15, 0.24), center, table_half_extent, margin, avoid=avoid)
        carry = _Carry(
            d, rng.uniform(0.04, 0.07), 0.0, np.radians(rng.uniform(-25, 25)), np.radians(rng.uniform(-5, 5))
        )
    else:  # pragma: no cover - the enum is closed
        raise ValueError(task)
    poses = _carry_poses(carry, n_frames, start_pose)

    # where the palm holds the object, in the object frame (the palm faces -X of the hand frame)
    if task is Task.PUSH:
        obj_d = start_pose[:3, :3].T @ np.array([*carry.displacement / np.linalg.norm(carry.displacement), 0.0])
        back = 0.5 * abs(obj_d[0]) * sx + 0.5 * abs(obj_d[1]) * sy
        hand_pos = -(back + 0.035) * obj_d + np.array([0.0, 0.0, 0.5 * sz])
        toward = obj_d
        approach = -0.5 * (start_pose[:3, :3] @ obj_d) + np.array([0.0, 0.0, 1.0])
    elif task is Task.ROTATE:
        hand_pos = np.array([0.0, 0.0, sz + 0.035])
        toward = np.array([0.0, 0.0, -1.0])
        approach = np.array([rng.uniform(-0.3, 0.3), rng.uniform(-0.3, 0.3), 1.0])
    elif abs(start_pose[2, 2]) < 0.5:  # lying on its side: from above, around its axis
        toward = start_pose[:3, :3].T @ np.array([0.0, 0.0, -1.0])
        toward[2] = 0.0
        toward /= np.linalg.norm(toward)
        hand_pos = np.array([0.0, 0.0, 0.5 * sz]) - (0.5 * sy + 0.035) * toward
        approach = np.array([rng.uniform(-0.3, 0.3), rng.uniform(-0.3, 0.3), 1.0])
    else:  # side grip, a little above the middle
        side = rng.choice([-1.0, 1.0])
        toward = np.array([0.0, side, 0.0])
        hand_pos = -(0.5 * sy + 0.035) * toward + np.array([0.0, 0.0, 0.6 * sz])
        approach = 0.5 * (start_pose[:3, :3] @ (-toward)) + np.array([0.0, 0.0, 1.0])
    hand_rot = se3.rotation_between([-1.0, 0.0, 0.0], toward)
    return TaskMotion(poses, se3.make_pose(hand_rot, hand_pos), approach / np.linalg.norm(approach))


def hand_trajectory(motion: TaskMotion, n_frames: int, *, reach_m: float = 0.5) -> np.ndarray:
    """world_from_hand per frame (N, 4, 4): approach, hold while the object moves, retreat."""
    ph = phases(n_frames)
    contact_pose = motion.world_from_object[ph.contact] @ motion.object_from_hand
    release_pose = motion.world_from_object[ph.release] @ motion.object_from_hand
    out = np.empty((n_frames, 4, 4))
    approach = _progress(n_frames, 0, ph.contact)
    retreat = _progress(n_frames, ph.release, ph.gone)
    for t in range(n_frames):
        if t < ph.contact:
            pose = contact_pose.copy()
            pose[:3, 3] += (1.0 - approach[t]) * reach_m * motion.approach_dir
        elif t < ph.release:
            pose = motion.world_from_object[t] @ motion.object_from_hand
        else:
            pose = release_pose.copy()
            pose[:3, 3] += retreat[t] * reach_m * motion.approach_dir
        out[t] = pose
    return out


def handheld_camera(
    n_frames: int,
    target: np.ndarray,
    rng: np.random.Generator,
    *,
    fps: float = 30.0,
    distance_m: tuple[float, float] = (0.55, 0.75),
    elevation_deg: tuple[float, float] = (30.0, 45.0),
    sweep_deg: float = 12.0,
    shake_m: float = 0.003,
    shake_deg: float = 0.4,
) -> np.ndarray:
    """world_from_camera (OpenCV) per frame (N, 4, 4) of a person filming ``target`` by hand.

    A slow azimuth sweep of ``sweep_deg`` in total and a few centimeters of radius and height drift
    (narrow baseline), plus shake: low-passed noise of about ``shake_m`` and ``shake_deg`` at 1-3 Hz.
    """
    t = np.arange(n_frames) / fps
    duration = max(t[-1], 1e-6)
    az0 = rng.uniform(-np.pi, np.pi)
    el = np.radians(rng.uniform(*elevation_deg))
    dist = rng.uniform(*distance_m)
    phase = rng.uniform(0, 2 * np.pi, size=3)
    az = az0 + np.radians(sweep_deg) * (t / duration - 0.5)
    radius = dist + 0.03 * np.sin(2 * np.pi * t / duration + phase[0])
    height_drift = 0.02 * np.sin(2 * np.pi * 0.7 * t / duration + phase[1])
    sigma = fps / (2 * np.pi * 2.0)  # ~2 Hz low pass

    def shake(scale: float, dims: int) -> np.ndarray:
        noise = gaussian_filter1d(rng.normal(size=(n_frames + 60, dims)), sigma, axis=0)[30:-30]
        noise /= max(noise.std(), 1e-9)
        return scale * noise

    trans_shake = shake(shake_m, 3)
    rot_shake = shake(np.radians(shake_deg), 3)
    poses = np.empty((n_frames, 4, 4))
    for i in range(n_frames):
        eye = target + np.array(
            [
                radius[i] * np.cos(el) * np.cos(az[i]),
                radius[i] * np.cos(el) * np.sin(az[i]),
                radius[i] * np.sin(el) + height_drift[i],
            ]
        )
        pose = se3.look_at(eye + trans_shake[i], target)
        pose[:3, :3] = pose[:3, :3] @ Rotation.from_rotvec(rot_shake[i]).as_matrix()
        poses[i] = pose
    return poses
