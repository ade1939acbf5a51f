"""The ``imported`` object backend: an object mesh made by another tool (TRELLIS's normalized
GLB, a scan or CAD model as GLB/OBJ/PLY/STL), brought to metric scale and posed at frame 0.

1. **Find** the mesh: ``mesh = "..."`` in the object's ``[[objects]]`` entry of rose.toml, else
   ``perception/<Name>.glb`` (or .obj/.ply/.stl), else, for a case with one object, the only
   mesh in ``perception/`` or in ``mesh/`` (FoundationPose's demo layout).
2. **Read and repair**: texture colors sampled at the vertices, vertices merged across UV seams,
   loose floaters (under 2 % of the surface) dropped, holes filled; a mesh that is still not a
   closed, self-intersection-free 2-manifold is rebuilt from its signed distance (Open3D ray
   parity, marching cubes). Each repair is a warning.
3. **Scale** by the paper's Eq. 1-3: rho_0 = d_image / d_mesh, the diameters of the object's
   resting points (masked metric depth, see object.fusion) and of the mesh; then a discrete
   search over rho in [rho_0 / alpha, rho_0 * alpha] (log-spaced, then a finer grid around the best,
   then a golden section to 0.2 %).
   The paper minimizes the silhouette IoU loss between the mesh rendered at its fitted pose and
   the masks of the resting frames (pixels of the interactor and of other objects left out);
   those frames see the object from about one viewpoint, where a smaller mesh nearer the camera
   meets the masks as well, so the loss here adds the depth fit's RMS (``scale_depth_weight``
   per mm, see ``PoseCost``). A mesh that is
   already metric (not TRELLIS's unit cube) keeps its scale, or its unit's (mm, cm, inch) when
   rho_0 says so; anything else is searched with a warning.
4. **Pose** at each rho: the mesh's up axis (+Y for glTF, +Z otherwise, or ``mesh_up``) is the
   world's, it stands on its support (the surface around it, or the object under it), and yaw and
   horizontal position start from ICP on the resting points (12 starting yaws, plus
   FoundationPose's pose of that frame when ``perception/ob_in_cam`` has one) and are refined on
   the same cost by a pattern search.

5. **Colors**: a file's texture stays a texture: the visual mesh is the file's own surface with
   its UVs (where the repairs dropped or rebuilt nothing), the texture in ``object_textures/``;
   else the file's vertex colors; a file without them (an STL; an OBJ whose
   materials have no color: trimesh's placeholder gray) is colored from the video, each vertex its median color
   over the rest frames where it faces the camera inside the mask, on the mesh subdivided to 8 mm
   edges within ``max_triangles`` (the object's ``colors`` fact says which).

The object's frame is the mesh's own, scaled to meters, so FoundationPose poses (made for the
same mesh) compose with the cameras unchanged. Priors, mass and collider as object.fusion."""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial
from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial import ConvexHull, cKDTree

from rose_usd.core import se3
from rose_usd.core.pinhole import silhouette
from rose_usd.core.watertight import is_closed
from rose_usd.geometry.mesh import decimate, longest_edge
from rose_usd.geometry.texture import transfer_colors
from rose_usd.io import foundationpose
from rose_usd.io.meshfile import file_unit
from rose_usd.layers.masks import Masks, read_masks
from rose_usd.layers.world import metric_depth_reader, read_cameras
from rose_usd.object.author import ObjectModel, author_objects, physics_for
from rose_usd.object.meshes import (  # noqa: F401  (re-exported: the backend's mesh reading)
    AXES,
    ImportedMesh,
    axis_name,
    axis_vector,
    choose_unit,
    find_mesh,
    read_imported,
    turned_by_colour,
    up_candidates,
    vertex_colors,
    world_from_up,
)
from rose_usd.object.rest import level_rotation, resting_clouds, spread_frames, support_height
from rose_usd.progress import say
from rose_usd.stage_api import StageContext
from rose_usd.usd.geom import MeshData


def diameter(points: np.ndarray) -> float:
    """The largest distance between two of the points (over their convex hull's vertices)."""
    hull = points[ConvexHull(points).vertices]
    if len(hull) > 2000:
        hull = hull[np.linspace(0, len(hull) - 1, 2000).astype(int)]
    d2 = ((hull[:, None, :] - hull[None, :, :]) ** 2).sum(axis=-1)
    return float(np.sqrt(d2.max()))


def _rot_z(yaw: float) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


@dataclass
class Fit:
    rho: float
    yaw: float
    translation: np.ndarray
    rms_m: float
    iou: float = float("nan")
    cost: float = float("nan")

    def world_from_up_frame(self) -> np.ndarray:
        return se3.make_pose(_rot_z(self.yaw), self.translation)


def resting_bottom(points: np.ndarray, band: float = 0.02) -> float:
    """Height of what an up-aligned mesh stands on, from its surface samples: the median height of
    those within ``band`` of its height above the lowest. The lowest vertex of a mesh made by a
    network sits under its bottom face by its noise (noise of 0.4 % of its size lifts a box by
    about 1.4 mm, which the depth fit then makes up for by shrinking it about 2 %); a round bottom
    sinks by ~1 % of its radius, which the rest step lifts out."""
    z = points[:, 2]
    low = z[z <= z.min() + band * (z.max() - z.min())]
    return float(np.median(low))


def fit_yaw_xy(
    model: np.ndarray,
    tree: cKDTree,
    observed: np.ndarray,
    rho: float,
    support_z: float,
    yaw: float,
    xy: np.ndarray,
    *,
    bottom: float,
    iters: int = 25,
) -> Fit:
    """ICP over yaw and horizontal position of the up-aligned model points (unit scale, scaled
    by ``rho``) standing by height ``bottom`` (``resting_bottom``) on z = ``support_z``, against
    the observed world points. Each observed point pairs with its nearest model point (observed
    points see one side; the model is whole); the worst 10 % of pairs are left out."""
    tz = support_z - rho * bottom
    xy = np.asarray(xy, float).copy()
    rms = float("inf")
    for _ in range(iters):
        local = (observed - np.array([*xy, tz])) @ _rot_z(yaw)  # into the model frame (rotated)
        d, idx = tree.query(local / rho)
        d = d * rho
        keep = d <= np.percentile(d, 90)
        a = (rho * model[idx[keep]]) @ _rot_z(yaw).T  # paired model points, world-rotated
        b = observed[keep] - np.array([*xy, tz])
        ca, cb = a[:, :2].mean(axis=0), b[:, :2].mean(axis=0)
        a2, b2 = a[:, :2] - ca, b[:, :2] - cb
        dyaw = float(np.arctan2(np.sum(a2[:, 0] * b2[:, 1] - a2[:, 1] * b2[:, 0]), np.sum(a2 * b2)))
        r2 = _rot_z(dyaw)[:2, :2]
        xy = xy + cb - r2 @ ca
        yaw += dyaw
        rms = float(np.sqrt(np.mean(d[keep] ** 2)))
        if abs(dyaw) < 1e-4 and np.linalg.norm(cb - r2 @ ca) < 1e-5:
            break
    return Fit(rho, float(np.arctan2(np.sin(yaw), np.cos(yaw))), np.array([*xy, tz]), rms)


@dataclass
class View:
    """One resting frame for the silhouette loss: the object's mask, the pixels to leave out (the
    interactor and other objects, which may hide the object), and the camera."""

    mask: np.ndarray
    ignore: np.ndarray
    K: np.ndarray
    world_from_cv: np.ndarray


def silhouette_iou(vertices_world: np.ndarray, faces: np.ndarray, views: list[View], *, closed: bool = False) -> float:
    """IoU of the rendered silhouettes and the masks, summed over the views, outside ``ignore``."""
    inter = union = 0
    for view in views:
        h, w = view.mask.shape
        rendered = silhouette(vertices_world, faces, view.world_from_cv, view.K, w, h, closed=closed) & ~view.ignore
        mask = view.mask & ~view.ignore
        inter += int(np.count_nonzero(rendered & mask))
        union += int(np.count_nonzero(rendered | mask))
    return inter / max(union, 1)


class PoseCost:
    """The cost of the mesh at a scale and a pose standing on its support: the silhouette IoU
    loss against the masks plus ``depth_weight`` per millimeter of the depth fit's RMS
    (observed points to the tangent plane of their nearest model sample, the worst 10 % left
    out).

    Neither term alone finds the pose. The resting frames see the object from nearly one
    viewpoint, so the silhouette is met as well by a smaller mesh nearer the camera (IoU alone
    can take a scale a few % small and move the object along the view ray); the depth sees one
    side, and a TRELLIS mesh's one side fits it a few degrees turned (ICP from neighboring starts
    converges to yaws several degrees apart). Together they agree from every start to within a
    fraction of a degree."""

    def __init__(
        self,
        vertices_up: np.ndarray,
        faces: np.ndarray,
        observed: np.ndarray,
        support_z: float,
        views: list[View],
        depth_weight: float,
    ):
        rng = np.random.default_rng(0)
        mesh = trimesh.Trimesh(vertices_up, faces, process=False)
        samples, face = trimesh.sample.sample_surface(mesh, 3000, seed=0)
        self.model, self.normals = np.asarray(samples), np.asarray(mesh.face_normals[face])
        self.tree = cKDTree(self.model)
        self.observed = observed[rng.choice(len(observed), size=min(len(observed), 2000), replace=False)]
        self.bottom = resting_bottom(self.model)
        if len(faces) > 1500:  # the silhouette needs no finer detail (a 4 cm cylinder of 1500 faces is within 0.2 mm)
            mesh = decimate(mesh, 1500, check=False)
        self.vertices, self.faces = np.asarray(mesh.vertices), np.asarray(mesh.faces)
        self.closed = is_closed(mesh)
        self.support_z, self.views, self.depth_weight = support_z, views, depth_weight

    def icp(self, rho: float, yaw: float, xy: np.ndarray) -> Fit:
        return self(fit_yaw_xy(self.model, self.tree, self.observed, rho, self.support_z, yaw, xy, bottom=self.bottom))

    def __call__(self, fit: Fit) -> Fit:
        """``fit`` with its depth RMS, IoU and cost filled in (at its own rho, yaw and xy)."""
        fit.translation = np.array([*fit.translation[:2], self.support_z - fit.rho * self.bottom])
        local = (self.observed - fit.translation) @ _rot_z(fit.yaw) / fit.rho
        idx = self.tree.query(local)[1]  # to the nearest sample's plane: the samples are ~5 mm apart on a 12 cm box
        d = np.abs(np.einsum("ij,ij->i", local - self.model[idx], self.normals[idx])) * fit.rho
        fit.rms_m = float(np.sqrt(np.mean(d[d <= np.percentile(d, 90)] ** 2)))
        fit.iou = silhouette_iou(
            se3.transform_points(fit.world_from_up_frame(), fit.rho * self.vertices),
            self.faces,
            self.views,
            closed=self.closed,
        )
        fit.cost = (1.0 - fit.iou) + self.depth_weight * 1e3 * fit.rms_m
        return fit

    def refine(
        self,
        fit: Fit,
        *,
        step_rad: float = np.radians(2.0),
        step_m: float = 0.002,
        finest: float = 1 / 8,
        max_evaluations: int = 150,
    ) -> Fit:
        """Pattern search over yaw and horizontal position from ``fit`` (scored) for the least
        cost: each coordinate stepped both ways, steps halved when none helps, down to
        ``finest`` of the first (0.25 degrees and 0.25 mm by default)."""
        best, steps, n = fit, np.array([step_rad, step_m, step_m]), 0
        while steps[0] >= step_rad * finest and n < max_evaluations:
            improved = False
            for i in range(3):
                for sign in (1.0, -1.0):
                    x = np.array([best.yaw, *best.translation[:2]])
                    x[i] += sign * steps[i]
                    trial, n = self(Fit(best.rho, float(x[0]), np.array([x[1], x[2], 0.0]), 0.0)), n + 1
                    if trial.cost < best.cost - 1e-9:
                        best, improved = trial, True
                        break
            if not improved:
                steps = steps / 2
        best.yaw = float(np.arctan2(np.sin(best.yaw), np.cos(best.yaw)))
        return best


def fit_scale_and_pose(
    vertices_up: np.ndarray,
    faces: np.ndarray,
    observed: np.ndarray,
    support_z: float,
    views: list[View],
    *,
    rho0: float,
    alpha: float,
    steps: int,
    search: bool,
    depth_weight: float = 0.1,
    extra_starts: tuple = (),
    modes: int = 4,
    resolution: float = 0.002,
) -> tuple[Fit, list[Fit]]:
    """The paper's discrete scale search (module step 3) with a joint cost (``PoseCost``): the
    best fit and the best fit at every scale tried. ``vertices_up`` are the mesh's vertices,
    up-aligned, in file units; ``extra_starts`` are (yaw, xy) poses to start from besides the
    yaw grid.

    At rho_0, ICP from 12 yaws (and the extra starts) finds the pose's modes (a box has four);
    the ``modes`` cheapest are refined on the cost and the best kept. Every scale of the
    log-spaced grid starts ICP from that pose, and the three cheapest are refined. The modes are
    found again at the best of them (at a wrong scale a box's modes cost alike: one slightly
    longer than wide can take at rho_0 the mode turned 90 degrees). Every scale of a finer
    grid around the best starts ICP from the best pose so far (and the extra starts) and is
    refined, and a golden section between the best's neighbors on it narrows the scale to
    ``resolution`` (ratio). The least cost over all is the fit."""
    cost = PoseCost(vertices_up, faces, observed, support_z, views, depth_weight)
    center_xy = 0.5 * (cost.model[:, :2].min(axis=0) + cost.model[:, :2].max(axis=0))
    obs_center = 0.5 * (cost.observed[:, :2].min(axis=0) + cost.observed[:, :2].max(axis=0))

    def best_mode(rho: float) -> Fit:
        found: list[Fit] = []
        grid = [
            (yaw, obs_center - rho * (_rot_z(yaw)[:2, :2] @ center_xy)) for yaw in np.radians(np.arange(0, 360, 30))
        ]
        for yaw, xy in list(extra_starts) + grid:
            fit = cost.icp(rho, yaw, xy)
            if all(
                abs(np.angle(np.exp(1j * (fit.yaw - d.yaw)))) > np.radians(2)
                or np.linalg.norm(fit.translation - d.translation) > 0.002
                for d in found
            ):
                found.append(fit)  # starts that converged to the same pose are refined once
        return min((cost.refine(f) for f in sorted(found, key=lambda f: f.cost)[:modes]), key=lambda f: f.cost)

    def at(rho: float, start: Fit) -> Fit:
        fits = [cost.icp(rho, start.yaw, start.translation[:2])] + [cost.icp(rho, yaw, xy) for yaw, xy in extra_starts]
        return cost.refine(min(fits, key=lambda f: f.cost))

    first = best_mode(rho0)
    if not search:
        return first, [first]
    coarse = sorted(
        (
            cost.icp(float(rho), first.yaw, first.translation[:2])
            for rho in rho0 * alpha ** np.linspace(-1.0, 1.0, steps)
        ),
        key=lambda f: f.cost,
    )
    tried = [first] + [cost.refine(f) for f in coarse[:3]] + coarse[3:]
    best = min(tried, key=lambda f: f.cost)
    if best.rho != rho0:  # a box's modes cost alike at a wrong scale: choose again at this one
        tried.append(best_mode(best.rho))
        best = min(tried, key=lambda f: f.cost)
    step = alpha ** (2.0 / (steps - 1))
    for rho in best.rho * step ** np.linspace(-1.0, 1.0, 9):
        tried.append(at(float(rho), best))
    # that grid is 1.46 % apart at the defaults, half the benchmark's scale budget (a scale halfway
    # between two of its points is about 0.7 % off): a golden section between the best's
    # neighbors narrows it to ``resolution``, each scale started from the best pose so far
    _golden_section(at, tried, step, resolution)
    return min(tried, key=lambda f: f.cost), tried


def _golden_section(at, tried: list[Fit], step: float, resolution: float) -> None:
    """Narrow the scale between the best fit's neighbors on a grid of ratio ``step`` to
    ``resolution`` (ratio) by a golden section on log scale, each scale fitted by ``at(rho,
    start)`` from the best pose so far; every fit is appended to ``tried``."""
    best = min(tried, key=lambda f: f.cost)
    lo, hi = np.log(best.rho) - 0.25 * np.log(step), np.log(best.rho) + 0.25 * np.log(step)
    g = (np.sqrt(5.0) - 1.0) / 2.0
    a, b = hi - g * (hi - lo), lo + g * (hi - lo)
    fa, fb = at(float(np.exp(a)), best), at(float(np.exp(b)), best)
    tried += [fa, fb]
    while hi - lo > np.log1p(resolution):
        start = min(tried, key=lambda f: f.cost)
        if fa.cost < fb.cost:
            hi, b, fb = b, a, fa
            a = hi - g * (hi - lo)
            fa = at(float(np.exp(a)), start)
            tried.append(fa)
        else:
            lo, a, fa = a, b, fb
            b = lo + g * (hi - lo)
            fb = at(float(np.exp(b)), start)
            tried.append(fb)


# ---------------------------------------------------------------- the backend


def _views(layer: Masks, name: str, frames: list[int], masks: list, cameras, count: int = 6) -> list[View]:
    """Up to ``count`` resting frames spread over the rest, with what to leave out of each."""
    picked = spread_frames(frames, count)
    return [
        View(masks[t], layer.occluders(name, t, masks[t].shape, grow_px=2), cameras.K[t], cameras.world_from_cv[t])
        for t in picked
    ]


def _foundationpose_start(ctx: StageContext, name: str, t: int, cameras, up_rot: np.ndarray):
    """(yaw, xy) of FoundationPose's pose of frame t as an ICP start, or None without one."""
    path = ctx.case.pose_dir(name) / f"{ctx.case.frame_name(t)}.txt"
    if path.is_file():
        world_from_mesh = cameras.world_from_cv[t] @ foundationpose.read_pose(path)
        rot = world_from_mesh[:3, :3] @ up_rot.T  # world from the up-aligned frame
        return float(np.arctan2(rot[1, 0], rot[0, 0])), world_from_mesh[:2, 3]
    return None


def _initial_scale(ctx: StageContext, name: str, path: Path, normalized: bool, d_image: float, d_mesh: float):
    """rho_0, whether to search the scale, and how it was chosen (without ``mesh_units``): the
    paper's diameter ratio for a normalized mesh (or one in unknown units), a metric mesh's own unit
    otherwise, the one the measured diameter points to (with a warning unless meters)."""
    rho0 = d_image / d_mesh
    if normalized:
        return rho0, True, "searched (normalized mesh)"
    unit_scale, unit = choose_unit(rho0)
    if unit_scale is None:
        ctx.warn(
            f"object {name!r} ({path.name}): the mesh is {d_mesh:.4g} units across "
            f"and the object ~{d_image:.3f} m: its scale is searched, as for a normalized mesh"
        )
        return rho0, True, "searched (unknown units)"
    if unit != "meters":
        ctx.warn(
            f"object {name!r} ({path.name}): the mesh looks like it is in {unit} "
            f"({d_mesh:.4g} units across, the object ~{d_image:.3f} m): scaled by {unit_scale:g}"
        )
    return unit_scale, False, f"file units ({unit})"


def _choose_up(imp: ImportedMesh, observed, support: float, views, rho0: float, depth_weight: float, fp_start):
    """The rotation (3, 3) from the mesh's frame to its up-aligned frame, the levelling rotation in
    it, and each tried axis's [cost, IoU, depth RMS mm]. Without ``mesh_up`` every signed axis is tried at rho_0
    (ICP from 12 yaws, and FoundationPose's pose when given, on ``PoseCost``); the format's
    convention keeps the choice unless another axis costs less by ``0.02`` (a cube fits alike on
    all six; a Y-up OBJ stood on +Z put a dragon on its tail)."""
    chosen, costs = None, {}
    for axis in up_candidates(imp):
        rot = world_from_up(axis)
        level = level_rotation(imp.vertices @ rot.T, imp.faces)
        rot = level @ rot
        if len(up_candidates(imp)) == 1:
            return rot, level, {}
        cost = PoseCost(imp.vertices @ rot.T, imp.faces, observed, support, views, depth_weight)
        center_xy = 0.5 * (cost.model[:, :2].min(axis=0) + cost.model[:, :2].max(axis=0))
        obs_center = 0.5 * (cost.observed[:, :2].min(axis=0) + cost.observed[:, :2].max(axis=0))
        starts = [
            (yaw, obs_center - rho0 * (_rot_z(yaw)[:2, :2] @ center_xy)) for yaw in np.radians(np.arange(0, 360, 30))
        ]
        fp = fp_start(rot)
        best = min((cost.icp(rho0, yaw, xy) for yaw, xy in ([fp] if fp else []) + starts), key=lambda f: f.cost)
        costs[axis_name(axis)] = [round(float(best.cost), 4), round(float(best.iou), 4), round(1e3 * best.rms_m, 2)]
        if chosen is None or best.cost < chosen[0] - 0.02:
            chosen = (best.cost, rot, level)
    return chosen[1], chosen[2], costs


def _read_meshes(ctx: StageContext) -> dict[str, tuple]:
    """Every object's imported mesh file, read and repaired (repairs become warnings)."""
    meshes = {}
    for spec in ctx.case.config.objects:
        path = find_mesh(ctx.case, spec)
        meshes[spec.name] = (path, read_imported(path, spec.overrides.get("mesh_up")))
        for repair in meshes[spec.name][1].repairs:
            ctx.warn(f"object {spec.name!r} ({path.name}): {repair}")
    return meshes


def _fit_object(ctx: StageContext, spec, path: Path, imp, clouds: dict, layer, cameras) -> tuple[ObjectModel, dict]:
    """Scale and pose of one imported mesh fitted to its resting points and silhouettes."""
    cfg = ctx.config
    cloud = clouds[spec.name]
    support = support_height(
        cloud.points, [c.points for name, c in clouds.items() if name != spec.name], ground=cloud.ground
    )
    observed = cloud.points[cloud.points[:, 2] > support + cfg.support_gap_m]
    d_image, d_mesh = diameter(observed), diameter(imp.vertices)
    given = spec.overrides.get("mesh_units")
    if given and given != "auto":
        unit = file_unit(d_mesh, imp.normalized, given)
        rho0, search, how = unit.meters, False, f"file units ({unit.name}, given)"
    else:
        rho0, search, how = _initial_scale(ctx, spec.name, path, imp.normalized, d_image, d_mesh)
    views = _views(layer, spec.name, cloud.frames, cloud.masks, cameras)
    up_rot, level, up_costs = _choose_up(
        imp,
        observed,
        support,
        views,
        rho0,
        cfg.imported.scale_depth_weight,
        partial(_foundationpose_start, ctx, spec.name, cloud.frames[0], cameras),
    )
    vertices_up = imp.vertices @ up_rot.T
    fp = _foundationpose_start(ctx, spec.name, cloud.frames[0], cameras, up_rot)
    say(f"object {spec.name}: fitting scale and pose to {len(observed)} points and {len(views)} silhouettes")
    best, tried = fit_scale_and_pose(
        vertices_up,
        imp.faces,
        observed,
        support,
        views,
        rho0=rho0,
        alpha=cfg.imported.scale_search_alpha,
        steps=cfg.imported.scale_search_steps,
        search=search,
        depth_weight=cfg.imported.scale_depth_weight,
        extra_starts=() if fp is None else (fp,),
    )
    if best.iou < 0.5:
        unprompted = (
            "; unprompted, its masks may be another object's: a box around it on its first frame (rose.toml's"
            " prompt = { frame = 0, box = [x0, y0, x1, y1] }, or --prompt) puts them on it"
            if spec.prompt is None
            else ""
        )
        ctx.warn(
            f"object {spec.name!r}: the fitted mesh overlaps its masks poorly (silhouette IoU {best.iou:.2f}); "
            f"check that {path.name} is this object and its masks are on it{unprompted}"
        )
    model, colors, turn = _scaled_model(ctx, spec, imp, best, up_rot, cloud, cameras)
    facts = {
        "mesh_file": str(path),
        "colors": colors,
        "colour_turn": turn,
        "scale": how,
        "rho0": round(float(rho0 if search else d_image / d_mesh), 6),
        "rho": round(float(best.rho), 6),
        "silhouette_iou": round(float(best.iou), 4),
        "icp_rms_m": round(float(best.rms_m), 5),
        "cost": round(float(best.cost), 4),
        "search": [
            [round(f.rho, 6), round(f.iou, 4), round(1e3 * f.rms_m, 2), round(f.cost, 4)]
            for f in sorted(tried, key=lambda f: f.rho)
        ],
        "rest_frames": [cloud.frames[0], cloud.frames[-1]],
        "support_height_m": round(float(support), 4),
        "foundationpose_start": fp is not None,
        "levelled_deg": round(float(se3.rotation_angle_deg(level)), 2),
        "up_axis": axis_name(np.linalg.inv(up_rot) @ np.array([0.0, 0.0, 1.0])),
        "up_costs": up_costs,
        "repairs": imp.repairs,
        "triangles": int(len(model.mesh.faces)),
    }
    return model, facts


VIDEO_COLOR_EDGE_M = 0.008
"""A mesh colored from the video is subdivided until its edges are this short (or it would pass
``object.max_triangles``): the silhouette backend's primitives are colored at the same spacing."""


def _scaled_model(
    ctx: StageContext, spec, imp, best, up_rot: np.ndarray, cloud, cameras
) -> tuple[ObjectModel, str, dict | None]:
    """The imported mesh at the fitted scale, decimated, coloured, with its physics and pose; and
    where its colors came from: the file's texture, which the visual mesh shows on the file's own
    surface ("file texture"), the file's vertex colors ("file"), else the video
    ("video": each vertex's median color over up to 12 rest frames, ``vertex_colors``, on the
    mesh subdivided to ``VIDEO_COLOR_EDGE_M`` within ``object.max_triangles``, so that a box's
    twelve triangles can show its print); the pose turned by its file colours (``turned_by_colour``)."""
    local = best.rho * imp.vertices
    tm = decimate(trimesh.Trimesh(local, imp.faces, process=False), ctx.config.max_triangles)
    vertices, faces = np.asarray(tm.vertices, float), np.asarray(tm.faces, np.int64)
    pose = best.world_from_up_frame() @ se3.make_pose(up_rot, np.zeros(3))
    surface = imp.surface.scaled(best.rho) if imp.surface is not None else None
    pose, turn = turned_by_colour(
        local, imp.faces, surface, imp.colors, pose, spread_frames(cloud.frames, 6), ctx.case.rgb, cloud.masks, cameras
    )
    if imp.colors is not None:
        colors, source = transfer_colors(vertices, local, imp.colors), "file"
    else:
        while 4 * len(faces) <= ctx.config.max_triangles and longest_edge(vertices, faces) > VIDEO_COLOR_EDGE_M:
            vertices, faces = trimesh.remesh.subdivide(vertices, faces)
        world = se3.transform_points(pose, vertices)
        picked = spread_frames(cloud.frames, 12)
        colors, source = vertex_colors(world, faces, picked, ctx.case.rgb, cloud.masks, cameras), "video"
    mesh = MeshData(vertices=vertices, faces=faces, vertex_colors=colors)
    physics, mass = physics_for(spec, vertices, faces, ctx)
    model = ObjectModel(spec.name, mesh, pose, mass, physics, surface)
    return model, "file texture" if surface else source, turn


def run(ctx: StageContext) -> None:
    n = ctx.time_info.n_frames
    cameras = read_cameras(ctx.stage, n)
    depth_of = metric_depth_reader(ctx.stage, ctx.case, cache=8)
    meshes = _read_meshes(ctx)  # every file read and repaired before any depth work: bad files fail fast
    clouds = resting_clouds(ctx, cameras, depth_of)
    layer = read_masks(ctx.stage, n)
    models, facts = [], {}
    for spec in ctx.case.config.objects:
        path, imp = meshes[spec.name]
        model, facts[spec.name] = _fit_object(ctx, spec, path, imp, clouds, layer, cameras)
        models.append(model)
    authored = author_objects(ctx, models, ctx.config.convex_tolerance)  # everything built and checked: now author
    for name, values in authored.items():
        facts[name] |= values
    ctx.record(objects=facts)
