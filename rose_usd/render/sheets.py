"""Contact sheets of a reconstruction (a run folder or its composed stage), every few frames,
optionally cropped to a region of interest and enlarged (real clips' objects can be 20-40 px
wide); the gate writes the first two into ``report/``, the segment stage the first into
``masks/sheet.jpg``:

- ``mask_sheet``: each object's mask (its own colour) and the interactor's (blue) over the video;
- ``object_sheet``: each object's mesh posed by the trajectory layer, drawn through the world
  layer's camera (filled outline in the object's colour), with the mask's outline in red;
- ``outline_sheet``: one object's mask outline (green) and the interactor's (blue), on a window
  that follows the object, enlarged: for judging masks frame by frame.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
from pxr import Usd

from rose_usd.case.layout import Case
from rose_usd.core import se3
from rose_usd.core.pinhole import silhouette
from rose_usd.layers.masks import INTERACTOR, read_masks
from rose_usd.layers.objects import default_pose, object_paths, visual_mesh
from rose_usd.layers.trajectory import object_poses
from rose_usd.layers.world import read_cameras
from rose_usd.usd.stage import open_stage

Source = Path | Usd.Stage
"""A run folder (its ``rose.usda`` is opened) or a stage."""

COLOURS = [(0, 230, 0), (255, 60, 200), (255, 200, 0), (0, 220, 255)]
HAND = (40, 80, 255)
SHEET_FRAMES = 16
"""The contact sheets the stages write (``masks/sheet.jpg``, ``report/``) show about this many
frames, spread over the video."""


def sheet_every(n_frames: int) -> int:
    """The frame step of the contact sheets that show about SHEET_FRAMES frames of a video."""
    return max(1, -(-n_frames // SHEET_FRAMES))


def mask_sheet(
    case: Case,
    run_dir: Source,
    path: Path,
    *,
    every: int = 20,
    crop: tuple[int, int, int, int] | None = None,
    tile_w: int = 320,
    cols: int = 4,
    label=None,
) -> Path:
    """Write ``path``: the masks of ``run_dir`` (an output folder with a masks layer) over the
    frames of ``case``, every ``every`` frames; ``crop`` is (x0, y0, x1, y1) in pixels;
    ``label(t)`` adds text under the frame number."""
    masks = read_masks(_open(run_dir), case.n_frames, (case.height, case.width))

    def mask_of(name: str, t: int) -> np.ndarray | None:
        return masks.mask(name, t) if masks.has(name) else None

    frames = range(0, case.n_frames, every)
    return masks_sheet(case, frames, mask_of, masks.names, path, crop=crop, tile_w=tile_w, cols=cols, label=label)


def masks_sheet(case: Case, frames, mask_of, names, path: Path, *, crop=None, tile_w=320, cols=4, label=None) -> Path:
    """Write ``path``: ``mask_of(name, t)`` (a boolean mask or None) of each object in ``names``
    (its own colour) and of the interactor (blue) over ``frames`` of ``case``."""
    tiles = []
    for t in frames:
        rgb = case.rgb(t)
        over = rgb.copy()
        hand = mask_of(INTERACTOR, t)
        if hand is not None:
            over[hand] = HAND
        for k, name in enumerate(names):
            m = mask_of(name, t)
            if m is not None:
                over[m] = COLOURS[k % len(COLOURS)]
        tiles.append(_tile(cv2.addWeighted(rgb, 0.45, over, 0.55, 0), t, crop, tile_w, label))
    return _write(tiles, cols, path)


def object_sheet(
    case: Case,
    run_dir: Source,
    path: Path,
    *,
    every: int = 20,
    crop: tuple[int, int, int, int] | None = None,
    tile_w: int = 320,
    cols: int = 4,
) -> Path:
    """Write ``path``: every object's mesh at its trajectory pose over the frames of ``case``
    (shaded in the object's colour, outlined), with its mask's outline (red)."""
    n = case.n_frames
    stage = _open(run_dir)
    cams = read_cameras(stage, n)
    masks = read_masks(stage, n, (case.height, case.width))
    names = list(object_paths(stage))
    meshes = {name: visual_mesh(stage, name) for name in names}
    poses = {name: object_poses(stage, name, n) for name in names}
    rest = {name: se3.invert(default_pose(stage, name)) for name in names}  # the meshes are posed there
    tiles = []
    for t in range(0, n, every):
        rgb = case.rgb(t)
        image = rgb.copy()
        for k, name in enumerate(names):
            moved = poses[name][t] @ rest[name]
            vertices = se3.transform_points(moved, meshes[name].vertices)
            sil = silhouette(vertices, meshes[name].faces, cams.world_from_cv[t], cams.K[t], case.width, case.height)
            colour = COLOURS[k % len(COLOURS)]
            image[sil] = (0.5 * image[sil] + 0.5 * np.array(colour)).astype(np.uint8)
            _outline(image, sil, colour)
            m = masks.mask(name, t) if name in masks.names else None
            if m is not None:
                _outline(image, m, (255, 0, 0))
        tiles.append(_tile(image, t, crop, tile_w, None))
    return _write(tiles, cols, path)


def outline_sheet(
    case: Case,
    run_dir: Source,
    path: Path,
    name: str,
    *,
    every: int = 6,
    window: tuple[int, int] = (120, 100),
    scale: int = 3,
    cols: int = 6,
) -> Path:
    """Write ``path``: object ``name``'s mask outline (green, all of its parts and holes) and the
    interactor's (blue) over the frames of ``case``, every ``every`` frames, each on a ``window``
    (w, h) pixel window centred on the mask (where it was last seen when it is empty), enlarged
    ``scale`` times without smoothing."""
    n = case.n_frames
    masks = read_masks(_open(run_dir), n, (case.height, case.width))
    w, h = window
    centre = (case.width // 2, case.height // 2)
    tiles = []
    for t in range(0, n, every):
        m = masks.mask(name, t)
        if m is not None and m.any():
            ys, xs = np.nonzero(m)
            centre = (int(np.median(xs)), int(np.median(ys)))
        x0 = int(np.clip(centre[0] - w // 2, 0, max(case.width - w, 0)))
        y0 = int(np.clip(centre[1] - h // 2, 0, max(case.height - h, 0)))
        big = cv2.resize(
            case.rgb(t)[y0 : y0 + h, x0 : x0 + w], None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST
        )
        hand = masks.mask(INTERACTOR, t) if masks.has(INTERACTOR) else None
        for mask, colour, kind in ((hand, HAND, cv2.RETR_EXTERNAL), (m, COLOURS[0], cv2.RETR_LIST)):
            if mask is None:
                continue
            crop = mask[y0 : y0 + h, x0 : x0 + w].astype(np.uint8)
            crop = cv2.resize(crop, None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST)
            contours, _ = cv2.findContours(crop, kind, cv2.CHAIN_APPROX_NONE)
            cv2.drawContours(big, contours, -1, colour, 2)
        cv2.putText(big, str(t), (6, 22), cv2.FONT_HERSHEY_SIMPLEX, 0.7, (255, 255, 0), 2, cv2.LINE_AA)
        tiles.append(big)
    return _write(tiles, cols, path)


def _outline(image: np.ndarray, mask: np.ndarray, colour) -> None:
    contours, _ = cv2.findContours(mask.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    cv2.drawContours(image, contours, -1, colour, 1)


def _tile(image: np.ndarray, t: int, crop, tile_w: int, label) -> np.ndarray:
    if crop is not None:
        x0, y0, x1, y1 = crop
        image = image[y0:y1, x0:x1]
    tile = cv2.resize(
        image, (tile_w, int(round(tile_w * image.shape[0] / image.shape[1]))), interpolation=cv2.INTER_AREA
    )
    text = f"{t}" + (f"  {label(t)}" if label is not None else "")
    cv2.putText(tile, text, (5, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 0), 1, cv2.LINE_AA)
    return tile


def _write(tiles: list[np.ndarray], cols: int, path: Path) -> Path:
    while len(tiles) % cols:
        tiles.append(np.zeros_like(tiles[0]))
    sheet = np.vstack([np.hstack(tiles[i : i + cols]) for i in range(0, len(tiles), cols)])
    path.parent.mkdir(parents=True, exist_ok=True)
    params = [cv2.IMWRITE_JPEG_QUALITY, 80] if path.suffix.lower() in (".jpg", ".jpeg") else []
    cv2.imwrite(str(path), cv2.cvtColor(sheet, cv2.COLOR_RGB2BGR), params)
    return path


def _open(source: Source) -> Usd.Stage:
    return source if isinstance(source, Usd.Stage) else open_stage(Path(source) / "rose.usda")
