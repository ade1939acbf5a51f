"""The foundationpose trajectory backend: FoundationPose's ob_in_cam/ files (its exact format,
np.savetxt of T_cam<-object) composed with the cameras; gaps filled and flagged; bad poses fail
before anything is written."""

from __future__ import annotations

import numpy as np
import pytest

from rose_usd.bench.evaluate import evaluate
from rose_usd.case.gt import GroundTruth
from rose_usd.core import se3
from rose_usd.errors import InputError
from rose_usd.io import foundationpose
from rose_usd.pipeline import Options, Pipeline
from rose_usd.trajectory.author import fill_gaps
from rose_usd.usd.stage import layer_file, read_provenance

BACKENDS = {"all": "oracle", "trajectory": "foundationpose"}


def test_gaps_are_interpolated_on_se3_and_held_at_the_ends():
    a = se3.make_pose(np.eye(3), [0.0, 0.0, 0.0])
    b = se3.make_pose(se3.rotation_about([0, 0, 1], np.radians(40.0)), [0.04, 0.0, 0.0])
    poses = np.stack([a, a, a, a, b, b, b])
    present = np.array([False, True, False, False, False, True, False])
    poses[1], poses[5] = a, b
    out, conf = fill_gaps(poses, present)
    assert conf.tolist() == [0.0, 1.0, 0.5, 0.5, 0.5, 1.0, 0.0]
    assert out[3][:3, 3] == pytest.approx([0.02, 0.0, 0.0])
    assert se3.rotation_angle_deg(out[3][:3, :3]) == pytest.approx(20.0)
    assert np.allclose(out[0], a) and np.allclose(out[6], b)


def _write_truth(case, drop=(), mesh_frame=np.eye(4)):
    """FoundationPose files of the sample's true motion: T_cam<-object of the true box per frame
    (of the mesh frame ``mesh_frame``, given in the box's frame)."""
    gt = GroundTruth(case / "gt")
    cams, objs = gt.camera_poses(), gt.object_poses("Box")
    for t in range(gt.n_frames):
        if t not in drop:
            foundationpose.write_pose(
                case / "perception" / "ob_in_cam" / f"{t:06d}.txt", se3.invert(cams[t]) @ objs[t] @ mesh_frame
            )
    return gt.n_frames


def test_true_poses_give_the_true_trajectory_and_gaps_are_flagged(tmp_path, case_copy):
    n = _write_truth(case_copy, drop=(5, 6, 7))
    out = tmp_path / "out"
    Pipeline(case_copy, out, Options(backends=BACKENDS)).run("trajectory")
    prov = read_provenance(layer_file(out, "trajectory"))
    facts = prov["results"]["objects"]["Box"]
    assert {k: facts[k] for k in ("frames_read", "frames_filled")} == {"frames_read": n - 3, "frames_filled": 3}
    # at rest before the push (frames 0-6) and after it (37-47): each run held at one pose
    assert [r["frames"] for r in facts["rests"]] == [[0, 6], [37, 47]] and all(r["held"] for r in facts["rests"])
    assert any("5-7" in w for w in prov["warnings"])
    score = evaluate(case_copy, out).objects[0]
    # the object stage lifted the true box ~6 mm out of the wrapped table: a constant offset
    assert score.ape_translation_m < 0.01
    assert score.rpe_translation_m < 0.0015  # interpolated frames of a smooth motion stay close
    assert score.rpe_rotation_deg < 0.5


def test_a_pose_that_is_not_a_rotation_names_its_file(tmp_path, case_copy):
    _write_truth(case_copy)
    bad = case_copy / "perception" / "ob_in_cam" / "000004.txt"
    pose = np.loadtxt(bad)
    pose[:3, :3] *= 1.2  # scaled: not a rotation
    np.savetxt(bad, pose)
    out = tmp_path / "out"
    with pytest.raises(InputError, match="000004.txt.*not a rotation"):
        Pipeline(case_copy, out, Options(backends=BACKENDS)).run("trajectory")
    assert not layer_file(out, "trajectory").exists()


def test_a_mesh_frame_turned_from_the_object_stages_keeps_the_path(tmp_path, case_copy):
    """FoundationPose's mesh frame need not be the object stage's (a can's yaw is arbitrary): the
    poses are re-expressed in the object stage's frame (the correction is on the object side), so
    the path in the world is FoundationPose's. Corrected on the world side instead, the whole path
    would turn about the world origin by the frames' 70 deg difference."""
    turn = se3.make_pose(se3.rotation_about([0, 0, 1], np.radians(70.0)), [0.01, -0.02, 0.0])
    _write_truth(case_copy, mesh_frame=turn)
    out = tmp_path / "out"
    Pipeline(case_copy, out, Options(backends=BACKENDS)).run("trajectory")
    score = evaluate(case_copy, out).objects[0]
    assert score.ape_translation_m < 0.01 and score.ape_rotation_deg < 0.5
    assert score.rpe_translation_m < 0.001 and score.rpe_rotation_deg < 0.1
