"""Authoring mask tracks: PNGs under <out>/masks, their prims under /World/Masks and a contact
sheet, ``masks/sheet.jpg``.
Every segment backend ends here (author_and_check), so all of them write the same layer."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
from pxr import Sdf, Usd, UsdGeom

from rose_usd.io.images import write_mask
from rose_usd.layers.masks import INTERACTOR
from rose_usd.render.sheets import masks_sheet, sheet_every
from rose_usd.stage_api import StageContext
from rose_usd.usd import paths, schema, tokens
from rose_usd.usd.geom import relative_asset

SHEET = "sheet.jpg"
"""In ``masks/``: every object's mask and the interactor's over about 16 frames of the video."""


@dataclass(frozen=True)
class MaskTrack:
    """One object's (or the interactor's) masks over the video."""

    name: str
    """Object name, or INTERACTOR."""
    masks: Iterable[np.ndarray]
    """Boolean (H, W) masks, one per frame, in frame order (consumed once)."""
    confidence: np.ndarray | None = None
    """Per-frame confidence in [0, 1]; 1 everywhere if None."""


def author_tracks(ctx: StageContext, tracks: list[MaskTrack]) -> dict[str, np.ndarray]:
    """Write each track's PNGs and prim. Returns visible pixel counts per track, shape (N,)."""
    n = ctx.time_info.n_frames
    stage = ctx.stage
    folder = ctx.side_dir("masks")
    final_root = ctx.out_dir / "masks"
    world = stage.GetPrimAtPath(paths.WORLD)
    no_world = not (world and world.IsDefined())  # no world layer (the flow backend on RGB alone)
    UsdGeom.Scope.Define(stage, paths.MASKS)
    UsdGeom.Scope.Define(stage, paths.OBJECT_MASKS)
    counts, shown = {}, set(range(0, n, sheet_every(n)))
    sampled: dict[str, dict[int, np.ndarray]] = {}
    for track in tracks:
        is_interactor = track.name == INTERACTOR
        prim_path = paths.INTERACTOR_MASK if is_interactor else paths.object_mask(track.name)
        prim = UsdGeom.Scope.Define(stage, prim_path).GetPrim()
        prim.ApplyAPI(schema.MASK_API)
        prim.GetAttribute(tokens.MASKS_ROLE).Set("interactor" if is_interactor else "object")
        prim.GetAttribute(tokens.MASKS_OBJECT_NAME).Set("" if is_interactor else track.name)
        file_attr = prim.GetAttribute(tokens.MASKS_FILE)
        count_attr = prim.GetAttribute(tokens.MASKS_VISIBLE_PIXELS)
        conf_attr = prim.GetAttribute(tokens.MASKS_CONFIDENCE)
        conf = np.ones(n) if track.confidence is None else np.asarray(track.confidence, dtype=float)
        visible = np.zeros(n, dtype=np.int64)
        t = -1
        for t, mask in enumerate(track.masks):
            if t >= n:
                raise ValueError(f"mask track {track.name!r} has more than {n} frames")
            name = f"{track.name}/{t:06d}.png"
            write_mask(folder / name, mask)
            if t in shown:
                sampled.setdefault(track.name, {})[t] = mask
            visible[t] = int(np.count_nonzero(mask))
            code = Usd.TimeCode(t)
            file_attr.Set(Sdf.AssetPath(relative_asset(final_root / name, ctx.layer_dir)), code)
            count_attr.Set(int(visible[t]), code)
            conf_attr.Set(float(conf[t]), code)
        if t != n - 1:
            raise ValueError(f"mask track {track.name!r} has {t + 1} frames, expected {n}")
        counts[track.name] = visible
    if no_world:  # Define made /World a def here; this layer may only hold an over of it
        stage.GetEditTarget().GetLayer().GetPrimAtPath(paths.WORLD).specifier = Sdf.SpecifierOver
    names = [tr.name for tr in tracks if tr.name != INTERACTOR]
    masks_sheet(ctx.case, sorted(shown), lambda k, t: sampled.get(k, {}).get(t), names, folder / SHEET)
    return counts


def author_and_check(ctx: StageContext, tracks: list[MaskTrack], missing, **record) -> dict[str, np.ndarray]:
    """author_tracks, then raise ``missing(name)`` (an InputError) for an object no frame shows
    (the layer is then not written), and record visible frames and mean visible pixels with
    ``record``. Every segment backend ends here."""
    counts = author_tracks(ctx, tracks)
    for track in tracks:
        if track.name != INTERACTOR and not np.any(counts[track.name] > 0):
            raise missing(track.name)
    ctx.record(
        **record,
        visible_frames={k: int(np.count_nonzero(v)) for k, v in counts.items()},
        mean_visible_px={k: round(float(v.mean()), 1) for k, v in counts.items()},
    )
    return counts
