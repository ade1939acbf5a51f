"""The trajectory's resting runs held at one pose and rested on what supports them
(``trajectory.rests``): a set-down measured 2 mm into the table and tilted 4 deg, with jitter,
becomes one level pose on the table; the run from frame 0 holds the default pose; what is not a
rest (drifting, or far inside the scene) keeps its poses."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from rose_usd.core import se3
from rose_usd.sim.resting import box_corners
from rose_usd.sim.settle import CLEARANCE_M
from rose_usd.trajectory.rests import _rest_run, level, mean_pose
from rose_usd.usd.geom import MeshData

SIZE = 0.06
EASE = 5
"""Frames over which a held run's change fades out before and after it (0.15 s at 30 fps)."""


def _table():
    slab = trimesh.creation.box(extents=(0.6, 0.6, 0.2))
    slab.apply_translation([0.0, 0.0, -0.1])  # top at z = 0
    return np.asarray(slab.vertices), np.asarray(slab.faces)


def _cube() -> MeshData:
    box = trimesh.creation.box(extents=(SIZE, SIZE, SIZE))  # object frame at its centre
    return MeshData(np.asarray(box.vertices), np.asarray(box.faces))


def _pose(x: float, bottom_z: float, tilt_deg: float = 0.0, yaw_deg: float = 0.0) -> np.ndarray:
    rot = se3.rotation_about([0, 0, 1], np.radians(yaw_deg)) @ se3.rotation_about([1, 0, 0], np.radians(tilt_deg))
    return se3.make_pose(rot, [x, 0.0, bottom_z + 0.5 * SIZE])


def _track(rng) -> np.ndarray:
    """30 frames: at rest on the table (0-9), carried 10 cm (10-19), set down at x = 0.1 measured
    2 mm deep and tilted 4 deg about x, each frame jittered by 0.3 mm and 0.2 deg (20-29)."""
    poses = [_pose(0.0, 0.0) for _ in range(10)]
    poses += [_pose(0.01 * k, 0.03) for k in range(10)]
    for _ in range(10):
        jitter = se3.make_pose(se3.rotation_about(rng.normal(size=3), np.radians(0.2)), rng.normal(0, 3e-4, 3))
        poses.append(jitter @ _pose(0.1, -0.002, tilt_deg=4.0, yaw_deg=30.0))
    return np.array(poses)


def _run(poses, first, last):
    mesh = _cube()
    meshes = {"Cube": mesh}
    corners = box_corners(mesh.vertices.min(axis=0), mesh.vertices.max(axis=0))
    fixed = np.zeros(len(poses), bool)
    fixed[first : last + 1] = True
    args = (corners, _table(), lambda name: mesh.vertices, poses[0].copy(), 30.0, fixed)
    return _rest_run("Cube", first, last, {"Cube": poses}, meshes, *args)


def test_a_set_down_is_held_level_and_on_the_table():
    poses = _track(np.random.default_rng(0))
    before = poses.copy()
    done = _run(poses, 20, 29)
    assert done["held"] and done["settle_lift_m"] == pytest.approx(0.002 + CLEARANCE_M, abs=5e-4)
    held = poses[20:30]
    assert np.allclose(held, held[0])  # one pose
    up = held[0][:3, :3] @ np.array([0.0, 0.0, 1.0])
    assert np.degrees(np.arccos(min(up[2], 1.0))) < 0.1  # level again: the face it stood on at frame 0 is down
    bottom = se3.transform_points(held[0], _cube().vertices)[:, 2].min()
    assert bottom == pytest.approx(CLEARANCE_M, abs=2e-4)
    # the yaw and the place are the run's: within the jitter
    assert np.linalg.norm(held[0][:2, 3] - [0.1, 0.0]) < 1e-3
    yaw = np.degrees(np.arctan2(held[0][1, 0], held[0][0, 0]))
    assert yaw == pytest.approx(30.0, abs=0.5)
    assert np.array_equal(poses[: 20 - EASE], before[: 20 - EASE])  # nothing before the easing
    # the 5 frames before the set-down take 5/6 ... 1/6 of its change: no jump into the held pose
    centre = _cube().vertices.mean(axis=0)

    def moved(t):
        return se3.transform_points(poses[t], centre[None])[0] - se3.transform_points(before[t], centre[None])[0]

    for j in range(1, EASE + 1):
        t, share = 20 - j, 1.0 - j / (EASE + 1)
        assert np.allclose(moved(t), share * moved(20), atol=1e-9)


def test_the_run_from_frame_0_holds_the_default_pose():
    poses = _track(np.random.default_rng(1))
    poses[3, 0, 3] += 0.001  # a tracked millimetre while it rests
    done = _run(poses, 0, 9)
    assert done == {"held": True, "settle_lift_m": 0.0}
    assert np.allclose(poses[:10], _pose(0.0, 0.0))


def test_a_drifting_run_and_a_pose_deep_in_the_table_keep_their_poses():
    poses = _track(np.random.default_rng(2))
    poses[20:30, 0, 3] += np.linspace(0.0, 0.03, 10)  # 3 cm over the run
    before = poses.copy()
    assert _run(poses, 20, 29)["held"] is False
    assert np.array_equal(poses, before)
    poses[20:30, 2, 3] -= 0.05  # 5 cm into the table: a wrong pose, not a contact error
    poses[20:30, 0, 3] = 0.1
    before = poses.copy()
    assert _run(poses, 20, 29) == {"held": False, "why": "more than 3 cm inside the scene"}
    assert np.array_equal(poses, before)


def test_level_turns_small_tilts_only_and_mean_pose_averages():
    flat = _pose(0.0, 0.0)
    tilted = _pose(0.0, 0.0, tilt_deg=8.0, yaw_deg=20.0)
    out = level(tilted, flat, _cube().vertices)
    assert np.degrees(np.arccos(min((out[:3, :3] @ [0, 0, 1.0])[2], 1.0))) < 1e-4
    assert np.allclose(se3.transform_points(out, _cube().vertices).mean(axis=0), tilted[:3, 3])
    on_side = _pose(0.0, 0.0, tilt_deg=90.0)  # set down on another face: left as it is
    assert np.array_equal(level(on_side, flat, _cube().vertices), on_side)
    poses = np.array([_pose(0.0, 0.0, yaw_deg=a) for a in (-2.0, 0.0, 2.0)])
    assert np.allclose(mean_pose(poses), _pose(0.0, 0.0), atol=1e-9)


def _cut_ball(radius=0.025, cut=0.8):
    """A ball of 1280 faces with a flat cut through its bottom, ``cut`` x radius below its center
    (a fused ball's flat pad): (vertices, faces)."""
    import trimesh

    ball = trimesh.creation.icosphere(subdivisions=3, radius=radius)
    cut_mesh = ball.slice_plane([0, 0, -cut * radius], [0, 0, 1], cap=True)
    return np.asarray(cut_mesh.vertices), np.asarray(cut_mesh.faces)


def test_a_round_object_set_down_turned_is_stood_on_its_flat_face_not_a_facet():
    """A ball with a flat pad, set down turned every which way: stable_down turns it onto the pad
    (its center of mass stands 37 deg inside the pad's rim), never onto one of the small facets
    of its round side that happens to face down (1-2 deg inside theirs: Newton rolls it off; cups-
    rgbd's ball rolled 2.7 m in the gate's rest check). A box stays on the face nearest down."""
    from scipy.spatial.transform import Rotation

    from rose_usd.core import se3
    from rose_usd.trajectory.rests import stable_down

    vertices, faces = _cut_ball()
    for seed in range(8):
        rot = Rotation.random(random_state=seed).as_matrix()
        pose = se3.make_pose(rot, np.array([0.1, 0.2, 0.3]))
        turn = stable_down(vertices, pose, faces)
        pad_normal = turn @ rot @ np.array([0.0, 0.0, -1.0])
        assert pad_normal[2] < -0.9999, (seed, pad_normal)
    box = np.array([[x, y, z] for x in (-0.05, 0.05) for y in (-0.03, 0.03) for z in (-0.02, 0.02)])
    tilt = Rotation.from_euler("x", 30, degrees=True).as_matrix()
    turn = stable_down(box, se3.make_pose(tilt, np.zeros(3)))
    assert np.allclose(turn @ tilt @ np.array([0.0, 0.0, -1.0]), [0, 0, -1], atol=1e-9)
