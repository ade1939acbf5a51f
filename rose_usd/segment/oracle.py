"""Oracle segmentation: ground-truth object and interactor masks of a benchmark case."""

from __future__ import annotations

from pathlib import Path

from rose_usd.errors import InputError
from rose_usd.io.images import read_mask
from rose_usd.segment.tracks import INTERACTOR, MaskTrack, author_and_check
from rose_usd.stage_api import StageContext


def _read_all(folder: Path, n: int, width: int, height: int):
    """Check that all n masks exist (now), then read them one by one (lazily)."""
    files = [folder / f"{t:06d}.png" for t in range(n)]
    missing = [f for f in files if not f.is_file()]
    if missing:
        raise InputError(
            f"{len(missing)} ground-truth mask(s) missing, first {missing[0].name}",
            path=folder,
            hint="regenerate the case",
        )
    return _masks(files, width, height)


def _masks(files: list[Path], width: int, height: int):
    for f in files:
        mask = read_mask(f)
        if mask.shape != (height, width):
            raise InputError(
                f"mask is {mask.shape[1]}x{mask.shape[0]}, frames are {width}x{height}",
                path=f,
                hint="regenerate the case",
            )
        yield mask


def run(ctx: StageContext) -> None:
    case = ctx.case
    gt = case.gt
    n = ctx.time_info.n_frames
    tracks = []
    for spec in case.config.objects:
        gt.object(spec.name)  # the object must exist in the ground truth
        tracks.append(MaskTrack(spec.name, _read_all(gt.mask_dir(spec.name), n, case.width, case.height)))
    if gt.interactor is not None:
        tracks.append(MaskTrack(INTERACTOR, _read_all(gt.mask_dir("interactor"), n, case.width, case.height)))
    author_and_check(
        ctx,
        tracks,
        lambda name: InputError(
            f"object {name!r} is never visible in the ground-truth masks", path=gt.mask_dir(name), hint="check the case"
        ),
    )
