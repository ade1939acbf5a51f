"""The sam2 segment backend: import SAM 2's video masks (formats.md) from ``perception/masks``.

Object ids map to rose.toml's objects by ``segment.sam2.ids`` ("Name=id,..."), by default in order
(1, 2, ...). The hand is SAM 2's ``segment.sam2.interactor_id`` when it was prompted; otherwise the
interactor is what stands in front of the static world (as in the classical backend).
"""

from __future__ import annotations

import numpy as np

from rose_usd.errors import ConfigError, InputError
from rose_usd.geometry.background import StaticBackground
from rose_usd.io.sam2 import read_masks, read_object_mask
from rose_usd.layers.world import metric_depth_reader, read_cameras
from rose_usd.segment.interactor import interactor_mask
from rose_usd.segment.segmenter import Segmenter
from rose_usd.segment.tracks import INTERACTOR, MaskTrack, author_and_check
from rose_usd.stage_api import StageContext


def object_ids(given: tuple[tuple[str, int], ...], names: list[str]) -> dict[str, int]:
    """Object name -> SAM 2 id: ``segment.sam2.ids``, by default the objects in order, 1, 2, ..."""
    if not given:
        return {name: i for i, name in enumerate(names, start=1)}
    ids = dict(given)
    unknown = [n for n in ids if n not in names]
    if unknown:
        raise ConfigError(
            f"segment.sam2.ids names {', '.join(unknown)}, not an object of rose.toml",
            hint=f"objects: {', '.join(names)}",
        )
    missing = [n for n in names if n not in ids]
    if missing:
        raise ConfigError(
            f"segment.sam2.ids names no id for {', '.join(missing)}", hint="give every object of rose.toml an id"
        )
    return ids


def run(ctx: StageContext) -> None:
    case = ctx.case
    n = ctx.time_info.n_frames
    folder = case.sam2_dir
    frames = read_masks(folder)
    bad = sorted(t for t in frames if not 0 <= t < n)
    if bad:
        raise InputError(
            f"SAM 2 masks name frame {bad[0]}, the video has frames 0..{n - 1}",
            path=folder,
            hint="run SAM 2 on this video's frames",
        )
    names = [o.name for o in case.config.objects]
    ids = object_ids(ctx.config.sam2.ids, names)
    hand_id = ctx.config.sam2.interactor_id

    def mask_of(t: int, obj_id: int) -> np.ndarray:
        entries = frames.get(t)
        if not entries:
            return np.zeros((case.height, case.width), bool)
        m = read_object_mask(entries, obj_id)
        if m is None:
            return np.zeros((case.height, case.width), bool)
        if m.shape != (case.height, case.width):
            f = next(iter(entries.values()))
            raise InputError(
                f"SAM 2 mask is {m.shape[1]}x{m.shape[0]}, the video is {case.width}x{case.height}",
                path=f,
                hint="export SAM 2's masks at the video's resolution",
            )
        return m

    # read every frame once, checking sizes before anything is written
    obj_masks = {name: [mask_of(t, ids[name]) for t in range(n)] for name in names}
    missing = sorted(set(range(n)) - set(frames))
    if missing:
        ctx.warn(
            f"SAM 2 gave no mask for {len(missing)} frame(s) (first {missing[0]}): "
            "the objects count as not visible there"
        )
    if hand_id:
        hands = [mask_of(t, hand_id) for t in range(n)]
        interactor_source = "sam2"
    else:
        cameras = read_cameras(ctx.stage, n)
        depth_of = metric_depth_reader(ctx.stage, case, cache=24)
        seg = Segmenter(
            case.rgb,
            depth_of,
            cameras,
            ctx.config,
            StaticBackground(depth_of, cameras.world_from_cv, cameras.K, case.width, case.height),
        )
        hands = [interactor_mask(seg, t, [obj_masks[name][t] for name in names]) for t in range(n)]
        interactor_source = "static-world residual"
    tracks = [MaskTrack(name, iter(obj_masks[name])) for name in names] + [MaskTrack(INTERACTOR, iter(hands))]
    author_and_check(
        ctx,
        tracks,
        lambda name: InputError(
            f"object {name!r} (SAM 2 id {ids[name]}) is in no mask",
            path=folder,
            hint="check segment.sam2.ids against the ids SAM 2 used",
        ),
        object_ids=ids,
        interactor=interactor_source,
    )
