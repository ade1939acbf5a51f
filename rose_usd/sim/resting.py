"""Where the video shows each object at rest: the frames in which it is seen, no hand touches it
and it does not move. The trajectory stage holds each such run at one pose rested on what
supports it (``trajectory.rests``); the gate's rest check starts from the first resting frame
(where the object starts) and, when it rests again later, the last (where it was left): an object
set down in the air, or into the table, moves there in the simulator though it rests in the
video. An object that rests in no frame (held from the first frame to the last) has nothing to
check."""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from rose_usd.core.runs import true_runs
from rose_usd.layers.masks import INTERACTOR, Masks

STILL_M = 0.003
"""An object is still at frame t when no corner of its bounding box moves more than this from
frame t-1 to t or from t to t+1 [m]."""
TOUCH_FRACTION = 0.01
"""The interactor touches an object when its mask, grown by this fraction of the image width (at
least 3 px), meets the object's mask."""
MIN_RUN_S = 0.15
"""Resting frames count only in runs at least this long [s] (at least 3 frames)."""


@dataclass(frozen=True)
class RestCheck:
    frame: int
    """The frame whose poses the check starts from."""
    names: tuple[str, ...]
    """The objects checked there (each object is checked at its first and last resting frame)."""
    resting: tuple[str, ...]
    """Every object resting at that frame (they take part; the others are set aside)."""


def box_corners(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """The 8 corners (8, 3) of the axis-aligned box from ``lo`` to ``hi``."""
    return np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])


def posed_corners(poses: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """The box ``corners`` (object frame, (8, 3)) in the world at each of ``poses`` (N, 4, 4): (N, 8, 3)."""
    return np.einsum("nij,kj->nki", poses[:, :3, :3], corners) + poses[:, None, :3, 3]


def still_frames(poses: np.ndarray, corners: np.ndarray, still_m: float = STILL_M) -> np.ndarray:
    """Per frame, whether the object's bounding box ``corners`` (object frame, (8, 3)) at
    ``poses`` (N, 4, 4) moves less than ``still_m`` into and out of that frame."""
    world = posed_corners(poses, corners)
    step = np.zeros(len(poses))
    step[1:] = np.linalg.norm(world[1:] - world[:-1], axis=2).max(axis=1)
    after = np.append(step[1:], 0.0)
    return (step < still_m) & (after < still_m)


def still_from_start(poses: np.ndarray, corners: np.ndarray, still_m: float = STILL_M) -> np.ndarray:
    """The frames from the first up to the first in which a corner of the object's box (``corners``,
    object frame) at ``poses`` (N, 4, 4) lies ``still_m`` or more from where frame 0 puts it: where
    the object stage rested the object, before anything moved it (a hand beside it at the start,
    adjacent in the image, is not yet holding it; a slow turn leaves that place too)."""
    world = posed_corners(poses, corners)
    moved = np.flatnonzero(np.linalg.norm(world - world[0], axis=2).max(axis=1) >= still_m)
    out = np.zeros(len(poses), bool)
    out[: moved[0] if len(moved) else len(poses)] = True
    return out


def untouched_frames(masks: Masks, name: str, n_frames: int) -> np.ndarray:
    """Per frame, whether object ``name`` has a mask there and the interactor's mask, grown by
    ``TOUCH_FRACTION`` of the width, does not meet it (a frame without the object's mask shows
    nothing at rest)."""
    out = np.zeros(n_frames, bool)
    kernel = None
    for t in range(n_frames):
        mask = masks.mask(name, t)
        if mask is None or not mask.any():
            continue
        hand = masks.mask(INTERACTOR, t) if masks.has(INTERACTOR) else None
        if hand is None or not hand.any():
            out[t] = True
            continue
        if kernel is None:
            r = max(3, int(round(TOUCH_FRACTION * mask.shape[1])))
            kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
        out[t] = not np.any(cv2.dilate(hand.astype(np.uint8), kernel).astype(bool) & mask)
    return out


def resting_frames(stage, objects: dict[str, str], n_frames: int) -> dict[str, np.ndarray]:
    """Per object (name -> prim path), the frames it rests in: still, and untouched by the
    interactor or still from the start."""
    from rose_usd.layers.masks import read_masks
    from rose_usd.layers.trajectory import object_poses
    from rose_usd.sim.rest import body_corners

    masks = read_masks(stage, n_frames)
    corners = body_corners(stage, objects)
    out = {}
    for name in objects:
        poses = object_poses(stage, name, n_frames)
        still = still_frames(poses, corners[name])
        out[name] = still & (untouched_frames(masks, name, n_frames) | still_from_start(poses, corners[name]))
    return out


def resting_runs(resting: np.ndarray, min_frames: int) -> list[tuple[int, int]]:
    """(first, last) frame of each run of ``resting`` frames at least ``min_frames`` long."""
    return [(a, b) for a, b in true_runs(resting) if b - a + 1 >= min_frames]


def min_run_frames(fps: float) -> int:
    """The fewest frames a resting run counts from: ``MIN_RUN_S``, at least 3 frames."""
    return max(3, math.ceil(MIN_RUN_S * fps - 1e-9))


def rest_checks(resting: dict[str, np.ndarray], fps: float) -> list[RestCheck]:
    """The frames to start the rest check from: each object's first resting frame and, when it
    rests again later, its last (runs shorter than ``MIN_RUN_S`` not counted), in frame order,
    objects sharing a frame checked together; an object that rests in no frame is in none."""
    min_frames = min_run_frames(fps)
    kept = {name: np.zeros_like(r) for name, r in resting.items()}
    wanted: dict[int, list[str]] = {}
    for name, r in resting.items():
        runs = resting_runs(r, min_frames)
        for first, last in runs:
            kept[name][first : last + 1] = True
        starts = [runs[0][0], runs[-1][1]] if len(runs) > 1 else [r[0] for r in runs]
        for t in starts:
            wanted.setdefault(t, []).append(name)
    return [RestCheck(t, tuple(names), tuple(n for n in resting if kept[n][t])) for t, names in sorted(wanted.items())]
