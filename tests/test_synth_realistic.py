"""The realistic generator: a hand whose fingers wrap the object without entering it, a mug that
lies the way a real one does, and a realistic case that is still a consistent case."""

import numpy as np
import pytest
import trimesh

from rose_usd.case import load_case
from rose_usd.case.gt import GroundTruth
from rose_usd.core import se3
from rose_usd.synth import hand, shapes
from rose_usd.synth.generate import GenerateConfig, _lying_rotation, generate_case
from rose_usd.synth.motion import Task


def _signed_distance(mesh: trimesh.Trimesh, points: np.ndarray) -> np.ndarray:
    return -trimesh.proximity.signed_distance(mesh, points)  # trimesh: positive inside


@pytest.mark.parametrize("shape", [shapes.ObjectShape.CAN, shapes.ObjectShape.MUG, shapes.ObjectShape.BOX])
def test_wrap_grip_surrounds_the_object_without_entering_it(shape):
    """Side grip: the hand's surface stays outside the object (>= -1 mm, the box's corners aside)
    and covers more than half of the turn around it at grip height."""
    rng = np.random.default_rng(4)
    spec = shapes.sample_object(shape, rng)
    sy, sz = spec.size_m[1], spec.size_m[2]
    object_from_hand = se3.make_pose(
        se3.rotation_between([-1.0, 0.0, 0.0], [0.0, 1.0, 0.0]), [0.0, -(0.5 * sy + 0.035), 0.6 * sz]
    )
    mesh, colors = hand.build_hand(
        spec.mesh,
        object_from_hand,
        np.array([0.0, 0.0, 1.0]),
        hand.Grip.WRAP,
        hand.sample_look(rng),
        rng,
        avoid=np.array([1.0, 0.0, 0.0]),
    )
    assert mesh.is_watertight and colors.shape == (len(mesh.vertices), 3)
    in_object = se3.transform_points(object_from_hand, mesh.vertices)
    depth = _signed_distance(spec.mesh, in_object)
    tolerance = 0.012 if shape is shapes.ObjectShape.BOX else 0.001  # fingers follow a box's corners only
    assert np.percentile(depth, 0.1) > -tolerance
    band = np.abs(in_object[:, 2] - 0.6 * sz) < 0.015
    near = band & (np.hypot(in_object[:, 0], in_object[:, 1]) < 0.5 * max(spec.size_m[:2]) + 0.03)
    angles = np.degrees(np.arctan2(in_object[near, 1], in_object[near, 0]))
    covered = np.unique(np.floor(angles / 10.0)).size * 10.0
    assert covered > 180.0
    if shape is shapes.ObjectShape.MUG:  # the fingers curl away from the handle (+X)
        assert not np.any(near & (in_object[:, 0] > 0.5 * sy + 0.012) & (np.abs(in_object[:, 1]) < 0.01))


def test_a_lying_mug_rests_on_its_body_and_its_handle():
    rng = np.random.default_rng(2)
    spec = shapes.sample_object(shapes.ObjectShape.MUG, rng)
    v = spec.mesh.vertices @ _lying_rotation(spec.mesh, rng).T
    z = v[:, 2] - v[:, 2].min()
    radial = np.hypot(spec.mesh.vertices[:, 0], spec.mesh.vertices[:, 1])
    handle = radial > radial[spec.mesh.vertices[:, 0] <= 0].max() + 0.002
    assert z[handle].min() < 0.0015 and z[~handle].min() < 1e-9
    # lying: the mug's axis is horizontal
    axis = _lying_rotation(spec.mesh, rng) @ np.array([0.0, 0.0, 1.0])
    assert abs(axis[2]) < 1e-9


@pytest.fixture(scope="module")
def realistic_case(tmp_path_factory):
    out = tmp_path_factory.mktemp("gen") / "place-mug-lying"
    config = GenerateConfig(
        task=Task.PLACE,
        shape=shapes.ObjectShape.MUG,
        seed=5,
        n_frames=12,
        width=120,
        height=90,
        spp=2,
        realistic=True,
        static_camera=True,
        lying=True,
    )
    return generate_case(config, out)


def test_realistic_case_is_consistent(realistic_case):
    """A static camera, a cloth under the lying mug, a hand in the interactor masks, and ground
    truth that the case loader accepts."""
    case = load_case(realistic_case)
    gt = GroundTruth(realistic_case / "gt")
    cams = gt.camera_poses()
    assert np.allclose(cams, cams[0])
    assert "Cloth" in [p.name for p in gt.parts]
    pose0 = gt.object_poses("Mug")[0]
    assert abs(pose0[2, 2]) < 0.5  # lying: its axis is horizontal
    mesh = gt.object_mesh("Mug")
    lowest = se3.transform_points(pose0, mesh.vertices)[:, 2].min()
    assert abs(lowest) < 1e-6  # on the cloth's top, z = 0
    assert gt.data["generator"]["realistic"] is True
    assert case.n_frames == 12
