"""Renders of a fixed camera that re-render only the window the moving items project into are
the whole renders' but for anti-aliasing noise at edges; the window is where the items are."""

from __future__ import annotations

import numpy as np
import pytest

from rose_usd.core import se3
from rose_usd.render.fixed_view import FixedView, fixed_view_applies
from rose_usd.render.lighting import Lighting, PointLight
from rose_usd.render.scene import RenderItem, RenderScene
from rose_usd.synth.shapes import box, sphere
from rose_usd.usd.geom import MeshData

W, H = 160, 120
K = np.array([[150.0, 0.0, 81.3], [0.0, 145.0, 57.6], [0.0, 0.0, 1.0]])  # fx != fy: resampled
CAMERA = se3.look_at([0.0, -0.45, 0.35], [0.0, 0.0, 0.0])


def _scene(lighting=None) -> RenderScene:
    ground = box((2.0, 2.0, 0.02), (0.0, 0.0, -0.01))
    ball = sphere(0.03, (0.08, 0.05, 0.03), subdivisions=3)
    cube = box((0.05, 0.05, 0.05))
    return RenderScene(
        [
            RenderItem("ground", MeshData(ground.vertices, ground.faces, color=(0.5, 0.45, 0.4)), moves=False),
            RenderItem("ball", MeshData(ball.vertices, ball.faces, color=(0.1, 0.3, 0.9)), label=2),
            RenderItem("cube", MeshData(cube.vertices, cube.faces, color=(0.9, 0.2, 0.1)), label=1),
        ],
        lighting or Lighting.unlit(),
    )


def _at(x: float, y: float, z: float = 0.025) -> np.ndarray:
    return se3.make_pose(se3.rotation_about(np.array([0.0, 0.0, 1.0]), 0.4), np.array([x, y, z]))


@pytest.mark.parametrize("where", [(0.0, 0.0), (-0.1, -0.05), (0.2, 0.1)])
def test_windowed_render_is_the_whole_render(where):
    scene = _scene()
    view = FixedView(scene, CAMERA, K, W, H, spp=4, moving=["cube"])
    scene.set_poses({"cube": _at(*where)})
    img, labels = view.render_srgb8_and_labels(seed=5)
    whole, whole_labels = scene.render_srgb8_and_labels(CAMERA, K, W, H, spp=4, seed=5)
    x0, y0, x1, y1 = view.last_window
    assert (x1 - x0) * (y1 - y0) < 0.25 * W * view.render_h
    for label in (1, 2):  # the moving cube and the ball that stays
        a, b = labels == label, whole_labels == label
        assert b.sum() > 50 and (a & b).sum() / (a | b).sum() > 0.95
    differs = np.abs(img.astype(int) - whole).max(axis=-1) > 2
    assert differs.mean() < 0.01  # anti-aliased edge pixels only


def test_window_is_none_off_screen_and_whole_behind_the_camera():
    scene = _scene()
    view = FixedView(scene, CAMERA, K, W, H, spp=2, moving=["cube"])
    scene.set_poses({"cube": _at(3.0, 0.0)})
    assert view.window() is None
    img, labels = view.render_srgb8_and_labels(seed=1)
    assert not (labels == 1).any() and (labels == 2).any()
    scene.set_poses({"cube": se3.make_pose(np.eye(3), CAMERA[:3, 3])})  # around the camera itself
    assert view.window() == (0, 0, W, view.render_h)


def test_only_fixed_cameras_without_point_lights():
    cams = np.repeat(CAMERA[None], 3, axis=0)
    assert fixed_view_applies(_scene(), cams, np.repeat(K[None], 3, axis=0))
    moved = cams.copy()
    moved[2, 0, 3] += 0.01
    assert not fixed_view_applies(_scene(), moved, np.repeat(K[None], 3, axis=0))
    lit = _scene(Lighting(ambient=(0.3, 0.3, 0.3), points=(PointLight((0.0, 0.0, 1.0), (1.0, 1.0, 1.0)),)))
    assert not fixed_view_applies(lit, cams, np.repeat(K[None], 3, axis=0))
    with pytest.raises(ValueError, match="point lights"):
        FixedView(lit, CAMERA, K, W, H, spp=2, moving=["cube"])
