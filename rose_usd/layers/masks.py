"""The masks layer (``/World/Masks``, ``RoseMaskAPI``): per object and for the interactor, a mask
file per frame, visible pixels and confidence. Later stages read masks only through
:class:`Masks`, which resolves each frame's ``rose:masks:file`` asset; nobody rebuilds the path."""

from __future__ import annotations

import functools
from pathlib import Path

import cv2
import numpy as np
from pxr import Usd

from rose_usd.errors import InputError, StageError
from rose_usd.io.images import read_mask
from rose_usd.usd import paths, tokens

INTERACTOR = "Interactor"
"""The interactor's (hand and arm) track name: its masks sit at ``/World/Masks/Interactor``."""


class Masks:
    """The mask tracks of a composed stage.

    ``names`` are the object tracks in the order they were written; :data:`INTERACTOR` is the
    interactor's track. Masks are boolean (H, W) arrays; a frame without a file reads as None.
    """

    def __init__(self, stage: Usd.Stage, n_frames: int, shape: tuple[int, int] | None = None):
        self.stage, self.n_frames, self.shape = stage, n_frames, shape
        root = stage.GetPrimAtPath(paths.OBJECT_MASKS)
        if not stage.GetPrimAtPath(paths.MASKS):
            raise StageError(
                "the stage has no masks layer", path=stage.GetRootLayer().identifier, hint="run the segment stage"
            )
        # every child, also where no world layer defines /World (a stage of the segment stage alone)
        self.names = [p.GetName() for p in root.GetAllChildren()] if root else []

    def _prim(self, name: str) -> Usd.Prim:
        path = paths.INTERACTOR_MASK if name == INTERACTOR else paths.object_mask(name)
        prim = self.stage.GetPrimAtPath(path)
        if not prim:
            raise StageError(
                f"the masks layer has no track {name!r}",
                path=self.stage.GetRootLayer().identifier,
                hint="re-run the segment stage",
            )
        return prim

    def has(self, name: str) -> bool:
        path = paths.INTERACTOR_MASK if name == INTERACTOR else paths.object_mask(name)
        return bool(self.stage.GetPrimAtPath(path))

    def require(self, name: str) -> None:
        """An InputError naming the stage when object ``name`` has no mask track (a rose.toml
        object added after the segment stage ran)."""
        if not self.has(name):
            raise InputError(
                f"no masks of object {name!r}", path=self.stage.GetRootLayer().identifier, hint="run the segment stage"
            )

    def file(self, name: str, t: int) -> Path | None:
        """The mask file of track ``name`` at frame t, None when there is none."""
        asset = self._prim(name).GetAttribute(tokens.MASKS_FILE).Get(Usd.TimeCode(t))
        if asset is None or not asset.resolvedPath:
            return None
        return Path(asset.resolvedPath)

    def where(self, name: str) -> Path:
        """Where track ``name``'s masks are (their folder), for messages."""
        f = self.file(name, 0) if self.has(name) else None
        return f.parent if f is not None else Path(self.stage.GetRootLayer().identifier)

    def mask(self, name: str, t: int) -> np.ndarray | None:
        """Track ``name``'s mask at frame t (bool (H, W)), None when the frame has no file."""
        f = self.file(name, t)
        if f is None:
            return None
        mask = read_mask(f)
        if self.shape is not None and mask.shape != self.shape:
            raise InputError(
                f"mask is {mask.shape[1]}x{mask.shape[0]}, frames are {self.shape[1]}x{self.shape[0]}",
                path=f,
                hint="re-run the segment stage",
            )
        return mask

    def track(self, name: str) -> list[np.ndarray | None]:
        """Every frame's mask of track ``name``."""
        return [self.mask(name, t) for t in range(self.n_frames)]

    def visible_pixels(self, name: str) -> np.ndarray:
        """Visible pixels per frame, (N,) int, as the segment stage counted them."""
        attr = self._prim(name).GetAttribute(tokens.MASKS_VISIBLE_PIXELS)
        return np.array([int(attr.Get(Usd.TimeCode(t)) or 0) for t in range(self.n_frames)])

    @functools.lru_cache(maxsize=64)  # noqa: B019  one reader per stage run
    def _cached(self, name: str, t: int) -> np.ndarray | None:
        return self.mask(name, t)

    def occluders(self, name: str, t: int, shape: tuple[int, int], *, grow_px: int, objects=None) -> np.ndarray:
        """What may stand in front of object ``name`` or beside it in frame t: the masks of the
        other objects (``objects``, default every object track) and of the interactor, grown by
        ``grow_px`` (bool, ``shape``)."""
        out = np.zeros(shape, np.uint8)
        others = [o for o in (self.names if objects is None else objects) if o != name] + [INTERACTOR]
        for other in others:
            if not self.has(other):
                continue
            m = self._cached(other, t)
            if m is not None:
                out |= m.astype(np.uint8)
        return cv2.dilate(out, np.ones((2 * grow_px + 1, 2 * grow_px + 1), np.uint8)).astype(bool)


def read_masks(stage: Usd.Stage, n_frames: int, shape: tuple[int, int] | None = None) -> Masks:
    """The masks layer's tracks on a composed stage; with ``shape`` (height, width), a mask of
    another size is an InputError naming its file."""
    return Masks(stage, n_frames, shape)
