"""The plane scene backend (RGB only): the support plane (z = 0), seen and collidable as a slab,
and beyond it a visual-only backdrop, both textured from the video. What it builds and why is
``scene.backdrop``'s (``author_plane``), which the stereo backend builds on too."""

from __future__ import annotations

from rose_usd.scene.backdrop import author_plane
from rose_usd.stage_api import StageContext


def run(ctx: StageContext) -> None:
    author_plane(ctx)
