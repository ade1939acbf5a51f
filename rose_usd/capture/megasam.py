"""The megasam capture backend: import MegaSaM's cameras and depth, and make them metric.

MegaSaM's depth and translations are metric times an unknown per-video scale. The paper's global
alpha, beta (metric depth = alpha * MegaSaM depth + beta) are fitted robustly against an absolute
depth source, in this order of preference: the sensor's depth (depth/), UniDepth's npz
(perception/unidepth/), or a known object size from rose.toml (``size_m`` of the prompted
object, with its prompt box). The fit's residual is recorded. Translations scale by alpha.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from rose_usd.capture.intrinsics import resolve_K
from rose_usd.capture.world import author_tracked_world, fused_points, locate, prompted_objects
from rose_usd.case.layout import Case
from rose_usd.core import se3
from rose_usd.errors import InputError
from rose_usd.io.megasam import FAR_CLIP, MegaSamOutput, metric_from_megasam, read_megasam
from rose_usd.io.unidepth import read_unidepth
from rose_usd.stage_api import StageContext


def find_npz(case: Case) -> Path:
    path = case.megasam_file()
    if path is None:
        raise InputError(
            "no MegaSaM output (perception/*_sgd_cvd_hr.npz)",
            path=case.perception_dir,
            hint="run MegaSaM and copy its npz there, or choose --backend capture=rgbd",
        )
    return path


def fit_alpha_beta(
    relative: np.ndarray, metric: np.ndarray, *, iterations: int = 20
) -> tuple[float, float, float, int]:
    """Robust fit of metric = alpha * relative + beta (Huber IRLS). Returns alpha, beta, the
    median absolute residual [m] and the number of samples."""
    x, y = np.asarray(relative, dtype=float), np.asarray(metric, dtype=float)
    if len(x) < 100:
        raise InputError(
            f"only {len(x)} pixels have both MegaSaM and metric depth",
            hint="check that the absolute depth source covers the frames",
        )
    w = np.ones_like(x)
    alpha, beta = 1.0, 0.0
    for _ in range(iterations):
        a = np.stack([x * w, w], axis=1)
        alpha, beta = np.linalg.lstsq(a, y * w, rcond=None)[0]
        r = y - (alpha * x + beta)
        mad = 1.4826 * np.median(np.abs(r - np.median(r))) + 1e-9
        delta = 1.5 * mad
        w = np.sqrt(np.where(np.abs(r) <= delta, 1.0, delta / np.abs(r)))
    r = y - (alpha * x + beta)
    return float(alpha), float(beta), float(np.median(np.abs(r))), len(x)


def _samples(out: MegaSamOutput, frames: list[int], metric_of) -> tuple[np.ndarray, np.ndarray]:
    h, w = out.depths.shape[1:]
    xs, ys = [], []
    rng = np.random.default_rng(0)
    for t in frames:
        metric = cv2.resize(metric_of(t).astype(np.float32), (w, h), interpolation=cv2.INTER_NEAREST)
        rel = out.depths[t].astype(np.float32)
        valid = (metric > 0) & np.isfinite(metric) & (rel > 0) & (rel < FAR_CLIP)
        idx = np.flatnonzero(valid)
        idx = rng.choice(idx, size=min(len(idx), 20_000), replace=False) if len(idx) else idx
        xs.append(rel.reshape(-1)[idx])
        ys.append(metric.reshape(-1)[idx])
    return np.concatenate(xs), np.concatenate(ys)


def metric_scale(ctx: StageContext, out: MegaSamOutput, K_case: np.ndarray) -> tuple[float, float, float, str]:
    """alpha, beta, residual [m], source token."""
    case = ctx.case
    n = case.n_frames
    frames = sorted(set(np.linspace(0, n - 1, min(n, 24)).round().astype(int).tolist()))
    choice = ctx.config.megasam.scale_source.value
    uni = case.folder / "perception" / "unidepth"
    if choice in ("auto", "sensor") and case.has_depth:
        alpha, beta, res, _ = fit_alpha_beta(*_samples(out, frames, case.depth_m))
        return alpha, beta, res, "sensor"
    if choice in ("auto", "unidepth") and uni.is_dir():

        def unidepth(t: int) -> np.ndarray:
            path = uni / f"{case.frame_name(t)}.npz"
            if not path.is_file():
                raise InputError(
                    f"UniDepth output for frame {t} is missing",
                    path=path,
                    hint="run UniDepth on every frame (or on none)",
                )
            return read_unidepth(path).depth_m

        alpha, beta, res, _ = fit_alpha_beta(*_samples(out, frames, unidepth))
        return alpha, beta, res, "unidepth"
    if choice in ("auto", "size-prior"):
        return (*_size_prior(ctx, out, K_case), "size-prior")
    raise InputError(
        f"scale source {choice!r} is not available for this case",
        path=case.folder,
        hint="give depth/, perception/unidepth/, or size_m and a prompt box for an object in rose.toml",
    )


def _size_prior(ctx: StageContext, out: MegaSamOutput, K_case: np.ndarray) -> tuple[float, float, float]:
    """alpha from a known object size: the prompt box's width at the object's MegaSaM depth is
    the object's size in MegaSaM units. A rough scale (no offset); the residual says how rough."""
    spec = next((o for o in prompted_objects(ctx) if o.prompt.box is not None and "size_m" in o.overrides), None)
    if spec is None:
        raise InputError(
            "no absolute depth source: no depth/, no perception/unidepth/, no object with size_m and a prompt box",
            path=ctx.case.settings_file,
            hint="add depth, UniDepth output, or size_m (the object's largest dimension in meters) and a prompt box",
        )
    x0, y0, x1, y1 = spec.prompt.box
    h, w = out.depths.shape[1:]
    sx, sy = w / ctx.case.width, h / ctx.case.height
    patch = out.depths[spec.prompt.frame][int(y0 * sy) : int(y1 * sy) + 1, int(x0 * sx) : int(x1 * sx) + 1].astype(
        float
    )
    z = float(np.median(patch[(patch > 0) & (patch < FAR_CLIP)]))
    extent_px = max(x1 - x0, (y1 - y0) * K_case[0, 0] / K_case[1, 1])
    size_rel = extent_px * z / K_case[0, 0]
    alpha = float(spec.overrides["size_m"]) / size_rel
    return alpha, 0.0, float("nan")


def run(ctx: StageContext) -> None:
    case = ctx.case
    path = find_npz(case)
    out = read_megasam(path)
    n = case.n_frames
    if len(out.cam_c2w) != n:
        raise InputError(
            f"MegaSaM has {len(out.cam_c2w)} frames, the video {n}",
            path=path,
            hint="run MegaSaM on every frame of this video",
        )
    h, w = out.depths.shape[1:]
    K_mega = np.asarray(out.intrinsic, dtype=float)
    sx, sy = case.width / w, case.height / h
    imported = np.array(
        [
            [K_mega[0, 0] * sx, 0.0, (K_mega[0, 2] + 0.5) * sx - 0.5],
            [0.0, K_mega[1, 1] * sy, (K_mega[1, 2] + 0.5) * sy - 0.5],
            [0.0, 0.0, 1.0],
        ]
    )
    K, k_source, warning = resolve_K(case, imported=imported, fov_guess_deg=ctx.config.fov_guess_deg)
    if warning:
        ctx.warn(warning)
    alpha, beta, residual, scale_source = metric_scale(ctx, out, K)
    if scale_source == "size-prior":
        ctx.warn("metric scale from an object size prior: expect a few percent of scale error")
    poses = np.asarray(out.cam_c2w, dtype=float).copy()
    for t in range(n):
        se3.check_rotation(poses[t, :3, :3], tol=1e-3, what=f"MegaSaM camera {t}", path=path)
    poses[:, :3, 3] *= alpha

    def metric_depth(t: int) -> np.ndarray:
        return metric_from_megasam(out.depths[t], alpha, beta, case.width, case.height)

    frames = sorted(set(np.linspace(0, n - 1, min(n, 30)).round().astype(int).tolist()))
    points = fused_points(metric_depth, frames, K, poses, depth_max_m=ctx.config.depth_max_m)
    # planes of fused MegaSaM depth tilt by 1-2.5 deg on the benchmark (focal error, per-frame
    # depth error, scale drift), worse than GeoCalib's ~0.5: they barely move a GeoCalib estimate
    gravity, support, world_from_track, how = locate(ctx, poses, points, metric_depth, K, plane_floor_deg=2.0)
    author_tracked_world(
        ctx,
        poses,
        K,
        world_from_track,
        gravity,
        k_source,
        scale_source=scale_source,
        scale_alpha=alpha,
        scale_beta=beta,
        scale_residual=0.0 if not np.isfinite(residual) else residual,
    )
    ctx.record(
        megasam=str(path.name),
        alpha=alpha,
        beta_m=beta,
        scale_residual_m=residual,
        scale_source=scale_source,
        gravity=gravity.source,
        origin=how,
    )
