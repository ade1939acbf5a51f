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
    """Manipulation tasks the generator can stage (the paper's five, as they are implemented)."""

    PUSH = "push"
    LIFT = "lift"


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


def _progress(n_frames: int, start: int, end: int) -> np.ndarray:
    t = np.arange(n_frames, dtype=float)
    return min_jerk((t - start) / max(end - start, 1))


@dataclass(frozen=True)
class TaskMotion:
    world_from_object: np.ndarray
    """Object poses per frame (N, 4, 4)."""
    object_from_hand: np.ndarray
    """Where the palm sits on the object while in contact (4, 4)."""
    approach_dir: np.ndarray
    """Unit world direction the hand comes from and leaves to (3,)."""


def task_motion(task: Task, n_frames: int, start_pose: np.ndarray, size_m, rng: np.random.Generator, *, table_half_extent=(0.5, 0.3)) -> TaskMotion:
    """The object's trajectory for ``task`` starting at rest at ``start_pose`` (on the table, z=0)."""
    ph = phases(n_frames)
    sx, sy, sz = size_m
    poses = np.repeat(start_pose[None], n_frames, axis=0)
    s = _progress(n_frames, ph.contact, ph.release)
    if task is Task.PUSH:
        # push along a direction that keeps the object on the table
        for _ in range(100):
            heading = rng.uniform(-np.pi, np.pi)
            dist = rng.uniform(0.12, 0.22)
            d = np.array([np.cos(heading), np.sin(heading), 0.0])
            end = start_pose[:3, 3] + dist * d
            if abs(end[0]) < table_half_extent[0] - 0.12 and abs(end[1]) < table_half_extent[1] - 0.12:
                break
        yaw = np.radians(rng.uniform(-20.0, 20.0))
        for t in range(n_frames):
            rot = se3.rotation_about([0, 0, 1], yaw * s[t]) @ start_pose[:3, :3]
            poses[t] = se3.make_pose(rot, start_pose[:3, 3] + dist * s[t] * d)
        # palm behind the object, facing the push direction, at mid height
        obj_d = start_pose[:3, :3].T @ d
        back = 0.5 * abs(obj_d[0]) * sx + 0.5 * abs(obj_d[1]) * sy
        hand_pos = -(back + 0.035) * obj_d + np.array([0.0, 0.0, 0.5 * sz])
        hand_rot = se3.rotation_between([-1.0, 0.0, 0.0], obj_d)  # palm faces -X in hand frame
        approach = -0.5 * d + np.array([0.0, 0.0, 1.0])  # arrives and leaves from above
    elif task is Task.LIFT:
        lift_h = rng.uniform(0.08, 0.14)
        shift = rng.uniform(-0.04, 0.04, size=2)
        up = np.sin(np.pi * np.clip(s, 0, 1)) * lift_h  # up then down, min-jerk timed
        for t in range(n_frames):
            p = start_pose[:3, 3] + np.array([shift[0] * s[t], shift[1] * s[t], up[t]])
            tilt = se3.rotation_about([1, 0, 0], np.radians(6.0) * np.sin(np.pi * s[t]))
            poses[t] = se3.make_pose(tilt @ start_pose[:3, :3], p)
        # palm on the object's side, a little above its middle
        side = rng.choice([-1.0, 1.0])
        obj_d = np.array([0.0, side, 0.0])
        hand_pos = -(0.5 * sy + 0.035) * obj_d + np.array([0.0, 0.0, 0.6 * sz])
        hand_rot = se3.rotation_between([-1.0, 0.0, 0.0], obj_d)
        approach = 0.5 * (start_pose[:3, :3] @ (-obj_d)) + np.array([0.0, 0.0, 1.0])
    else:  # pragma: no cover
        raise ValueError(task)
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
            [radius[i] * np.cos(el) * np.cos(az[i]), radius[i] * np.cos(el) * np.sin(az[i]), radius[i] * np.sin(el) + height_drift[i]]
        )
        pose = se3.look_at(eye + trans_shake[i], target)
        pose[:3, :3] = pose[:3, :3] @ Rotation.from_rotvec(rot_shake[i]).as_matrix()
        poses[i] = pose
    return poses
