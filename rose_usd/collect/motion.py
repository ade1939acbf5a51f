"""What the robot is told to do: joint targets per control tick, in phases.

home -> pre-grasp (to an IK solution 10 cm back along the approach, through joint space: the
straight line, or around the scene where that collides, :mod:`rose_usd.collect.planning`) ->
grasp (a straight descent) -> close (the fingers' target goes to 0; their drives' force limit
squeezes) -> lift (to the path's first pose, ``lift_m`` higher) -> follow (the path at the
video's times) -> place (down by ``lift_m``) -> release (fingers open, hand backs off). The
fingers open no wider than the grasp's pre-shape (``Plan.opening_m``) from home to the grasp and at
the release.

The follow is ``T_ee(t) = T_obj(t) · T_obj(t_grasp)^-1 · T_ee(t_grasp)`` (:func:`follow_poses`),
with the object's and the hand's poses at the grasp as simulated, so a grasp that landed a few
millimetres off still carries the object along its path. The control rate is the video's frame
rate, and a follow tick is a video frame wherever the arm can keep up at ``FOLLOW_SPEED`` of its
joints' velocity limits; where the video's object moves faster (two hands turning a cup 11 deg a
frame), the arm follows the same path slower (:func:`retimed`), and each tick records the
(fractional) video frame it stands for (``Plan.frame``).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from rose_usd.collect import ik
from rose_usd.core import se3
from rose_usd.sim import panda

PREGRASP_M = 0.10
"""Distance of the pre-grasp pose behind the grasp along the approach [m]."""
DESCEND_S = 0.8
APPROACH_SPEED_RAD_S = 1.0
"""Mean speed [rad/s] of the fastest joint along a planned approach (its peak is 1.5 times that,
under the Panda's limits); the approach takes ``approach_s`` or longer when its route needs."""
SETTLE_S = 0.1
CLOSE_S = 0.5
SQUEEZE_S = 0.3
LIFT_S = 0.5
PLACE_S = 0.4
RELEASE_S = 0.3
RETREAT_S = 0.4
RETREAT_M = 0.05
FOLLOW_SPEED = 0.5
"""The follow's arm joints move at most this share of the Panda's velocity limits (the rest is
room for the drives' lag and the object's inertia)."""
RAMP_FRAMES = 3
"""A slowdown spreads over this many video frames each side of where it is needed."""


def follow_poses(world_from_object: np.ndarray, object_at_grasp: np.ndarray, ee_at_grasp: np.ndarray) -> np.ndarray:
    """``T_ee(t) = T_obj(t) · T_obj(t_grasp)^-1 · T_ee(t_grasp)`` for every t.

    Args:
        world_from_object: (N, 4, 4) the object's path.
        object_at_grasp: (4, 4) the object's world pose when it was grasped.
        ee_at_grasp: (4, 4) the tool's world pose when it grasped.

    Returns:
        (N, 4, 4) tool poses that carry the object along its path, held as it was grasped.
    """
    object_from_ee = se3.invert(object_at_grasp) @ ee_at_grasp
    return np.einsum("nij,jk->nik", np.asarray(world_from_object, dtype=float), object_from_ee)


def lifted(poses: np.ndarray, height_m: float) -> np.ndarray:
    """Poses moved up (world +z) by ``height_m``."""
    out = np.array(poses, dtype=float, copy=True)
    out[..., 2, 3] += height_m
    return out


def backed_off(tcp: np.ndarray, distance_m: float) -> np.ndarray:
    """Tool poses (..., 4, 4) moved back along their approach (their z axis) by ``distance_m``."""
    out = np.array(tcp, dtype=float, copy=True)
    out[..., :3, 3] -= distance_m * out[..., :3, 2]
    return out


def cartesian(start: np.ndarray, end: np.ndarray, n: int) -> np.ndarray:
    """``n`` poses from ``start`` (excluded) to ``end`` (included): smoothstep in time, linear
    in position, slerp in rotation. (n, 4, 4)."""
    s = np.linspace(0.0, 1.0, n + 1)[1:]
    s = s * s * (3 - 2 * s)
    rot = Slerp([0.0, 1.0], Rotation.from_matrix(np.stack([start[:3, :3], end[:3, :3]])))(s).as_matrix()
    return se3.make_pose(rot, start[:3, 3] + s[:, None] * (end[:3, 3] - start[:3, 3]))


def ticks(seconds: float, rate_hz: float) -> int:
    return max(1, int(round(seconds * rate_hz)))


def retimed(q: np.ndarray, rate_hz: float, *, speed: float = FOLLOW_SPEED, ramp: int = RAMP_FRAMES) -> np.ndarray:
    """The video frame (fractional) each control tick of a follow stands for, from the joint path
    ``q`` (N, 7+) at the video's N frames, a tick every 1 / ``rate_hz`` s: one tick a frame where
    every arm joint stays under ``speed`` of its velocity limit at that pace, more where it would
    not, the slowdown spread over ``ramp`` frames each side (a running maximum, then a running
    mean) so the pace changes gradually. (M,) rising from 0 to N - 1, M >= N."""
    q = np.asarray(q, dtype=float)
    n = len(q)
    if n < 2:
        return np.zeros(n)
    limit = speed * np.asarray(panda.ARM_MAX_VELOCITY_RAD_S)
    # ticks each frame-to-frame step needs (at least one)
    need = np.maximum((np.abs(np.diff(q[:, :7], axis=0)) / limit).max(axis=1) * rate_hz, 1.0)
    if need.max() > 1.0:
        if ramp > 0:
            window = np.lib.stride_tricks.sliding_window_view
            widest = window(np.pad(need, ramp, mode="edge"), 2 * ramp + 1).max(axis=1)
            need = window(np.pad(widest, ramp - 1, mode="edge"), 2 * ramp - 1).mean(axis=1)
        # a whole number of ticks: the slowed steps take the rest, the others keep one tick a frame
        slowed = need - 1.0
        need += (np.ceil(need.sum() - 1e-9) - need.sum()) * slowed / slowed.sum()
    elapsed = np.concatenate([[0.0], np.cumsum(need)])  # ticks from frame 0 to each frame
    m = int(round(elapsed[-1]))
    out = np.interp(np.arange(m + 1, dtype=float), elapsed, np.arange(n, dtype=float))
    out[-1] = n - 1
    return out


def poses_at(poses: np.ndarray, frames: np.ndarray) -> np.ndarray:
    """Poses (N, 4, 4) at fractional indices ``frames`` (M,): linear in position, slerp in rotation."""
    poses = np.asarray(poses, dtype=float)
    index = np.arange(len(poses), dtype=float)
    if len(poses) == 1:
        return np.repeat(poses, len(frames), axis=0)
    rot = Slerp(index, Rotation.from_matrix(poses[:, :3, :3]))(np.clip(frames, 0, index[-1])).as_matrix()
    xyz = np.stack([np.interp(frames, index, poses[:, k, 3]) for k in range(3)], axis=1)
    return se3.make_pose(rot, xyz)


@dataclass
class Plan:
    """Joint targets per control tick, the tool pose they were solved for and the phase."""

    rate_hz: float
    q: list[np.ndarray] = field(default_factory=list)
    """(9,) targets: 7 arm joints [rad], 2 finger joints [m]."""
    tcp: list[np.ndarray] = field(default_factory=list)
    """(4, 4) commanded tool pose in the world (NaN during joint-space moves)."""
    phase: list[str] = field(default_factory=list)
    frame: list[float] = field(default_factory=list)
    """The video frame (fractional) a follow tick stands for; NaN for the other ticks (``video_frames``)."""
    ik_error_m: float = 0.0
    """Largest IK position error on the Cartesian segments [m]."""
    ik_error_deg: float = 0.0
    approach: str = "straight"
    """How the approach's route was found (:class:`rose_usd.collect.planning.Route`)."""
    opening_m: float = panda.MAX_OPENING_M
    """How far apart the pads open before they close and at the release [m]."""

    def __len__(self) -> int:
        return len(self.q)

    def joint_path(self, waypoints: np.ndarray, seconds: float, phase: str, fingers: float) -> None:
        """Through joint-space waypoints (K, 7+) from the first (excluded) to the last: one smoothstep
        in time over their length (the largest joint change per segment)."""
        waypoints = np.asarray(waypoints, dtype=float)
        lengths = np.abs(np.diff(waypoints, axis=0)).max(axis=1)
        along = np.concatenate([[0.0], np.cumsum(lengths)]) / max(lengths.sum(), 1e-12)
        s = np.linspace(0.0, 1.0, ticks(seconds, self.rate_hz) + 1)[1:]
        s = s * s * (3 - 2 * s)
        for si in s:
            k = min(int(np.searchsorted(along, si, side="right")) - 1, len(lengths) - 1)
            a = (si - along[k]) / max(along[k + 1] - along[k], 1e-12)
            q = np.zeros(len(panda.JOINTS))
            q[: waypoints.shape[1]] = waypoints[k] + a * (waypoints[k + 1] - waypoints[k])
            q[7:] = fingers
            self._append(q, np.full((4, 4), np.nan), phase)

    def hold(self, q: np.ndarray, seconds: float, phase: str, fingers: float, tcp: np.ndarray) -> None:
        for _ in range(ticks(seconds, self.rate_hz)):
            qq = q.copy()
            qq[7:] = fingers
            self._append(qq, tcp, phase)

    def fingers_to(self, q: np.ndarray, start: float, end: float, seconds: float, phase: str, tcp) -> None:
        n = ticks(seconds, self.rate_hz)
        for s in np.linspace(0.0, 1.0, n + 1)[1:]:
            qq = q.copy()
            qq[7:] = start + s * (end - start)
            self._append(qq, tcp, phase)

    def path(self, base_pose: np.ndarray, world_tcp: np.ndarray, seed: np.ndarray, phase: str, fingers: float):
        """Append the IK solutions of a path of world tool poses; returns the last joint coordinates."""
        q = self._solved(base_pose, world_tcp, seed, fingers)
        for qq, tcp in zip(q, world_tcp, strict=True):
            self._append(qq, tcp, phase)
        return q[-1]

    def follow(self, base_pose: np.ndarray, world_tcp: np.ndarray, seed: np.ndarray, fingers: float):
        """Append the follow of world tool poses at the video's frames (N, 4, 4): their IK solutions,
        retimed (:func:`retimed`) and interpolated between frames where the arm cannot keep the
        video's pace; returns the last joint coordinates."""
        q = self._solved(base_pose, world_tcp, seed, fingers)
        frames = retimed(q, self.rate_hz)
        index = np.arange(len(q), dtype=float)
        q_ticks = np.stack([np.interp(frames, index, q[:, j]) for j in range(q.shape[1])], axis=1)
        for qq, tcp, f in zip(q_ticks, poses_at(world_tcp, frames), frames, strict=True):
            self._append(qq, tcp, "follow", f)
        return q[-1]

    def _solved(self, base_pose: np.ndarray, world_tcp: np.ndarray, seed: np.ndarray, fingers: float) -> np.ndarray:
        """IK along world tool poses (N, 4, 4) from ``seed``: (N, 9), the errors kept."""
        q, pos_err, rot_err = ik.solve_path(se3.invert(base_pose) @ world_tcp, seed)
        q[:, 7:] = fingers
        self.ik_error_m = max(self.ik_error_m, float(pos_err.max()))
        self.ik_error_deg = max(self.ik_error_deg, float(rot_err.max()))
        return q

    def _append(self, q: np.ndarray, tcp: np.ndarray, phase: str, frame: float = np.nan) -> None:
        self.q.append(q)
        self.tcp.append(tcp)
        self.phase.append(phase)
        self.frame.append(frame)

    def video_frames(self) -> np.ndarray:
        """(T,) the video frame each tick stands for: the follow's own, frame 0 before it, its last after."""
        frame = np.asarray(self.frame, dtype=float)
        known = np.flatnonzero(np.isfinite(frame))
        if not len(known):
            return np.zeros(len(frame))
        return np.interp(np.arange(len(frame)), known, frame[known])

    def phase_ticks(self, phase: str) -> np.ndarray:
        return np.flatnonzero(np.asarray(self.phase) == phase)

    def delayed(self, length: int) -> "Plan":
        """This plan ``length`` ticks long: its first tick held longer (phase ``home``) in front."""
        extra = max(0, length - len(self))
        return dataclasses.replace(
            self,
            q=[self.q[0]] * extra + self.q,
            tcp=[self.tcp[0]] * extra + self.tcp,
            phase=["home"] * extra + self.phase,
            frame=[np.nan] * extra + self.frame,
        )


def approach_plan(
    base_pose: np.ndarray,
    grasp_tcp: np.ndarray,
    rate_hz: float,
    approach_s: float,
    route: Callable[[np.ndarray, np.ndarray], object],
    opening_m: float = panda.MAX_OPENING_M,
) -> Plan:
    """Home -> pre-grasp -> grasp -> close, for a grasp's world tool pose (4, 4), the pads
    ``opening_m`` apart until they close.

    ``route(q_home, q_pregrasp)`` returns the approach's :class:`rose_usd.collect.planning.Route`
    (``ArmChecker.route``)."""
    plan = Plan(rate_hz, opening_m=min(float(opening_m), panda.MAX_OPENING_M))
    open_, closed = plan.opening_m / 2, 0.0
    pre = backed_off(grasp_tcp, PREGRASP_M)
    q_pre, pos_err, rot_err = ik.solve((se3.invert(base_pose) @ pre)[None], panda.HOME_Q, n_seeds=16, iterations=80)
    plan.ik_error_m, plan.ik_error_deg = float(pos_err[0]), float(rot_err[0])
    plan.hold(panda.HOME_Q, 0.2, "home", open_, np.full((4, 4), np.nan))
    found = route(panda.HOME_Q, q_pre[0])  # from home's 7 arm joints to the pre-grasp's
    plan.approach = found.how
    length = np.abs(np.diff(found.waypoints, axis=0)).max(axis=1).sum()
    seconds = max(approach_s, length / APPROACH_SPEED_RAD_S)
    plan.joint_path(found.waypoints, seconds, "approach", open_)
    q = plan.path(base_pose, cartesian(pre, grasp_tcp, ticks(DESCEND_S, rate_hz)), q_pre[0], "descend", open_)
    plan.hold(q, SETTLE_S, "settle", open_, grasp_tcp)
    plan.fingers_to(q, open_, closed, CLOSE_S, "close", grasp_tcp)
    plan.hold(q, SQUEEZE_S, "squeeze", closed, grasp_tcp)
    return plan


def carry_plan(plan: Plan, base_pose: np.ndarray, follow_tcp: np.ndarray, lift_m: float) -> None:
    """Append lift -> follow -> place -> release to a plan that ends closed on the object.

    Args:
        follow_tcp: (N, 4, 4) world tool poses at the video's frames, already ``lift_m`` up.
    """
    rate = plan.rate_hz
    closed, open_ = 0.0, plan.opening_m / 2
    q = plan.q[-1].copy()
    grasp_tcp = plan.tcp[-1]
    q = plan.path(base_pose, cartesian(grasp_tcp, follow_tcp[0], ticks(LIFT_S, rate)), q, "lift", closed)
    q = plan.follow(base_pose, follow_tcp, q, closed)
    placed = lifted(follow_tcp[-1], -lift_m)
    q = plan.path(base_pose, cartesian(follow_tcp[-1], placed, ticks(PLACE_S, rate)), q, "place", closed)
    plan.fingers_to(q, closed, open_, RELEASE_S, "release", placed)
    back = backed_off(placed, RETREAT_M)
    plan.path(base_pose, cartesian(placed, back, ticks(RETREAT_S, rate)), q, "retreat", open_)
