"""Simulated outputs of the paper's perception tools, made from a case's ground truth with the
errors those tools show, and written in the tools' own file formats (rose_usd.io.*) in the
case layout's ``perception/`` folder (architecture.md section 3)::

    perception/scene_sgd_cvd_hr.npz        MegaSaM
    perception/unidepth/NNNNNN.npz         UniDepth, one per frame
    perception/geocalib.json               GeoCalib, frame 0
    perception/masks/NNNNN.png             SAM 2, DAVIS paletted, object ids in rose.toml order
    perception/ob_in_cam/NNNNNN.txt        FoundationPose (ob_in_cam/<Name>/ when several objects)
    perception/<Name>.glb                  TRELLIS
    perception/simulated.json              what was simulated (benchmark only; no backend reads it)

The tools' errors:

- MegaSaM: depth and camera translation at an unknown per-video scale and offset, with smooth
  per-frame depth error, scale drift over the video, pose drift, a focal-length error, at
  MegaSaM's working resolution (longer side 512 px);
- UniDepth: metric depth with a per-video scale bias, per-frame jitter, smooth spatial error and
  blurred depth edges, with its own field of view estimate;
- GeoCalib: the first frame's up vector with an error of a fraction of a degree;
- SAM 2: DAVIS paletted masks with boundary errors (growth, shrinkage, wobble);
- FoundationPose: T_cam<-object of the TRELLIS mesh frame per frame, with temporally correlated
  jitter and worse estimates while the object is mostly hidden;
- TRELLIS: the object mesh normalized into [-0.5, 0.5]^3, Y-up, arbitrary yaw, with small shape
  errors, xatlas UVs and a baseColor texture.

Every error is drawn from a seeded generator; the magnitudes are recorded in
``perception/simulated.json`` for the benchmark report (never read by rose's backends).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import trimesh
from scipy.ndimage import gaussian_filter, gaussian_filter1d
from scipy.spatial.transform import Rotation

from rose_usd.case.gt import GroundTruth
from rose_usd.core import se3
from rose_usd.core.color import linear_to_srgb8
from rose_usd.io import foundationpose, geocalib, megasam, sam2, trellis, unidepth
from rose_usd.io.images import read_depth_m, read_mask, read_rgb

PERCEPTION_DIR = "perception"
PERCEPTION_VERSION = 3
"""Bumped whenever a change here changes the files written (cached mode cases are then rebuilt)."""


@dataclass(frozen=True)
class PerceptionErrors:
    """Magnitudes of the simulated tools' errors."""

    megasam_drift: float = 0.01
    """Camera translation drift over the video, as a fraction of the path length."""
    megasam_depth_noise: float = 0.015
    """Smooth relative depth error per frame (one sigma)."""
    megasam_scale_drift: float = 0.02
    """Relative change of the depth scale from the first to the last frame."""
    megasam_focal_error: float = 0.015
    unidepth_scale_sigma: float = 0.01
    """Per-video scale bias of UniDepth (one sigma). The megasam import's scale error follows it
    one to one (measured at 0.03 on the default suite: alpha error = bias within 1 %)."""
    unidepth_noise: float = 0.02
    geocalib_error_deg: float = 0.5
    sam2_boundary_px: float = 1.5
    """Boundary error at 640 px image width (scaled with the width) [px]."""
    foundationpose_trans_sigma_m: float = 0.002
    foundationpose_rot_sigma_deg: float = 0.6
    trellis_shape_noise: float = 0.004
    """Shape error of the generated mesh, relative to its size (one sigma, smooth)."""


def _smooth_noise(rng: np.random.Generator, shape: tuple[int, int], cells: float) -> np.ndarray:
    field = gaussian_filter(rng.normal(size=shape), sigma=max(shape) / cells)
    return field / max(float(field.std()), 1e-9)


def _working_size(width: int, height: int, longer: int = 512) -> tuple[int, int]:
    scale = min(1.0, longer / max(width, height))
    return int(round(width * scale / 8) * 8), int(round(height * scale / 8) * 8)


def simulate_megasam(case_dir: Path, gt: GroundTruth, rng: np.random.Generator, errors: PerceptionErrors) -> dict:
    n, W, H = gt.n_frames, gt.width, gt.height
    w, h = _working_size(W, H)
    sx, sy = w / W, h / H
    scale = float(np.exp(rng.uniform(np.log(0.3), np.log(3.0))))  # the unknown per-video scale
    offset = float(rng.uniform(-0.03, 0.03) * scale)
    scale_t = scale * (1.0 + errors.megasam_scale_drift * (np.arange(n) / max(n - 1, 1) - 0.5) * rng.choice([-1, 1]))
    cams = gt.camera_poses()
    rel = np.einsum("ij,njk->nik", se3.invert(cams[0]), cams)  # MegaSaM's world: the first camera
    path_len = float(np.linalg.norm(np.diff(rel[:, :3, 3], axis=0), axis=1).sum())
    walk = np.cumsum(rng.normal(size=(n, 3)), axis=0)
    walk = walk / max(float(np.abs(walk).max()), 1e-9) * errors.megasam_drift * max(path_len, 0.05)
    rot_walk = np.cumsum(rng.normal(scale=np.radians(0.02), size=(n, 3)), axis=0)
    c2w = rel.copy()
    for t in range(n):
        c2w[t, :3, :3] = Rotation.from_rotvec(rot_walk[t]).as_matrix() @ rel[t, :3, :3]
        c2w[t, :3, 3] = scale * (rel[t, :3, 3] + walk[t])
    K = gt.K.copy()
    K[0] *= sx
    K[1] *= sy
    K[:2, :2] *= 1.0 + rng.normal(scale=errors.megasam_focal_error)
    images = np.empty((n, h, w, 3), np.uint8)
    depths = np.empty((n, h, w), np.float32)
    for t in range(n):
        images[t] = cv2.resize(read_rgb(case_dir / "rgb" / f"{t:06d}.png"), (w, h), interpolation=cv2.INTER_AREA)
        clean = cv2.resize(read_depth_m(gt.depth_dir / f"{t:06d}.png"), (w, h), interpolation=cv2.INTER_NEAREST)
        rel_err = 1.0 + errors.megasam_depth_noise * _smooth_noise(rng, (h, w), 6.0)
        depths[t] = np.where(clean > 0, scale_t[t] * clean * rel_err + offset, 1e2)  # no depth: MegaSaM's far clip
    path = case_dir / PERCEPTION_DIR / "scene_sgd_cvd_hr.npz"
    megasam.write_megasam(path, megasam.MegaSamOutput(images, depths, K, c2w))
    return {"scale": scale, "offset_m": offset, "working_size": [w, h], "drift_m": float(np.linalg.norm(walk[-1]))}


def simulate_unidepth(case_dir: Path, gt: GroundTruth, rng: np.random.Generator, errors: PerceptionErrors) -> dict:
    bias = float(1.0 + rng.normal(scale=errors.unidepth_scale_sigma))
    K = gt.K.copy()
    K[:2, :2] *= 1.0 + rng.normal(scale=0.02)
    fov = float(np.degrees(2 * np.arctan(gt.width / (2 * K[0, 0]))))
    for t in range(gt.n_frames):
        clean = read_depth_m(gt.depth_dir / f"{t:06d}.png")
        jitter = 1.0 + rng.normal(scale=0.01)
        rel_err = 1.0 + errors.unidepth_noise * _smooth_noise(rng, clean.shape, 8.0)
        depth = np.where(clean > 0, clean, np.max(clean)) * bias * jitter * rel_err
        depth = cv2.GaussianBlur(depth.astype(np.float32), (0, 0), sigmaX=1.5)  # networks blur depth edges
        conf = np.clip(1.0 - 5.0 * np.abs(cv2.Laplacian(depth, cv2.CV_32F)), 0.05, 1.0)
        unidepth.write_unidepth(
            case_dir / PERCEPTION_DIR / "unidepth" / f"{t:06d}.npz", unidepth.UniDepthFrame(depth, fov, K, conf)
        )
    return {"scale_bias": bias, "fov_deg": fov}


def simulate_geocalib(case_dir: Path, gt: GroundTruth, rng: np.random.Generator, errors: PerceptionErrors) -> dict:
    cam0 = gt.camera_poses()[0]
    up_cam = cam0[:3, :3].T @ (-gt.gravity / np.linalg.norm(gt.gravity))
    axis = rng.normal(size=3)
    axis -= axis.dot(up_cam) * up_cam
    err_deg = abs(rng.normal(scale=errors.geocalib_error_deg))
    noisy = se3.rotation_about(axis, np.radians(err_deg)) @ up_cam
    roll, pitch = geocalib.rp_from_up(noisy)
    vfov = float(2 * np.arctan(gt.height / (2 * gt.K[1, 1])))
    sigma = np.radians(errors.geocalib_error_deg)
    geocalib.write_geocalib(
        case_dir / PERCEPTION_DIR / "geocalib.json", geocalib.GeoCalib(noisy, roll, pitch, 0, None, vfov, sigma, sigma)
    )
    return {"error_deg": err_deg}


def _perturb_mask(mask: np.ndarray, rng: np.random.Generator, boundary_px: float) -> np.ndarray:
    if not mask.any():
        return mask
    dist_in = cv2.distanceTransform(mask.astype(np.uint8), cv2.DIST_L2, 3)
    dist_out = cv2.distanceTransform((~mask).astype(np.uint8), cv2.DIST_L2, 3)
    signed = np.where(mask, dist_in, -dist_out)
    wobble = boundary_px * _smooth_noise(rng, mask.shape, 24.0) + rng.normal(scale=0.5 * boundary_px)
    return signed > wobble


def simulate_sam2(
    case_dir: Path, gt: GroundTruth, names: list[str], rng: np.random.Generator, errors: PerceptionErrors
) -> dict:
    boundary_px = errors.sam2_boundary_px * gt.width / 640.0  # the error is ~1.5 px at 640 px wide
    for t in range(gt.n_frames):
        ids = np.zeros((gt.height, gt.width), np.uint8)
        for obj_id, name in enumerate(names, start=1):
            mask = _perturb_mask(read_mask(gt.mask_dir(name) / f"{t:06d}.png"), rng, boundary_px)
            ids[mask & (ids == 0)] = obj_id
        sam2.write_id_mask(case_dir / PERCEPTION_DIR / "masks" / f"{t:05d}.png", ids)
    return {"object_ids": {name: i for i, name in enumerate(names, start=1)}}


def trellis_frame(mesh: trimesh.Trimesh, yaw_rad: float) -> tuple[np.ndarray, float]:
    """object_from_trellis (4, 4) of a frame centered on the mesh's bounding box, yawed by
    ``yaw_rad`` about the object's up and turned Y-up (metric), and the mesh's longest extent in
    that frame [m]."""
    center = 0.5 * (mesh.bounds[0] + mesh.bounds[1])
    rot_zup = se3.rotation_about([0, 0, 1], yaw_rad)
    local = (mesh.vertices - center) @ rot_zup  # in the yawed, centered Z-up frame
    size = float(np.max(local.max(axis=0) - local.min(axis=0)))
    # object_from_trellis: p_obj = center + rot_zup @ Y_UP_FROM_Z_UP^T @ p_trellis
    rot = rot_zup @ trellis.Y_UP_FROM_Z_UP.T
    return se3.make_pose(rot, center), size


def simulate_trellis(
    case_dir: Path, gt: GroundTruth, name: str, rng: np.random.Generator, errors: PerceptionErrors
) -> tuple[np.ndarray, dict]:
    """Write the TRELLIS GLB of one object; returns object_from_trellis (metric) for FoundationPose."""
    import xatlas

    truth = gt.object_mesh(name)
    mesh = trimesh.Trimesh(truth.vertices, truth.faces, process=True)
    while len(mesh.faces) < 4000:
        mesh = mesh.subdivide()
    yaw = float(rng.uniform(-np.pi, np.pi))
    object_from_trellis, size = trellis_frame(mesh, yaw)
    verts = se3.transform_points(se3.invert(object_from_trellis), mesh.vertices)  # metric, TRELLIS axes
    # smooth shape error along the normals
    normals = se3.transform_points(se3.make_pose(object_from_trellis[:3, :3].T, np.zeros(3)), mesh.vertex_normals)
    freq = rng.normal(size=(3, 3)) * 2 * np.pi / size
    phase = rng.uniform(0, 2 * np.pi, size=3)
    bumps = np.sin(verts @ freq.T + phase).sum(axis=1) / np.sqrt(1.5)
    verts = verts + normals * (errors.trellis_shape_noise * size * bumps)[:, None]
    # TRELLIS normalizes the generated mesh: bounding box centered, longest side 1
    center = 0.5 * (verts.min(axis=0) + verts.max(axis=0))
    scale = float(np.max(verts.max(axis=0) - verts.min(axis=0)))  # meters per GLB unit
    unit = (verts - center) / scale
    object_from_trellis = object_from_trellis @ se3.make_pose(np.eye(3), center)
    vmapping, indices, uvs = xatlas.parametrize(unit.astype(np.float32), mesh.faces.astype(np.uint32))
    color = np.asarray(
        linear_to_srgb8(np.asarray(truth.color if truth.color is not None else (0.5, 0.5, 0.5))), dtype=np.uint8
    )
    texture = np.tile(color, (64, 64, 1))
    path = case_dir / PERCEPTION_DIR / f"{name}.glb"
    trellis.write_trellis_glb(path, unit[vmapping], indices, uvs, texture)
    return object_from_trellis, {"scale_m_per_unit": scale, "yaw_rad": yaw}


def simulate_foundationpose(
    case_dir: Path,
    gt: GroundTruth,
    name: str,
    object_from_trellis: np.ndarray,
    rng: np.random.Generator,
    errors: PerceptionErrors,
    *,
    one_object: bool,
) -> dict:
    n = gt.n_frames
    cams = gt.camera_poses()
    objs = gt.object_poses(name)
    visible = np.array([read_mask(gt.mask_dir(name) / f"{t:06d}.png").sum() for t in range(n)], dtype=float)
    hidden = 1.0 - np.clip(visible / max(visible.max(), 1.0) / 0.5, 0.0, 1.0)  # 1 when mostly hidden
    trans = gaussian_filter1d(rng.normal(size=(n, 3)), 2.0, axis=0)
    trans /= max(float(trans.std()), 1e-9)
    rot = gaussian_filter1d(rng.normal(size=(n, 3)), 2.0, axis=0)
    rot /= max(float(rot.std()), 1e-9)
    gain = 1.0 + 4.0 * hidden
    # FoundationPose's own layout for one object; one folder per object when there are several
    folder = case_dir / PERCEPTION_DIR / "ob_in_cam" if one_object else case_dir / PERCEPTION_DIR / "ob_in_cam" / name
    for t in range(n):
        cam_from_trellis = se3.invert(cams[t]) @ objs[t] @ object_from_trellis
        # the rotation error turns the object about its own center (the TRELLIS frame's origin),
        # the translation error moves it in the camera frame: a pose estimator given depth and a
        # mask errs in the object's orientation and position, not by turning it about the camera
        # (which would move it sideways by the angle times its distance)
        noisy = cam_from_trellis @ se3.make_pose(
            Rotation.from_rotvec(np.radians(errors.foundationpose_rot_sigma_deg) * gain[t] * rot[t]).as_matrix(),
            np.zeros(3),
        )
        noisy[:3, 3] += errors.foundationpose_trans_sigma_m * gain[t] * trans[t]
        foundationpose.write_pose(folder / f"{t:06d}.txt", noisy)
    return {"hidden_frames": int((hidden > 0.5).sum())}


def write_mono_imported(case_dir: Path, seed: int, errors: PerceptionErrors = PerceptionErrors()) -> dict:
    """Write every simulated tool output for a case (which already holds rgb/ and gt/)."""
    gt = GroundTruth(case_dir / "gt")
    rng = np.random.default_rng(seed + 7919)
    names = [o.name for o in gt.objects]
    record = {
        "megasam": simulate_megasam(case_dir, gt, rng, errors),
        "unidepth": simulate_unidepth(case_dir, gt, rng, errors),
        "geocalib": simulate_geocalib(case_dir, gt, rng, errors),
        "sam2": simulate_sam2(case_dir, gt, names, rng, errors),
        "objects": {},
    }
    for name in names:
        object_from_trellis, info = simulate_trellis(case_dir, gt, name, rng, errors)
        info.update(
            simulate_foundationpose(case_dir, gt, name, object_from_trellis, rng, errors, one_object=len(names) == 1)
        )
        record["objects"][name] = info
    record["errors"] = errors.__dict__
    (case_dir / PERCEPTION_DIR / "simulated.json").write_text(json.dumps(record, indent=2, default=float) + "\n")
    return record
