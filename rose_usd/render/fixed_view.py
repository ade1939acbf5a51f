"""Renders from a camera that does not move, of a scene in which only some items do: what the
others show is rendered once, and each frame re-renders only the window the moving items project
into. Exact where nothing else depends on where they are: ``RenderScene``'s radiance is a
surface's albedo times the ambient term plus point lights, so a scene without point lights has no
shadows, and an item changes no pixel outside its own projection."""

from __future__ import annotations

import numpy as np

from rose_usd.core import se3
from rose_usd.core.color import linear_to_srgb8
from rose_usd.render.scene import RenderScene
from rose_usd.sim.resting import box_corners

HIDDEN_M = 1.0e5
"""How far below the world moving items are put while the rest is rendered: past the cameras'
far clip (1000 m), so no ray meets them."""

PAD_PX = 2
"""Pixels the window is grown by on every side around the moving items' projected bounds."""


def fixed_view_applies(scene: RenderScene, world_from_cv: np.ndarray, K: np.ndarray) -> bool:
    """Whether frames of these cameras ((N, 4, 4), (N, 3, 3)) can be rendered by ``FixedView``: one
    camera for every frame and no point lights."""
    world_from_cv, K = np.asarray(world_from_cv), np.asarray(K)
    one_camera = bool(np.all(world_from_cv == world_from_cv[0]) and np.all(K == K[0]))
    return one_camera and not scene.lighting.points


class FixedView:
    """``RenderScene.render_srgb8_and_labels`` from one camera, for scenes where only ``moving``
    items move (posed by the caller with ``scene.set_poses`` before each render) and no point
    light shines (``fixed_view_applies``)."""

    def __init__(
        self,
        scene: RenderScene,
        world_from_cv: np.ndarray,
        K: np.ndarray,
        width: int,
        height: int,
        *,
        spp: int,
        moving: list[str],
    ):
        if scene.lighting.points:
            raise ValueError("FixedView: a scene with point lights casts moving shadows")
        self.scene, self.spp, self.moving = scene, spp, list(moving)
        self.world_from_cv = np.asarray(world_from_cv, dtype=float)
        self.cv_from_world = se3.invert(self.world_from_cv)
        self.width, self.height = int(width), int(height)
        self.K_render, self.render_h = scene.square_pixels(K, height)
        vertices = {name: np.asarray(scene.items[name].mesh.vertices, float) for name in self.moving}
        self._corners = {name: box_corners(v.min(axis=0), v.max(axis=0)) for name, v in vertices.items()}
        self._background: np.ndarray | None = None
        self.last_window: tuple[int, int, int, int] | None = None
        """The window the last render re-rendered (None: none of it)."""

    def render_srgb8_and_labels(self, seed: int) -> tuple[np.ndarray, np.ndarray]:
        """The 8-bit sRGB image and item labels (as ``RenderScene.render_srgb8_and_labels``)."""
        scene = self.scene
        with scene.covering() as labels:
            img = self._background_film().copy()
            window = self.window()
            if window is not None:
                x0, y0, x1, y1 = window
                img[y0:y1, x0:x1] = scene.render_film(
                    self.world_from_cv, self.K_render, self.width, self.render_h, self.spp, seed, window
                )
            self.last_window = window
        img = scene.resampled(img, self.width, self.height)
        return linear_to_srgb8(img[..., :3]), scene.labels_of(img, labels)

    def window_share(self) -> float:
        """The share of the film the last render re-rendered."""
        if self.last_window is None:
            return 0.0
        x0, y0, x1, y1 = self.last_window
        return (x1 - x0) * (y1 - y0) / (self.width * self.render_h)

    def window(self) -> tuple[int, int, int, int] | None:
        """The pixels (x0, y0, x1, y1) of the square-pixel film the moving items' bounding boxes
        project into at their current poses, grown by ``PAD_PX``; the whole film where one reaches
        behind the camera; None where none is in view."""
        if not self.moving:
            return None
        corners = np.vstack([se3.transform_points(self.scene.items[n].pose, self._corners[n]) for n in self.moving])
        cam = se3.transform_points(self.cv_from_world, corners)
        w, h = self.width, self.render_h
        if np.any(cam[:, 2] <= 1e-3):
            return 0, 0, w, h
        K = self.K_render
        u = K[0, 0] * cam[:, 0] / cam[:, 2] + K[0, 2]
        v = K[1, 1] * cam[:, 1] / cam[:, 2] + K[1, 2]
        # pixel i covers [i - 0.5, i + 0.5)
        x0 = max(0, int(np.floor(u.min() + 0.5)) - PAD_PX)
        y0 = max(0, int(np.floor(v.min() + 0.5)) - PAD_PX)
        x1 = min(w, int(np.floor(u.max() + 0.5)) + 1 + PAD_PX)
        y1 = min(h, int(np.floor(v.max() + 0.5)) + 1 + PAD_PX)
        return (x0, y0, x1, y1) if x0 < x1 and y0 < y1 else None

    def _background_film(self) -> np.ndarray:
        """The square-pixel film with the moving items out of sight, made on first use."""
        if self._background is None:
            scene = self.scene
            poses = {name: scene.items[name].pose.copy() for name in self.moving}
            away = se3.make_pose(np.eye(3), np.array([0.0, 0.0, -HIDDEN_M]))
            scene.set_poses({name: away @ pose for name, pose in poses.items()})
            try:
                self._background = scene.render_film(
                    self.world_from_cv, self.K_render, self.width, self.render_h, self.spp, 0
                )
            finally:
                scene.set_poses(poses)
        return self._background
