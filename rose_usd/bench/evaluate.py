"""Score one reconstruction against its case's ground truth (architecture.md section 5).

Frames: the reconstruction's world is registered to the ground-truth world by the camera poses
(rose_usd.core.metrics.align_poses; identity for a perfect capture), so a world that is right up
to its arbitrary yaw and origin is not penalized, while every other error is. Each reconstructed
object frame is matched to the ground-truth object frame by registering its mesh to the true mesh
at frame 0 (ICP), so trajectories of differently-anchored object frames compare fairly.
"""

from __future__ import annotations

import itertools
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
from pxr import Usd, UsdGeom

from rose_usd.case.config import load_case_config
from rose_usd.case.gt import GroundTruth
from rose_usd.core import metrics, se3
from rose_usd.core.pinhole import backproject
from rose_usd.io.images import read_depth_m, read_mask
from rose_usd.render.lighting import Lighting
from rose_usd.render.scene import RenderItem, RenderScene
from rose_usd.usd import paths, tokens
from rose_usd.usd.camera import read_camera
from rose_usd.usd.geom import MeshData, read_mesh
from rose_usd.usd.stage import open_stage


@dataclass
class ObjectScore:
    name: str
    chamfer_m: float
    """Symmetric Chamfer of the object mesh against the true mesh, at frame 0 in the true world registered by
    the cameras (so its placement counts)."""
    ape_translation_m: float
    ape_rotation_deg: float
    rpe_translation_m: float
    rpe_rotation_deg: float
    ape_translation_per_frame_m: list[float] = field(default_factory=list)
    shape_chamfer_m: float | None = None
    """The same Chamfer after the rigid transform that best registers the mesh onto the true one
    (ICP, no scale): the mesh's shape and size alone, its frame-0 placement left to the APE."""
    mass_kg: float | None = None
    true_mass_kg: float | None = None
    size_error: float | None = None
    """Signed relative size error at frame 0: the RMS distance of the convex hull's surface from its
    centroid, reconstructed over true, minus 1 (the object's scale error)."""
    mass_range_kg: list[float] | None = None
    """The mass the category's density range gives the reconstructed volume (or shell) [kg]."""
    rest_drift_m: float | None = None
    """Largest displacement of its bounding box's corners in Newton from the frame-0 stage without
    the trajectory, over 1 s or until every object settled or crept steadily (``sim.rest.simulate_rest``;
    None: no object stage, or no scene to rest on)."""
    mask_iou: float | None = None
    """Mean mask IoU over the frames where the object is more than half visible (None: no segment stage)."""


@dataclass
class CaseScore:
    camera_ape_translation_m: float
    camera_ape_rotation_deg: float
    camera_rpe_translation_m: float
    camera_rpe_rotation_deg: float
    gravity_error_deg: float
    scale_error: float
    """|s - 1| of the Sim(3) scale registering the reconstructed camera centers to the true ones
    (NaN when the true centers spread less than 1 cm: a static camera has no path to scale). Ill
    conditioned where the path spreads little more than its error (``height_scale_error``)."""
    height_scale_error: float
    """|s - 1| of the camera's height above the support, reconstructed over true (``height_scale``):
    the world's metric scale where the camera stands still or its path is short."""
    scene_chamfer_m: float
    scene_chamfer_visible_m: float
    """Mean over sampled frames of the Chamfer between what the true and reconstructed scenes show."""
    scene_ghost_cm2: float
    """Area of reconstructed scene surface lying more than 1.5 cm inside an object or the hand at
    some frame, and more than 1.5 cm from the true static scene (a ghost of a moving part fused
    into the scene) [cm^2]."""
    objects: list[ObjectScore]
    ssim_mean: float | None
    gate_passed: bool | None
    interactor_iou: float | None = None
    """Mean interactor mask IoU over the frames where the true interactor covers at least 0.5 % of the image."""
    gravity_uncertainty_deg: float | None = None
    """The world layer's own gravity sigma (None: no capture stage), to set beside the error."""
    scale_uncertainty: float | None = None
    """The world layer's relative scale sigma (0 for metric depth; None: no capture stage)."""

    def to_json(self) -> dict:
        return asdict(self)


def prim_poses(stage: Usd.Stage, path, n: int) -> np.ndarray:
    """The prim's world poses (n, 4, 4) at frames 0..n-1 (an object's trajectory)."""
    xf = UsdGeom.Xformable(stage.GetPrimAtPath(path))
    return np.array([np.array(xf.ComputeLocalToWorldTransform(Usd.TimeCode(t))).T for t in range(n)])


def _meshes(stage: Usd.Stage, root, time: Usd.TimeCode = Usd.TimeCode.Default()) -> tuple[np.ndarray, np.ndarray]:
    """All renderable meshes under ``root`` merged, in world coordinates at ``time``."""
    purposes = (UsdGeom.Tokens.default_, UsdGeom.Tokens.render)
    verts, faces, offset = [], [], 0
    prim = stage.GetPrimAtPath(root)
    if not prim:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    for p in Usd.PrimRange(prim):
        if p.IsA(UsdGeom.Mesh) and UsdGeom.Imageable(p).ComputePurpose() in purposes:
            m = read_mesh(p, time, world=True)
            verts.append(m.vertices)
            faces.append(m.faces + offset)
            offset += len(m.vertices)
    if not verts:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    return np.concatenate(verts), np.concatenate(faces)


def _rest_drifts(out_dir, scores: list[ObjectScore]) -> None:
    """Each object's rest drift in Newton (``ObjectScore.rest_drift_m``) on a stage of the world, scene and
    object layers only (a trajectory layer's time samples are not what rests)."""
    from rose_usd.sim.rest import simulate_rest
    from rose_usd.usd.stage import layer_file

    if not scores or not all(layer_file(Path(out_dir), name).is_file() for name in ("object", "scene")):
        return
    stage = open_stage(Path(out_dir) / "rose.usda")
    for name in ("trajectory", "gate"):
        layer = layer_file(Path(out_dir), name)
        if layer.is_file():
            stage.MuteLayer(str(layer.resolve()))
    objects = {
        sc.name: str(paths.object_path(sc.name)) for sc in scores if stage.GetPrimAtPath(paths.object_path(sc.name))
    }
    for result in simulate_rest(stage, objects):
        next(sc for sc in scores if sc.name == result.name).rest_drift_m = result.max_displacement_m


def _mass_range(prim) -> list[float] | None:
    """mass x (density range / density): mass is density x volume, so this is the range's mass."""
    mass, rng, rho = (prim.GetAttribute(a) for a in ("physics:mass", tokens.PRIOR_DENSITY_RANGE, tokens.PRIOR_DENSITY))
    if not (mass and rng and rho and mass.HasAuthoredValue() and rng.HasAuthoredValue() and rho.HasAuthoredValue()):
        return None
    k = float(mass.Get()) / float(rho.Get())
    return [k * float(rng.Get()[0]), k * float(rng.Get()[1])]


def _backproject(depth: np.ndarray, mask: np.ndarray, K: np.ndarray, world_from_cv: np.ndarray) -> np.ndarray:
    v, u = np.nonzero(mask)
    z = depth[v, u]
    return se3.transform_points(world_from_cv, backproject(u, v, z, K))


def _static_pixels(gt: GroundTruth, t: int, stride_px: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """True depth of frame t and the pixels showing the static scene (objects, interactor and
    pixels without depth removed), subsampled every ``stride_px``."""
    depth = read_depth_m(gt.depth_dir / f"{t:06d}.png")
    mask = depth > 0
    for obj in gt.objects:
        mask &= ~read_mask(gt.mask_dir(obj.name) / f"{t:06d}.png")
    mask &= ~read_mask(gt.mask_dir("interactor") / f"{t:06d}.png")
    sub = np.zeros_like(mask)
    sub[::stride_px, ::stride_px] = True
    return depth, mask & sub


def _icp_correction(
    rec_points: np.ndarray, true_surface: metrics.SurfaceDistance, true_points: np.ndarray
) -> np.ndarray:
    """Rigid world correction C (4, 4) bringing the reconstructed object points onto the true
    surface (point-to-point ICP against dense true samples; identity when they already agree)."""
    from scipy.spatial import cKDTree

    if np.mean(true_surface(rec_points)) < 1e-6:
        return np.eye(4)
    tree = cKDTree(true_points)
    correction = np.eye(4)
    src = rec_points.copy()
    for _ in range(30):
        dist, idx = tree.query(src)
        keep = dist < max(0.02, 3 * np.median(dist))
        # rigid: a similarity's translation (my - s R mx) would shift a larger-than-true object
        # each iteration, and on a solid of revolution that drift spins it freely
        step, _ = metrics.umeyama_sim3(src[keep], true_points[idx[keep]], with_scale=False)
        src = se3.transform_points(step, src)
        correction = step @ correction
        if np.linalg.norm(step[:3, 3]) < 1e-6 and se3.rotation_angle_deg(step[:3, :3]) < 1e-4:
            break
    return correction


@dataclass
class ObjectRegistration:
    """An object's reconstructed mesh at frame 0 in the true world (the worlds registered by the
    cameras) with 50k surface samples, its true mesh's, and the rigid ``correction`` (4, 4) that
    brings the former onto the latter (``_icp_correction`` on 5k of the samples)."""

    rec_world0: np.ndarray
    rec_faces: np.ndarray
    rec_samples: np.ndarray
    true_world0: np.ndarray
    true_faces: np.ndarray
    true_surface: metrics.SurfaceDistance
    true_samples: np.ndarray
    correction: np.ndarray

    def size_error(self) -> float:
        """The mesh's size against the true one's: the ratio of their convex hulls' surface rms
        radii (exact, ``metrics.hull_rms_radius``) minus 1. The hulls': a true mug's inner wall
        pulled its surface's radius 8-9 % under its hull's, so a solid proxy of its exact outer
        size scored +7 %."""
        return metrics.hull_rms_radius(self.rec_world0) / metrics.hull_rms_radius(self.true_world0) - 1.0

    def placed_chamfer(self) -> float:
        """The object Chamfer [m] of the mesh where it was placed at frame 0."""
        return self._chamfer(self.rec_world0, self.rec_samples)

    def shape_chamfer(self) -> float:
        """The shape Chamfer [m]: the Chamfer after ``correction`` (the mesh's shape and size alone)."""
        return self._chamfer(
            se3.transform_points(self.correction, self.rec_world0),
            se3.transform_points(self.correction, self.rec_samples),
        )

    def _chamfer(self, rec_vertices: np.ndarray, rec_samples: np.ndarray) -> float:
        chamfer, _, _ = metrics.chamfer_point_surface(
            rec_samples, metrics.SurfaceDistance(rec_vertices, self.rec_faces), self.true_samples, self.true_surface
        )
        return chamfer


def register_mesh(
    rec_world0: np.ndarray, rec_faces: np.ndarray, gt: GroundTruth, name: str, rng: np.random.Generator
) -> ObjectRegistration:
    """The registration of a reconstructed mesh of object ``name`` at frame 0, already in the true
    world, onto the true one."""
    true_mesh = gt.object_mesh(name)
    true_world0 = se3.transform_points(gt.object_poses(name)[0], true_mesh.vertices)
    true_surface = metrics.SurfaceDistance(true_world0, true_mesh.faces)
    rec_samples = metrics.sample_surface(rec_world0, rec_faces, 50_000, rng)
    true_samples = metrics.sample_surface(true_world0, true_mesh.faces, 50_000, rng)
    correction = _icp_correction(rec_samples[:5000], true_surface, true_samples)
    return ObjectRegistration(
        rec_world0, rec_faces, rec_samples, true_world0, true_mesh.faces, true_surface, true_samples, correction
    )


def register_object(
    stage: Usd.Stage, gt: GroundTruth, align: np.ndarray, name: str, rng: np.random.Generator
) -> ObjectRegistration:
    """The registration that the object's Chamfers and its APE's object frame are computed from
    (``align``: the reconstructed world's pose in the true one)."""
    rec_world0, rec_faces = _meshes(stage, paths.object_visual(name), Usd.TimeCode(0))
    return register_mesh(se3.transform_points(align, rec_world0), rec_faces, gt, name, rng)


def _mask_ious(
    true_dir: Path, rec_dir: Path, n: int, *, min_fraction: float | None = None, min_pixels: int = 0
) -> float | None:
    """Mean IoU of reconstructed vs true masks over frames where the true mask is big enough:
    ``min_fraction`` of its 95th-percentile visible area ("more than half visible" for 0.5; the
    true masks hold visible pixels only, so the unoccluded area is estimated this way), or at
    least ``min_pixels``."""
    if not rec_dir.is_dir():
        return None
    true = [read_mask(true_dir / f"{t:06d}.png") for t in range(n)]
    area = np.array([m.sum() for m in true], dtype=float)
    floor = max(min_pixels, (min_fraction or 0.0) * float(np.percentile(area, 95)))
    ious = []
    for t in np.flatnonzero(area > max(floor, 0)):
        rec = read_mask(rec_dir / f"{t:06d}.png")
        ious.append(float((rec & true[t]).sum()) / float((rec | true[t]).sum()))
    return float(np.mean(ious)) if ious else None


def _camera_scores(gt: GroundTruth, true_cams: np.ndarray, track):
    """(rec world -> true world, camera APE, RPE, gravity error [deg], path scale error) of the
    recovered camera ``track`` against the true cameras ``true_cams`` (gt.camera_poses())."""
    align = metrics.align_poses(track.world_from_cv, true_cams)
    cams = np.einsum("ij,njk->nik", align, track.world_from_cv)
    up = align[:3, :3] @ np.array([0.0, 0.0, 1.0])
    true_up = -gt.gravity / np.linalg.norm(gt.gravity)
    gravity_err = float(np.degrees(np.arccos(np.clip(up @ true_up, -1.0, 1.0))))
    _, scale = metrics.umeyama_sim3(track.world_from_cv[:, :3, 3], true_cams[:, :3, 3])
    centers = true_cams[:, :3, 3]
    if np.sqrt(np.mean(np.sum((centers - centers.mean(axis=0)) ** 2, axis=1))) < 0.01:
        scale = float("nan")  # a camera that hardly moves has no path to scale (a tripod)
    return align, metrics.ape(cams, true_cams), metrics.rpe(cams, true_cams), gravity_err, scale


def height_scale(gt: GroundTruth, case_dir: Path, world_from_cv: np.ndarray) -> float:
    """The reconstructed world's metric scale: the camera's height above the support, ours over
    the truth's, the median over the frames the true camera is 5 cm or more above it (NaN if
    none). Our world's z = 0 is the support plane under the first prompted object (the world
    contract); the truth's is the lowest point of that object's mesh at its prompt frame (of every
    object at frame 0 without a prompt: the view-centred table). A support plane placed off the
    table by d moves it by d over the camera's height (1 cm at 0.5 m: 2 %).

    The Sim(3) that registers the camera paths measures the scale only where the path spreads well
    beyond its error: a hand-held path of the default suite spreads 25-52 mm RMS against 10-25 mm
    of SfM position error, and its scale read 24-36 % off where the camera's height and the
    object's fitted size were 2-5 % off."""
    from rose_usd import registry

    objects = load_case_config(Path(case_dir), registry.STAGE_NAMES).objects
    first = next((o for o in objects if o.prompt is not None), None)
    frame = first.prompt.frame if first is not None else 0
    names = [first.name] if first is not None else [o.name for o in gt.objects]
    up = -gt.gravity / np.linalg.norm(gt.gravity)
    posed = [se3.transform_points(gt.object_poses(name)[frame], gt.object_mesh(name).vertices) for name in names]
    bottom = min(float(np.min(v @ up)) for v in posed)
    true_h = gt.camera_poses()[:, :3, 3] @ up - bottom
    ours_h = np.asarray(world_from_cv)[:, 2, 3]
    keep = true_h >= 0.05
    return float(np.median(ours_h[keep] / true_h[keep])) if keep.any() else float("nan")


def evaluate(
    case_dir, out_dir, *, frame_stride: int = 10, seed: int = 0, scene: bool = True, rest: bool = True
) -> CaseScore:
    """Metrics of the stage in ``out_dir`` against the ground truth of ``case_dir``; without
    ``scene`` the scene's scores are NaN, without ``rest`` the objects' rest drifts are None (the
    two slow parts)."""
    rng = np.random.default_rng(seed)
    gt = GroundTruth(case_dir / "gt")
    stage = open_stage(out_dir / "rose.usda")
    n = gt.n_frames
    true_cams = gt.camera_poses()
    if stage.GetPrimAtPath(paths.CAMERA):
        track = read_camera(stage, paths.CAMERA, n)
        align, cam_ape, cam_rpe, gravity_err, scale = _camera_scores(gt, true_cams, track)
        height = height_scale(gt, case_dir, track.world_from_cv)
    else:  # no capture stage (the flow masks need none): nothing else needs the world either
        align, gravity_err, scale, height = np.eye(4), float("nan"), float("nan"), float("nan")
        cam_ape = cam_rpe = metrics.PoseErrors(np.full(1, np.nan), np.full(1, np.nan))

    # ---------------------------------------------------------------- scene
    rv, rf = _meshes(stage, paths.SCENE_VISUAL)  # empty when the scene stage has not run
    if scene and len(rf):
        true_parts = [gt.part_mesh(p) for p in gt.parts]
        tv = np.concatenate([m.vertices for m in true_parts])
        tf = np.concatenate(
            [m.faces + off for m, off in zip(true_parts, np.cumsum([0] + [len(m.vertices) for m in true_parts[:-1]]))]
        )
        true_surface = metrics.SurfaceDistance(tv, tf)
        frames = list(range(0, n, max(1, frame_stride)))
        pixels = {t: _static_pixels(gt, t) for t in frames}
        seen_all = np.concatenate(
            [_backproject(depth, mask, gt.K, true_cams[t]) for t, (depth, mask) in pixels.items()]
        )
        lo, hi = seen_all.min(axis=0) - 0.05, seen_all.max(axis=0) + 0.05
        rv = se3.transform_points(align, rv)
        rec_surface = metrics.SurfaceDistance(rv, rf)
        rec_pts = metrics.sample_surface(rv, rf, 400_000, rng)
        rec_pts = rec_pts[np.all((rec_pts >= lo) & (rec_pts <= hi), axis=1)]
        keep = rng.choice(len(seen_all), size=min(len(seen_all), 200_000), replace=False)
        scene_chamfer, _, _ = metrics.chamfer_point_surface(rec_pts, rec_surface, seen_all[keep], true_surface)
        # per frame: what the reconstruction shows through the same pixels as the true static scene
        rec_scene = RenderScene([RenderItem("scene", MeshData(rv, rf, color=(0.5, 0.5, 0.5)))], Lighting.unlit())
        per_frame = []
        for t, (true_depth, mask) in pixels.items():
            rec_depth, _ = rec_scene.depth_and_labels(true_cams[t], gt.K, gt.width, gt.height)
            # one random subset of the static pixels for both point sets, so the sampling itself
            # adds no distance; pixels the reconstruction leaves empty still count (as misses)
            v, u = np.nonzero(mask)
            keep = rng.choice(len(v), size=min(len(v), 40_000), replace=False)
            picked = np.zeros_like(mask)
            picked[v[keep], u[keep]] = True
            rec_seen = _backproject(rec_depth, picked & (rec_depth > 0), gt.K, true_cams[t])
            per_frame.append(metrics.chamfer_points(rec_seen, _backproject(true_depth, picked, gt.K, true_cams[t])))
        scene_visible = float(np.nanmean(per_frame))
        # ghosts: reconstructed surface more than 1.5 cm inside where an object or the hand was
        # at some frame and more than 1.5 cm from the true static scene (the support under an
        # object, wrapped with an offset, and a simulated hand dipping into the table stay out)
        area = float(
            np.sum(0.5 * np.linalg.norm(np.cross(rv[rf[:, 1]] - rv[rf[:, 0]], rv[rf[:, 2]] - rv[rf[:, 0]]), axis=1))
        )
        movers = [(gt.object_mesh(o.name), gt.object_poses(o.name)) for o in gt.objects]
        if gt.interactor is not None:
            movers.append((gt.mesh(gt.interactor.mesh, gt.interactor.appearance), gt.interactor_poses()))
        ghost = np.zeros(len(rec_pts), bool)
        for mesh, poses in movers:
            inside = metrics.SignedDistance(mesh.vertices, mesh.faces)
            lo, hi = mesh.vertices.min(axis=0), mesh.vertices.max(axis=0)
            for t in range(0, n, max(1, n // 30)):
                local = se3.transform_points(se3.invert(poses[t]), rec_pts)
                near = np.flatnonzero(np.all((local > lo) & (local < hi), axis=1) & ~ghost)  # inside only there
                ghost[near] = inside(local[near]) < -0.015
        ghost[ghost] = true_surface(rec_pts[ghost]) > 0.015
        scene_ghost_cm2 = 1e4 * area * float(ghost.sum()) / 400_000
    else:
        scene_chamfer = scene_visible = scene_ghost_cm2 = float("nan")

    # ---------------------------------------------------------------- objects
    scores = []
    for obj in gt.objects:
        path = paths.object_path(obj.name)
        prim = stage.GetPrimAtPath(path)
        if not prim:  # the object stage has not run
            scores.append(ObjectScore(obj.name, *(float("nan"),) * 5))
            continue
        true_poses = gt.object_poses(obj.name)
        reg = register_object(stage, gt, align, obj.name, rng)
        rec_poses = np.einsum("ij,njk->nik", align, prim_poses(stage, path, n))
        # object-frame correspondence: X maps true object coordinates into reconstructed ones
        x = se3.invert(rec_poses[0]) @ se3.invert(reg.correction) @ true_poses[0]
        est = np.einsum("nij,jk->nik", rec_poses, x)
        a, r = metrics.ape(est, true_poses), metrics.rpe(est, true_poses)
        mass_attr = prim.GetAttribute("physics:mass")
        true_mass = next((o.get("mass_kg") for o in gt.data["objects"] if o["name"] == obj.name), None)
        scores.append(
            ObjectScore(
                name=obj.name,
                chamfer_m=reg.placed_chamfer(),
                ape_translation_m=a.translation.rmse,
                ape_rotation_deg=a.rotation.rmse,
                rpe_translation_m=r.translation.rmse,
                rpe_rotation_deg=r.rotation.rmse,
                ape_translation_per_frame_m=[float(v) for v in a.translation_m],
                shape_chamfer_m=reg.shape_chamfer(),
                mass_kg=float(mass_attr.Get()) if mass_attr and mass_attr.HasAuthoredValue() else None,
                true_mass_kg=true_mass,
                size_error=reg.size_error(),
                mass_range_kg=_mass_range(prim),
            )
        )
    # without prompts nothing tells which found object is which name of rose.toml: unprompted
    # masks are scored under the best one-to-one matching of names
    names = [sc.name for sc in scores]
    from rose_usd import registry

    unprompted = all(o.prompt is None for o in load_case_config(Path(case_dir), registry.STAGE_NAMES).objects)
    pair: dict[tuple[str, str], float | None] = {}  # each (true, found) pair's masks read once

    def iou(a: str, b: str) -> float | None:
        if (a, b) not in pair:
            pair[(a, b)] = _mask_ious(gt.mask_dir(a), Path(out_dir) / "masks" / b, n, min_fraction=0.5)
        return pair[(a, b)]

    best = None
    for perm in itertools.permutations(names) if unprompted and len(names) > 1 else [tuple(names)]:
        ious = [iou(a, b) for a, b in zip(names, perm)]
        total = sum(v or 0.0 for v in ious)
        if best is None or total > best[0]:
            best = (total, ious)
    for sc, iou in zip(scores, best[1] if best else []):
        sc.mask_iou = iou

    if rest:
        _rest_drifts(out_dir, scores)

    gate = stage.GetPrimAtPath(paths.GATE)
    ssim = float(gate.GetAttribute(tokens.GATE_SSIM_MEAN).Get()) if gate else None
    passed = bool(gate.GetAttribute(tokens.GATE_PASSED).Get()) if gate else None
    return CaseScore(
        camera_ape_translation_m=cam_ape.translation.rmse,
        camera_ape_rotation_deg=cam_ape.rotation.rmse,
        camera_rpe_translation_m=cam_rpe.translation.rmse,
        camera_rpe_rotation_deg=cam_rpe.rotation.rmse,
        gravity_error_deg=gravity_err,
        scale_error=abs(scale - 1.0),
        height_scale_error=abs(height - 1.0),
        scene_chamfer_m=scene_chamfer,
        scene_chamfer_visible_m=scene_visible,
        scene_ghost_cm2=scene_ghost_cm2,
        objects=scores,
        ssim_mean=ssim,
        gate_passed=passed,
        interactor_iou=_mask_ious(
            gt.mask_dir("interactor"),
            Path(out_dir) / "masks" / "Interactor",
            n,
            min_pixels=int(0.005 * gt.width * gt.height),
        ),
        **_claimed(stage),
    )


def _claimed(stage: Usd.Stage) -> dict:
    """The world layer's gravity and scale sigmas (None without a world prim)."""
    world = stage.GetPrimAtPath(paths.WORLD)
    if not world:
        return {"gravity_uncertainty_deg": None, "scale_uncertainty": None}
    gravity = world.GetAttribute(tokens.WORLD_GRAVITY_UNCERTAINTY_DEG).Get()
    scale = world.GetAttribute(tokens.WORLD_SCALE_UNCERTAINTY).Get()
    return {
        "gravity_uncertainty_deg": None if gravity is None else float(gravity),
        "scale_uncertainty": None if scale is None else float(scale),
    }
