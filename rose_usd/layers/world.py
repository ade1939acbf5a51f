"""Metric depth per frame as the capture stage defined it, for the stages after it.

The world layer says where metric depth comes from: ``scaleSource = sensor`` (the case's depth/,
already metric) or a fit (``unidepth``, ``size-prior``, ...) of MegaSaM's depth, metric =
``scaleAlpha * depth + scaleBeta``. Readers get depth at the video's resolution, 0 where invalid.
An RGB-only world (capture ``sfm``) has none (``rose:world:metricDepth = false``,
``has_metric_depth``); its scale came from priors (``read_scale``: the cues and their uncertainty).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from pxr import Usd

from rose_usd.case.layout import Case
from rose_usd.errors import StageError
from rose_usd.geometry.registration import shift_depth
from rose_usd.io.megasam import metric_from_megasam, read_megasam
from rose_usd.usd import paths, tokens
from rose_usd.usd.camera import CameraTrack, read_camera

SENSOR_SOURCES = ("sensor", "oracle")
"""Scale sources under which later stages read the case's own depth/."""


def _scale_source(stage: Usd.Stage) -> str | None:
    """The world layer's ``rose:world:scaleSource``, None when the capture stage has not run."""
    world = stage.GetPrimAtPath(paths.WORLD)
    attr = world.GetAttribute(tokens.WORLD_SCALE_SOURCE) if world else None
    return attr.Get() if attr and attr.HasAuthoredValue() else None


def depth_is_sensor(stage: Usd.Stage) -> bool:
    """Whether later stages read the case's own depth/ (a sensor's, or ground truth's): then its
    scale holds from frame to frame, which MegaSaM's does only to a few %."""
    return _scale_source(stage) in SENSOR_SOURCES


def has_metric_depth(stage: Usd.Stage) -> bool:
    """Whether the world gives later stages metric depth per frame (``rose:world:metricDepth``;
    False for an RGB-only video, whose stages work from silhouettes and the support plane)."""
    world = stage.GetPrimAtPath(paths.WORLD)
    attr = world.GetAttribute(tokens.WORLD_METRIC_DEPTH) if world else None
    return bool(attr.Get()) if attr and attr.HasAuthoredValue() else _scale_source(stage) is not None


def metric_depth_reader(stage: Usd.Stage, case: Case, *, cache: int = 8) -> Callable[[int], np.ndarray]:
    """A function t -> metric depth (H, W) float32 [m] of frame t (0 = no depth), with a small cache."""
    source = _scale_source(stage)
    if source is None:
        raise StageError(
            "the world layer has no scale source", path=stage.GetRootLayer().identifier, hint="run the capture stage"
        )
    if not has_metric_depth(stage):
        raise StageError(
            "the world layer has no metric depth (an RGB-only video: capture backend sfm)",
            path=stage.GetRootLayer().identifier,
            hint="use the depth-free backends (scene stereo or plane, object silhouette, trajectory silhouette),"
            " or give depth",
        )
    if source in SENSOR_SOURCES:
        if not case.has_depth:
            raise StageError(
                f"capture used {source} depth but the case has no depth/", path=case.folder, hint="re-run capture"
            )
        dx, dy = depth_shift_px(stage)

        def read(t: int) -> np.ndarray:
            return shift_depth(case.depth_m(t), dx, dy)
    else:
        world = stage.GetPrimAtPath(paths.WORLD)
        alpha = float(world.GetAttribute(tokens.WORLD_SCALE_ALPHA).Get())
        beta = float(world.GetAttribute(tokens.WORLD_SCALE_BETA).Get())
        npz = case.megasam_file()
        if npz is None:
            raise StageError(
                f"capture used MegaSaM depth ({source}) but the case has no MegaSaM output",
                path=case.perception_dir,
                hint="re-run capture",
            )
        depths = read_megasam(npz).depths

        def read(t: int) -> np.ndarray:
            return metric_from_megasam(depths[t], alpha, beta, case.width, case.height)

    return cached_frames(read, cache)


def depth_shift_px(stage: Usd.Stage) -> tuple[int, int]:
    """(dx, dy): sensor depth pixel (x, y) shows colour pixel (x + dx, y + dy)."""
    value = stage.GetPrimAtPath(paths.WORLD).GetAttribute(tokens.WORLD_DEPTH_SHIFT_PX).Get()
    return (0, 0) if value is None else (int(value[0]), int(value[1]))


def cached_frames(read: Callable[[int], np.ndarray], size: int) -> Callable[[int], np.ndarray]:
    """``read`` (t -> depth [m]) with invalid values (NaN, inf, <= 0) set to 0 and the last
    ``size`` frames kept."""

    @functools.lru_cache(maxsize=size)
    def depth_of(t: int) -> np.ndarray:
        d = np.asarray(read(t), dtype=np.float32)
        return np.where(np.isfinite(d) & (d > 0), d, 0.0).astype(np.float32)

    return depth_of


@dataclass(frozen=True)
class ScaleInfo:
    """How the world's metric scale was found (RGB only: from priors, with an uncertainty)."""

    source: str
    uncertainty: float
    """Relative one-sigma [-]."""
    cues: dict[str, tuple[float, float]]
    """cue -> (meters per reconstruction unit, relative sigma)."""


def read_scale(stage: Usd.Stage) -> ScaleInfo:
    """The world's scale source, its uncertainty and the cues measured."""
    world = stage.GetPrimAtPath(paths.WORLD)
    names = list(world.GetAttribute(tokens.WORLD_SCALE_CUES).Get() or [])
    values = list(world.GetAttribute(tokens.WORLD_SCALE_CUE_VALUES).Get() or [])
    sigmas = list(world.GetAttribute(tokens.WORLD_SCALE_CUE_SIGMAS).Get() or [])
    return ScaleInfo(
        source=str(_scale_source(stage)),
        uncertainty=float(world.GetAttribute(tokens.WORLD_SCALE_UNCERTAINTY).Get() or 0.0),
        cues={str(n): (float(v), float(s)) for n, v, s in zip(names, values, sigmas, strict=True)},
    )


def read_cameras(stage: Usd.Stage, n_frames: int) -> CameraTrack:
    """The world layer's camera: OpenCV poses and intrinsics per frame."""
    return read_camera(stage, paths.CAMERA, n_frames)
