"""The object's texture tracked between frames (``rose_usd.trajectory.flow``) as constraints on the
tracker's registration: what depth leaves free, the image motion fixes."""

from __future__ import annotations

import cv2
import numpy as np
import trimesh

from rose_usd.core import se3
from rose_usd.core.pinhole import project
from rose_usd.trajectory import flow
from rose_usd.trajectory.config import TrackerConfig
from rose_usd.trajectory.tracker import Model, _exp, register

K = np.array([[500.0, 0, 160], [0, 500.0, 120], [0, 0, 1]])


def _project(world_from_cv: np.ndarray, points: np.ndarray) -> np.ndarray:
    return np.stack(project(se3.transform_points(se3.invert(world_from_cv), points), K), axis=1)


def test_the_gauss_newton_terms_are_the_residuals_derivative():
    """g = J^T r: for pixels that a small model-side step ``xi`` would explain, H xi equals g
    to first order (1 %)."""
    rng = np.random.default_rng(0)
    pose = se3.look_at(np.array([0.3, -0.4, 0.5]), np.array([0.0, 0.0, 0.05]))
    points = rng.normal(scale=0.03, size=(40, 3)) + [0.0, 0.0, 0.05]
    center = points.mean(axis=0)
    motion = se3.make_pose(se3.rotation_about(np.array([0.0, 0.0, 1.0]), 0.3), np.array([0.01, 0.02, 0.0]))
    xi = np.array([1e-4, -2e-4, 1.5e-4, 1e-4, 2e-4, -1e-4])
    step = se3.make_pose(np.eye(3), center) @ _exp(xi) @ se3.make_pose(np.eye(3), -center)
    stepped = se3.invert(step @ se3.invert(motion))
    here = _project(pose, se3.transform_points(motion, points))
    there = _project(pose, se3.transform_points(stepped, points))
    exact = flow.Features(points, here, se3.invert(pose), K)
    H, _ = flow.terms(exact, motion, center, 1.0)
    _, g = flow.terms(flow.Features(points, here - (there - here), se3.invert(pose), K), motion, center, 1.0)
    np.testing.assert_allclose(H @ xi, g, rtol=0.01, atol=1e-3 * np.abs(g).max())


def test_the_texture_fixes_the_spin_depth_cannot_see():
    """A can (r 3.3 cm) seen only by its wall, spun 8 deg about its axis: its depth fits at any
    spin, so ICP keeps the start (within 1 deg); with its printed corners followed in the image
    it recovers the spin to 0.1 deg. With the default settings, the pull toward the start (a
    filter on the turn rate) holds it back to a third of the spin in one frame, and a heavier
    flow weight overcomes it."""
    can = trimesh.creation.cylinder(radius=0.033, height=0.11, sections=96)
    can.apply_translation([0.0, 0.0, 0.055])
    model = Model.from_mesh(can.vertices, can.faces, 3000)
    eye = np.array([0.45, -0.35, 0.35])
    pose = se3.look_at(eye, np.array([0.0, 0.0, 0.05]))
    spin = se3.make_pose(se3.rotation_about(np.array([0.0, 0.0, 1.0]), np.radians(8.0)), np.zeros(3))
    pts, tri = trimesh.sample.sample_surface_even(can, 4000, seed=2)
    normals = can.face_normals[tri]
    wall = (np.abs(normals[:, 2]) < 0.5) & (np.einsum("ij,ij->i", normals, pts - eye) < 0)
    observed = se3.transform_points(spin, pts[wall])  # a cylinder's wall spun is the same surface
    printed = pts[wall][::40]  # corners of its print, on the object at frame 0
    seen = flow.Features(printed, _project(pose, se3.transform_points(spin, printed)), se3.invert(pose), K)

    for prior in (0.0, 0.001):
        blind = register(model, observed, eye, np.eye(4), prior_weight=prior)
        assert se3.rotation_angle_deg(blind.motion[:3, :3]) < 1.0
    fit = register(model, observed, eye, np.eye(4), features=seen, flow_weight=10.0)
    err = se3.invert(spin) @ fit.motion
    assert se3.rotation_angle_deg(err[:3, :3]) < 0.1
    assert np.linalg.norm(err[:3, 3]) < 5e-4
    cfg = TrackerConfig()
    shipped = register(
        model, observed, eye, np.eye(4), prior_weight=cfg.prior_weight, features=seen, flow_weight=cfg.flow_weight
    )
    assert 2.0 < se3.rotation_angle_deg(shipped.motion[:3, :3]) < 4.0
    heavy = register(model, observed, eye, np.eye(4), prior_weight=cfg.prior_weight, features=seen, flow_weight=300.0)
    assert 6.0 < se3.rotation_angle_deg(heavy.motion[:3, :3]) < 8.0


def test_corners_of_a_shifted_texture_are_followed_and_put_on_the_object():
    """A speckled plane 0.5 m in front of a still camera, shifted 3 px right and 2 px up in the
    next frame: its corners are found there, and their object points are the previous frame's
    depth carried back by the previous motion."""
    rng = np.random.default_rng(1)
    speckle = cv2.GaussianBlur((rng.random((240, 320)) * 255).astype(np.uint8), (0, 0), 1.5)
    shifted = np.roll(speckle, (-2, 3), axis=(0, 1))
    where = np.zeros((240, 320), bool)
    where[60:180, 80:240] = True
    depth = np.full((240, 320), 0.5, np.float32)
    camera = se3.look_at(np.array([0.2, -0.3, 0.6]), np.array([0.0, 0.0, 0.0]))
    K_prev = K.copy()
    K_prev[0, 0] = 450.0  # the earlier frame's intrinsics differ: they must be the ones used for it
    moved_by = se3.make_pose(se3.rotation_about(np.array([0.0, 0.0, 1.0]), 0.4), np.array([0.01, 0.02, 0.0]))
    got = flow.track_features(
        (speckle, where, depth),
        shifted,
        (camera, K_prev),
        (camera, K),
        moved_by,
        region=np.roll(where, (-2, 3), (0, 1)),
    )
    assert got is not None and len(got) >= 50
    seen_prev = se3.transform_points(se3.invert(camera), se3.transform_points(moved_by, got.points))
    np.testing.assert_allclose(seen_prev[:, 2], 0.5)  # on the previous depth, in the previous camera
    start = np.stack(project(seen_prev, K_prev), axis=1)
    np.testing.assert_allclose(np.median(got.pixels - start, axis=0), [3.0, -2.0], atol=0.1)
    assert flow.track_features((speckle, where, depth), shifted, (camera, K), (camera, K), moved_by,
                               region=np.zeros_like(where)) is None  # fmt: skip


def test_a_solid_of_revolution_is_tracked_without_its_texture_flow():
    """A can's or a cup's outline does not turn with it: the flow is off for those categories and
    on for a mug (its handle) or an object of no known category."""
    from types import SimpleNamespace

    from rose_usd.trajectory.tracker import _settings_for

    objects = [
        SimpleNamespace(name=n, category=c) for n, c in [("A", "can"), ("B", "Cup"), ("C", "mug"), ("D", "thing")]
    ]
    ctx = SimpleNamespace(case=SimpleNamespace(config=SimpleNamespace(objects=objects)))
    ctx.config = SimpleNamespace(tracker=TrackerConfig())
    weights = {o.name: _settings_for(ctx, o.name).flow_weight for o in objects}
    assert weights == {"A": 0.0, "B": 0.0, "C": 10.0, "D": 10.0}
