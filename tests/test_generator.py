"""The synthetic case generator: layout, ground-truth consistency and determinism."""

import hashlib

import numpy as np
import pytest

from rose_usd.case import load_case
from rose_usd.case.gt import GroundTruth
from rose_usd.core import se3
from rose_usd.io.images import read_depth_m, read_mask
from rose_usd.synth.generate import GenerateConfig, generate_case
from rose_usd.synth.motion import Task
from rose_usd.synth.shapes import ObjectShape


@pytest.fixture(scope="module")
def small_case(tmp_path_factory):
    out = tmp_path_factory.mktemp("gen") / "lift-mug"
    return generate_case(
        GenerateConfig(task=Task.LIFT, shape=ObjectShape.MUG, seed=3, n_frames=12, width=96, height=72, spp=4), out
    )


def test_layout_is_a_valid_case(small_case):
    """The generated folder is a case: rgb/, depth/, cam_K.txt, rose.toml and gt/ agree on 12 frames."""
    case = load_case(small_case)
    assert (case.n_frames, case.width, case.height, case.fps) == (12, 96, 72, 30.0)
    assert case.has_depth and case.K().shape == (3, 3)
    assert [o.name for o in case.config.objects] == ["Mug"]
    assert case.config.objects[0].category == "mug" and case.config.objects[0].prompt.box is not None
    gt = GroundTruth(small_case / "gt")
    assert gt.n_frames == 12 and len(gt.camera_poses()) == 12 and len(gt.object_poses("Mug")) == 12


def test_depth_agrees_with_ground_truth_geometry(small_case):
    """Clean depth (gt/depth) at the object's mask pixels back-projects onto the true object surface (< 2 mm)."""
    import trimesh

    case = load_case(small_case)
    gt = GroundTruth(small_case / "gt")
    mesh = gt.object_mesh("Mug")
    tm = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)
    K = case.K()
    for t in (0, 6, 11):
        depth = read_depth_m(gt.depth_dir / f"{t:06d}.png")
        mask = read_mask(gt.mask_dir("Mug") / f"{t:06d}.png") & (depth > 0)
        v, u = np.nonzero(mask)
        assert len(u) > 10
        rays = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u, dtype=float)], axis=1)
        pts_cam = rays * depth[v, u][:, None]
        world = se3.transform_points(gt.camera_poses()[t], pts_cam)
        local = se3.transform_points(se3.invert(gt.object_poses("Mug")[t]), world)
        dist = np.abs(trimesh.proximity.signed_distance(tm, local))
        # depth is stored in whole millimeters: allow quantization plus grazing angles
        assert np.median(dist) < 0.001 and np.percentile(dist, 90) < 0.002


def test_object_starts_at_rest_on_the_table(small_case):
    """At frame 0 the object's lowest point is on the support surface z = 0 and it is not moving."""
    gt = GroundTruth(small_case / "gt")
    mesh = gt.object_mesh("Mug")
    poses = gt.object_poses("Mug")
    lowest = se3.transform_points(poses[0], mesh.vertices)[:, 2].min()
    assert lowest == pytest.approx(0.0, abs=1e-6)
    np.testing.assert_allclose(poses[1], poses[0], atol=1e-6)


def test_same_seed_same_case(tmp_path):
    """Generation is deterministic in its seed."""
    cfg = GenerateConfig(seed=11, n_frames=10, width=64, height=48, spp=2)
    a = generate_case(cfg, tmp_path / "a")
    b = generate_case(cfg, tmp_path / "b")
    for rel in ("rgb/000002.png", "depth/000001.png", "gt/camera.tum", "gt/scene.json"):
        assert hashlib.sha256((a / rel).read_bytes()).digest() == hashlib.sha256((b / rel).read_bytes()).digest(), rel


@pytest.mark.parametrize("task", list(Task), ids=lambda t: t.value)
def test_every_task_starts_and_ends_at_rest_on_a_support(task, tmp_path):
    """Each task's objects rest at the start and the end (on the table or on each other), move in
    between, and stay over the table."""
    case = generate_case(
        GenerateConfig(task=task, shape=ObjectShape.BOX, seed=21, n_frames=30, width=64, height=48, spp=1),
        tmp_path / task.value,
    )
    gt = GroundTruth(case / "gt")
    layout = gt.data["layout"]
    half = np.asarray(layout["table_half_extent"])
    moved = []
    for obj in gt.objects:
        poses = gt.object_poses(obj.name)
        mesh = gt.object_mesh(obj.name)
        np.testing.assert_allclose(poses[1], poses[0], atol=1e-9)
        np.testing.assert_allclose(poses[-1], poses[-2], atol=1e-9)
        for t in (0, len(poses) - 1):
            lowest = se3.transform_points(poses[t], mesh.vertices)[:, 2].min()
            assert lowest >= -1e-6
            center = poses[t][:2, 3] - np.asarray(layout["table_center"])
            assert np.all(np.abs(center) < half)
        moved.append(
            float(np.linalg.norm(poses[-1][:3, 3] - poses[0][:3, 3]))
            + se3.rotation_angle_deg(poses[-1][:3, :3].T @ poses[0][:3, :3]) / 100
        )
    if task is Task.UNSTACK:
        base, top = gt.objects
        assert moved[0] == pytest.approx(0.0, abs=1e-9)  # the base stays
        start_top = se3.transform_points(gt.object_poses("Top")[0], gt.object_mesh("Top").vertices)[:, 2].min()
        base_height = gt.object_mesh("Base").vertices[:, 2].max()
        assert start_top == pytest.approx(base_height, abs=1e-6)  # the top starts on the base
        end_top = se3.transform_points(gt.object_poses("Top")[-1], gt.object_mesh("Top").vertices)[:, 2].min()
        assert end_top == pytest.approx(0.0, abs=1e-6)  # and ends on the table
    else:
        assert max(moved) > 0.05
