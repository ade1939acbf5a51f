"""Structure from motion with COLMAP (pycolmap, CPU SIFT): the cameras of a moving RGB-only video.

Keyframes spread over the video are written to a scratch folder (downscaled to ``max_side``),
SIFT features extracted (4096 per image: the keyframes overlap heavily and 8192 doubles the time
for no better pose), matched sequentially with each keyframe's ``overlap`` successors, verified,
and mapped incrementally into one model (the largest when several come out). A given K is held
fixed (PINHOLE); without one the focal length starts from the field-of-view guess and bundle
adjustment refines it (SIMPLE_RADIAL, self-calibration). Masked pixels (the hand, the object:
things that move) give no features. Poses come back as OpenCV world_from_camera in the map's own
frame and unit (no metric scale: the caller finds it).
"""

from __future__ import annotations

import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from rose_usd.core import se3


@dataclass
class SfmResult:
    poses: dict[int, np.ndarray]
    """Keyframe index (into the frames given) -> world_from_camera (4, 4), OpenCV axes, map units."""
    K: np.ndarray
    """Intrinsics at the video's resolution (3, 3) [px]."""
    distortion: float
    """SIMPLE_RADIAL's k1 (0 for PINHOLE)."""
    points: np.ndarray
    """Map points (P, 3), map units."""
    colors: np.ndarray
    """Their sRGB8 colors (P, 3)."""
    observations: dict[int, tuple[np.ndarray, np.ndarray]]
    """Keyframe index -> (pixel positions (M, 2) at the video's resolution, point indices (M,))."""
    reprojection_px: float
    wall_s: float
    models: int
    """How many separate models the mapper made (1 when everything joined)."""


def run_sfm(
    frames: list[np.ndarray],
    K_guess: np.ndarray,
    *,
    fix_K: bool,
    masks: list[np.ndarray | None] | None = None,
    max_side: int = 640,
    overlap: int = 8,
    max_features: int = 4096,
    num_threads: int = 1,
    max_runtime_s: float = 600.0,
) -> SfmResult | None:
    """SfM over ``frames`` (RGB uint8, one size); None when no model of at least 3 images forms.

    Args:
        K_guess: intrinsics at the frames' resolution; held fixed when ``fix_K``.
        masks: per frame, bool (H, W) of pixels to leave out (True = masked), or None.
        num_threads: pycolmap's threads for extraction, matching and mapping. One (the default)
            makes the map repeat bit for bit: with two, images were numbered in the order their
            features finished and the mapper chose differently each run (push-box-s13-rgb's 24
            keyframes, 3 runs: 13, 24 and 24 images registered, focal 325, 88 and 132 px; with
            one, 3 identical maps).
    """
    import pycolmap

    # fatal only: INFO is a line per image and step, and its errors ("Failed to create any sparse
    # model") are outcomes the caller reports in its own words
    pycolmap.logging.minloglevel = 3
    h, w = frames[0].shape[:2]
    s = min(1.0, max_side / max(w, h))
    sw, sh = int(round(w * s)), int(round(h * s))
    sx, sy = sw / w, sh / h
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="rose-sfm-") as tmp:
        root = Path(tmp)
        images, mask_dir = root / "images", root / "masks"
        names = _write_frames(frames, masks, images, mask_dir, (sw, sh), s)
        k = np.array(K_guess, dtype=float)
        reader = _reader_options(k, sx, sy, fix_K, mask_dir)
        database = root / "database.db"
        _extract_and_match(database, images, names, reader, num_threads, max_features, overlap)
        options = _mapping_options(num_threads, max_runtime_s, fix_K)
        out = root / "sparse"
        out.mkdir()
        models = pycolmap.incremental_mapping(database, images, out, options=options)
    if not models:
        return None
    rec = max(models.values(), key=lambda r: r.num_reg_images())
    if rec.num_reg_images() < 3:
        return None
    return _result(rec, len(models), k, fix_K, sx, sy, s, t0)


def _write_frames(frames, masks, images: Path, mask_dir: Path, size: tuple[int, int], s: float) -> list[str]:
    """The frames as JPEG files in ``images`` (and their kept pixels as PNG files in ``mask_dir``),
    downscaled by ``s`` to ``size`` (w, h) [px]; their file names."""
    sw, sh = size
    images.mkdir()
    names = []
    for i, rgb in enumerate(frames):
        name = f"{i:05d}.jpg"
        small = cv2.resize(rgb, (sw, sh), interpolation=cv2.INTER_AREA) if s < 1 else rgb
        cv2.imwrite(str(images / name), cv2.cvtColor(small, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 95])
        names.append(name)
        if masks is not None and masks[i] is not None:
            mask_dir.mkdir(exist_ok=True)
            keep = ~cv2.resize(masks[i].astype(np.uint8), (sw, sh), interpolation=cv2.INTER_NEAREST).astype(bool)
            cv2.imwrite(str(mask_dir / f"{name}.png"), keep.astype(np.uint8) * 255)
    return names


def _reader_options(k: np.ndarray, sx: float, sy: float, fix_K: bool, mask_dir: Path):
    """COLMAP's image reader options: the camera model and its starting parameters (``k`` scaled by
    ``sx``, ``sy`` to the written images), and the masks when there are any."""
    import pycolmap

    fx, fy = k[0, 0] * sx, k[1, 1] * sy
    cx, cy = (k[0, 2] + 0.5) * sx - 0.5, (k[1, 2] + 0.5) * sy - 0.5
    reader = pycolmap.ImageReaderOptions()
    if fix_K:
        reader.camera_model = "PINHOLE"
        reader.camera_params = f"{fx},{fy},{cx},{cy}"
    else:
        reader.camera_model = "SIMPLE_RADIAL"
        reader.camera_params = f"{0.5 * (fx + fy)},{cx},{cy},0"
    if mask_dir.is_dir():
        reader.mask_path = str(mask_dir)
    return reader


def _extract_and_match(
    database: Path, images: Path, names: list[str], reader, num_threads: int, max_features: int, overlap: int
) -> None:
    """SIFT features of the images into ``database`` (one camera, CPU), matched sequentially."""
    import pycolmap

    extraction = pycolmap.FeatureExtractionOptions()
    extraction.num_threads = num_threads
    extraction.sift.max_num_features = max_features
    pycolmap.extract_features(
        database,
        images,
        image_names=names,
        camera_mode=pycolmap.CameraMode.SINGLE,
        reader_options=reader,
        extraction_options=extraction,
        device=pycolmap.Device.cpu,
    )
    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = num_threads
    pairing = pycolmap.SequentialPairingOptions()
    pairing.overlap = overlap
    pairing.quadratic_overlap = True
    pycolmap.match_sequential(database, matching_options=matching, pairing_options=pairing, device=pycolmap.Device.cpu)


def _mapping_options(num_threads: int, max_runtime_s: float, fix_K: bool):
    """The incremental mapper's options: seeded, time-limited, refining the intrinsics unless fixed."""
    import pycolmap

    options = pycolmap.IncrementalPipelineOptions()
    options.num_threads = num_threads
    options.random_seed = 0
    options.mapper.random_seed = 0
    options.triangulation.random_seed = 0
    options.max_runtime_seconds = int(max_runtime_s)
    options.ba_refine_focal_length = not fix_K
    options.ba_refine_extra_params = not fix_K
    options.ba_refine_principal_point = False
    return options


def _result(rec, models: int, k: np.ndarray, fix_K: bool, sx: float, sy: float, s: float, t0: float) -> SfmResult:
    """The reconstruction ``rec`` at the video's resolution (undoing ``sx``, ``sy``): K, map points,
    keyframe poses and observations; its wall time since ``t0`` [s]."""
    camera = next(iter(rec.cameras.values()))
    params = np.asarray(camera.params, dtype=float)
    if fix_K:
        K = k.copy()
        k1 = 0.0
    else:
        f, pcx, pcy, k1 = params
        K = np.array([[f / sx, 0, (pcx + 0.5) / sx - 0.5], [0, f / sy, (pcy + 0.5) / sy - 0.5], [0, 0, 1.0]])
    point_ids = list(rec.point3D_ids())
    index = {pid: i for i, pid in enumerate(point_ids)}
    points = np.array([rec.point3D(pid).xyz for pid in point_ids]).reshape(-1, 3)
    colors = np.array([rec.point3D(pid).color for pid in point_ids]).reshape(-1, 3).astype(np.uint8)
    poses, observations = _poses_and_observations(rec, index, sx, sy)
    return SfmResult(
        poses=poses,
        K=K,
        distortion=float(k1),
        points=points,
        colors=colors,
        observations=observations,
        reprojection_px=float(rec.compute_mean_reprojection_error()) / s,
        wall_s=time.perf_counter() - t0,
        models=models,
    )


def _poses_and_observations(rec, index: dict, sx: float, sy: float) -> tuple[dict, dict]:
    """Each registered keyframe's world_from_camera (4, 4) and its observations: pixel positions
    (M, 2) at the video's resolution and indices (M,) of the map points (``index``: point id -> index)."""
    poses, observations = {}, {}
    for image in rec.images.values():
        if not image.has_pose:
            continue
        i = int(Path(image.name).stem)
        cam_from_world = np.asarray(image.cam_from_world().matrix(), dtype=float)
        poses[i] = se3.invert(np.vstack([cam_from_world, [0, 0, 0, 1]]))
        uv, ids = [], []
        for p2d in image.points2D:
            if p2d.has_point3D() and p2d.point3D_id in index:
                uv.append(p2d.xy)
                ids.append(index[p2d.point3D_id])
        uv = np.array(uv, dtype=float).reshape(-1, 2)
        uv = np.column_stack([(uv[:, 0] + 0.5) / sx - 0.5, (uv[:, 1] + 0.5) / sy - 0.5]) if len(uv) else uv
        observations[i] = (uv, np.array(ids, dtype=int))
    return poses, observations
