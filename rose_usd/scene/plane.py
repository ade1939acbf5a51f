"""The plane scene backend: the support surface and a textured backdrop, for videos without depth
(built in ``scene.backdrop``).

An RGB-only world knows one surface for sure: the support plane (z = 0) the objects rest on. What
lies beyond it (walls, furniture, a person) has no depth. So the scene is:

1. **Support** (visual and collider): the support plane as far as the reference camera (frame 0)
   sees it, out to ``wall_distance`` (``backdrop_reach`` times the camera's horizontal distance to
   the world origin, the object's foot, and at least ``object_reach`` times the farthest foot of
   an object masked in that frame, within 0.3-5 m, so every object stands on it): its visual mesh is textured from the
   video, and the collider is that region of the plane as a solid slab ``thickness_m`` thick (a
   prism: watertight by construction, checked as every collider is).
2. **Backdrop** (visual only, not collidable, named so): everything the camera sees beyond that
   distance or above the horizon, on a vertical cylinder of that radius around the camera's
   vertical, so floor and backdrop meet without a seam (a photo studio's cyclorama). Its depth is
   a choice, not a measurement: for a static camera, and for one that only turns, any depth
   re-renders the same picture; for a moving camera the backdrop is wrong by its parallax, which
   the gate's SSIM then shows.

Both are one grid over the reference image (``grid_px`` apart), extended to cover what the other
frames see, each vertex on the plane or the cylinder along its pixel's ray. The texture holds the
extended reference image plane: each texel is the median color of its 3D point's projections
into up to ``texture_frames`` frames spread over the video where no object's or interactor's mask
(grown by ``mask_margin_px``) covers it: the static background, objects and hands taken out,
what they always hid filled by inpainting. Lit by a unit ambient light (the video's own lighting
is in the texture).
"""

from __future__ import annotations

from rose_usd.scene.backdrop import author_plane
from rose_usd.stage_api import StageContext


def run(ctx: StageContext) -> None:
    author_plane(ctx)
