"""Camera video of a rollout (``collect.render``): the stage's scene and objects and the robot's
links at each tick's simulated poses, rendered with Mitsuba from the reconstructed camera.

A tick of the follow stands for a video frame (the nearest, where the arm follows slower than the
video: ``Rollout.frame``) and sees through that frame's camera; the ticks before it (home to
grasp) see through frame 0's, those after it (release, retreat) through the last frame's. The
moved object is drawn where the simulation put it; other objects where their trajectory has them
at that frame."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
from pxr import Usd, UsdGeom

from rose_usd.collect.author import link_meshes
from rose_usd.collect.rollout import Rollout
from rose_usd.core import se3
from rose_usd.layers.world import read_cameras
from rose_usd.render.from_usd import StageRenderer
from rose_usd.render.scene import RenderItem
from rose_usd.sim import panda
from rose_usd.usd import paths

LINK_ITEM = "robot:{}"


def even_size(width: int, height: int, scale: float) -> tuple[int, int]:
    """The video's size at ``scale`` of the camera's, rounded down to even numbers (yuv420p)."""
    return max(2, int(width * scale) // 2 * 2), max(2, int(height * scale) // 2 * 2)


class RolloutCamera:
    """Renders rollouts of the robot moving object ``object_name`` in ``stage``."""

    def __init__(self, stage: Usd.Stage, object_name: str, n_frames: int, *, scale: float, spp: int):
        meshes = link_meshes()
        self.links = [(li, LINK_ITEM.format(link)) for li, link in enumerate(panda.chain().links) if link in meshes]
        extra = [RenderItem(LINK_ITEM.format(link), mesh, pose=np.eye(4)) for link, mesh in meshes.items()]
        self.renderer = StageRenderer(stage, extra=extra)
        self.cameras = read_cameras(stage, n_frames)
        self.n_frames, self.spp = n_frames, spp
        self.width, self.height = even_size(self.cameras.width, self.cameras.height, scale)
        # the moved object's meshes relative to its body frame (the frame its simulated pose gives)
        body = stage.GetPrimAtPath(paths.object_path(object_name))
        body_inv = se3.invert(_world(body))
        self.parts = {
            name: body_inv @ _world(prim) for name, prim in self.renderer.animated_under(str(body.GetPath())).items()
        }
        s = np.diag([self.width / self.cameras.width, self.height / self.cameras.height, 1.0])
        self.K = np.einsum("ij,tjk->tik", s, self.cameras.K)

    def frames(self, rollout: Rollout, links: np.ndarray) -> Iterator[np.ndarray]:
        """The rollout's frames, one per tick, (H, W, 3) uint8 sRGB; ``links``: (T, L, 4, 4) world
        poses of the links (``rollout.links``, or forward kinematics of a batched rollout)."""
        scene = self.renderer.scene
        for tick in range(rollout.frames):
            t = int(np.clip(np.rint(rollout.frame[tick]), 0, self.n_frames - 1))
            poses = self.renderer.poses_at(t)
            poses.update({name: rollout.object_pose[tick] @ offset for name, offset in self.parts.items()})
            poses.update({name: links[tick, li] for li, name in self.links})
            scene.set_poses(poses)
            yield scene.render_srgb8(
                self.cameras.world_from_cv[t], self.K[t], self.width, self.height, spp=self.spp, seed=tick
            )


def _world(prim: Usd.Prim) -> np.ndarray:
    return np.asarray(UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(Usd.TimeCode(0)), dtype=float).T
