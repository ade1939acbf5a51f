"""The ``silhouette`` object backend: an object's shape and frame-0 pose from its masks alone, for
videos without depth (capture ``sfm``).

1. **Rest.** The frames in which the object's mask stays where it was in its first clear frame
   (image IoU at least ``rest_iou`` with it; the camera is static or nearly so) are its rest;
   up to ``views`` of them, spread over it, are fitted at once. Pixels of the interactor and of
   other objects are left out of every comparison (they may hide the object).
2. **Shape.**
   - With a mesh (rose.toml's ``mesh``, ``perception/<Name>.glb``; read and repaired as the
     imported backend does, ``object.meshes``): a metric mesh keeps its size; TRELLIS's unit
     cube (or a mesh in unknown units) is scaled by the silhouettes: the paper's Eq. 1-3, its
     search over rho done by the simplex with position and yaw, started at rho_0 = the world's
     object width over the mesh's.
   - Without: the category's primitive (``geometry.primitives``: a cup's frustum, a mug's
     cylinder with a handle, a can's cylinder, a pen's lying cylinder, a box), its dimensions
     fitted to the silhouettes under a log-normal prior around the typical ones (``size_m``'s
     where given; one sigma: the category's spread and the world scale's together), so a size
     the masks leave open (an end hidden by the hand or out of the crop) stays near it; marked as
     a proxy (``RoseShapeAPI``: ``rose:shape:proxy``). A pen starts on its mask's axis cast onto
     the support.
   The world's metric scale came from the same kind of fit in the capture stage (its size prior,
   category or mesh), so the sizes agree with it.
3. **Pose.** Standing on the support (the scene's pad height under it) at (x, y) turned by yaw,
   fitted by Nelder-Mead on the silhouette IoU (``geometry.silhouette.fit_standing``) from the
   foot of the mask, from several yaws. Stacks: an object whose mask's foot, cast onto another
   object's top, lands inside that one's footprint is fitted standing there too, and stands where
   that fit costs less (``_stack``). A metric mesh is also fitted free (6-DoF,
   ``search_free`` over 1800 orientations then ``fit_free``): when that fits better by
   ``held_margin`` IoU, or standing fits poorly, the object is held in the air in its rest frames
   and keeps the free pose (it is then not rested on the scene).
4. **Colors.** A mesh's own colors, else each vertex's median color over the rest frames where it
   faces the camera inside the mask (nearest seen vertex elsewhere).

Mass priors, the collider and its CoACD coverage, and the rest on the scene as for every object
backend (``object.author``).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
import trimesh
from scipy.spatial import ConvexHull, QhullError

from rose_usd.core import se3
from rose_usd.errors import InputError
from rose_usd.geometry.mesh import decimate, longest_edge
from rose_usd.geometry.primitives import (
    RESTING_MARGIN,
    TYPICAL,
    hull_points,
    largest_dimension,
    primitive_mesh,
    resting_kinds,
    turns,
    typical,
)
from rose_usd.geometry.silhouette import (
    View,
    crop_view,
    fit_free,
    fit_standing,
    footprint_xy,
    log_normal_given_size,
    log_normal_sizes,
    resting_start,
    search_free,
)
from rose_usd.geometry.texture import transfer_colors
from rose_usd.io.meshfile import file_unit
from rose_usd.layers.masks import read_masks
from rose_usd.layers.scene import support_heights
from rose_usd.layers.world import read_cameras, read_scale
from rose_usd.object.author import ObjectModel, author_objects, physics_for
from rose_usd.object.meshes import (
    axis_name,
    read_imported,
    turned_by_colour,
    up_candidates,
    vertex_colors,
    world_from_up,
)
from rose_usd.object.rest import level_rotation, spread_frames
from rose_usd.progress import say
from rose_usd.stage_api import StageContext
from rose_usd.usd import paths, schema, tokens
from rose_usd.usd.geom import MeshData


def rest_frames(masks: list, *, min_iou: float, min_px: int = 50) -> list[int]:
    """The first clear frame and every later one whose mask overlaps its mask by ``min_iou``
    (image IoU), until one does not (the object moved; a frame where it is hidden by more than
    half is skipped, not a move)."""
    area = np.array([0 if m is None else int(m.sum()) for m in masks])
    clear = np.flatnonzero(
        area >= max(min_px, 0.5 * np.percentile(area[area >= min_px], 90)) if (area >= min_px).any() else []
    )
    if not len(clear):
        return []
    first = int(clear[0])
    ref = masks[first]
    frames = [first]
    for t in range(first + 1, len(masks)):
        m = masks[t]
        if m is None or area[t] < 0.5 * area[first]:
            continue
        inter = np.count_nonzero(m & ref)
        if inter / max(np.count_nonzero(m | ref), 1) < min_iou:
            break
        frames.append(t)
    return frames


def _dense(vertices: np.ndarray, faces: np.ndarray, edge_m: float) -> tuple[np.ndarray, np.ndarray]:
    """The mesh subdivided until its edges are at most ``edge_m`` (a primitive's few vertices
    carry colors too coarse); a mesh whose longest edge is over 64 ``edge_m`` gets 64 pieces of it
    (marker on openreal2sim-marker-rgb fitted 3 m long: 8 halvings did not reach 8 mm)."""
    longest = longest_edge(vertices, faces)
    v, f = trimesh.remesh.subdivide_to_size(vertices, faces, max_edge=max(edge_m, longest / 64.0), max_iter=8)
    return np.asarray(v, float), np.asarray(f, np.int64)


def run(ctx: StageContext) -> None:
    case, cfg, n = ctx.case, ctx.config, ctx.time_info.n_frames
    scfg = cfg.silhouette
    cameras = read_cameras(ctx.stage, n)
    layer = read_masks(ctx.stage, n, (case.height, case.width))
    pads = support_heights(ctx.stage)
    scale = read_scale(ctx.stage)
    fits = {}
    for spec in case.config.objects:
        layer.require(spec.name)
        masks = layer.track(spec.name)
        frames = rest_frames(masks, min_iou=scfg.rest_iou)
        if not frames:
            raise InputError(
                f"object {spec.name!r} is never clearly seen in its masks",
                path=layer.where(spec.name),
                hint="check its prompt (rose-usd run segment ... --prompt)",
            )
        picked = spread_frames(frames, scfg.views)
        views = [
            crop_view(
                masks[t],
                layer.occluders(spec.name, t, masks[t].shape, grow_px=2),
                cameras.K[t],
                cameras.world_from_cv[t],
                frame=t,
                max_side=scfg.max_side_px,
            )
            for t in picked
        ]
        path = case.mesh_file(spec)
        say(f"object {spec.name}: fitting {'its mesh' if path else 'a primitive'} to {len(views)} silhouettes")

        def fit(support_z, spec=spec, path=path, views=views, masks=masks, picked=picked, frames=frames):
            xy = footprint_xy(masks[picked[0]], cameras.K[picked[0]], cameras.world_from_cv[picked[0]], support_z)
            with ctx.deferred_warnings() as warnings:  # given where this fit is kept
                if path is not None:
                    model, fact, shape = _fit_mesh(ctx, spec, path, views, masks, picked, xy, support_z, cameras)
                else:
                    model, fact, shape = _fit_primitive(ctx, spec, views, masks, picked, xy, support_z, cameras, scale)
            fact.update(rest_frames=[frames[0], frames[-1]], fitted_frames=picked, support_height_m=support_z)
            return FitResult(model, fact, shape, warnings)

        t0 = picked[0]
        foot = functools.partial(footprint_xy, masks[t0], cameras.K[t0], cameras.world_from_cv[t0])
        fits[spec.name] = Fitted(fit, foot, fit(float(pads.get(spec.name, 0.0))))
    _stack(fits)
    models, facts, shapes = [], {}, {}
    for spec in case.config.objects:
        name, (model, fact, shape, warnings) = spec.name, fits[spec.name].result
        for message in warnings:
            ctx.warn(message)
        if fact["silhouette_iou"] < 0.6:
            ctx.warn(
                f"object {name!r}: its shape overlaps its masks poorly"
                f" (silhouette IoU {fact['silhouette_iou']:.2f}): a {fact['size_m'] * 100:.1f} cm"
                f" {spec.category or 'object'} standing on the support does not fit them; {_poor_fit_cause(case, spec)}"
            )
        models.append(model)
        facts[name] = fact
        shapes[name] = shape
    authored = author_objects(ctx, models, cfg.convex_tolerance)
    for name, values in authored.items():
        facts[name] |= values
        prim = ctx.stage.GetPrimAtPath(paths.object_path(name))
        prim.ApplyAPI(schema.SHAPE_API)
        source, proxy, kind, iou = shapes[name]
        prim.GetAttribute(tokens.SHAPE_SOURCE).Set(source)
        prim.GetAttribute(tokens.SHAPE_PROXY).Set(proxy)
        prim.GetAttribute(tokens.SHAPE_PRIMITIVE).Set(kind)
        prim.GetAttribute(tokens.SHAPE_SILHOUETTE_IOU).Set(float(iou))
    ctx.record(objects=facts, world_scale={"source": scale.source, "uncertainty": round(scale.uncertainty, 4)})


@dataclass
class FitResult:
    model: ObjectModel
    fact: dict
    shape: tuple
    warnings: list[str]
    """What the fit would warn about, given only where it is kept."""

    def __iter__(self):
        return iter((self.model, self.fact, self.shape, self.warnings))

    @property
    def points(self) -> np.ndarray:
        """The mesh's vertices in the world at frame 0 (N, 3)."""
        return se3.transform_points(self.model.world_from_object_0, self.model.mesh.vertices)


@dataclass
class Fitted:
    """An object's fit: how to fit it standing on a height (z [m] -> FitResult), where its mask's
    foot meets a height (z -> (x, y) or None), and the fit kept."""

    refit: Callable[[float], FitResult]
    foot_xy: Callable[[float], np.ndarray | None]
    result: FitResult


STACKED_M = 0.01
"""Another object whose top is this much [m] above an object's support is a support it may stand on."""
STACKED_MARGIN = 0.005
"""How much lower [1 - IoU + size prior] a fit on another object must cost to be kept."""
INSIDE_FRACTION = 0.05
"""An object with this fraction of its volume inside another's hull stands in it: a fit on that
one's top is kept whatever it costs."""


def _poor_fit_cause(case, spec) -> str:
    """What a poor primitive fit may come from, naming only the inputs the user has not given."""
    missing = [
        name
        for name, given in (("cam_K.txt", case.K_path is not None), ("size_m", "size_m" in spec.overrides))
        if not given
    ]
    if missing:
        return f"the world's gravity, intrinsics or scale may be wrong (give {', '.join(missing)})"
    return (
        "cam_K.txt and size_m are given: the masks may hold more or less than the object,"
        " or the object is not its category's shape (give its mesh)"
    )


def _stack(fits: dict[str, Fitted]) -> None:
    """Objects stacked on others. An object whose mask's foot, cast onto the top of another (not
    held in the air), lands inside that one's footprint is fitted standing on it too, and stands
    there where that fit costs ``STACKED_MARGIN`` less (1 - IoU + the size prior), or wherever its
    fit on the support puts it inside that one (``INSIDE_FRACTION``), and is not held; an object
    standing on one that moved is refitted on its new top. Repeated until nothing moves
    (a stack of three settles from the bottom). In place; the fact says ``stands_on``."""
    world = {n: f.result.points for n, f in fits.items()}
    for _ in range(len(fits)):
        moved = False
        for name, a in fits.items():
            for other, b in fits.items():
                if other == name or b.result.fact.get("held") or b.result.fact.get("stands_on") == name:
                    continue
                top, now = float(world[other][:, 2].max()), a.result.fact
                on = now.get("stands_on") == other
                if on and abs(top - now["support_height_m"]) < 1e-6:
                    continue
                if not on and (
                    top - now["support_height_m"] < STACKED_M or not _lands_on(a.foot_xy(top), world[other])
                ):
                    continue
                found = a.refit(top)
                cheaper = found.fact["fit_cost"] <= now["fit_cost"] - STACKED_MARGIN
                if found.fact.get("held") or (not on and not cheaper and not _inside(world[name], world[other])):
                    continue
                found.fact["stands_on"] = other
                a.result, world[name], moved = found, found.points, True
        if not moved:
            return


def _inside(points: np.ndarray, other: np.ndarray) -> bool:
    """Whether more than ``INSIDE_FRACTION`` of the convex hull of ``points`` (N, 3) lies 5 mm or
    more inside that of ``other`` (M, 3), by volume (a grid of 10^3 over the first's box): two
    solids in one place, which no rest allows."""
    try:
        mine, theirs = ConvexHull(points), ConvexHull(other)
    except QhullError:
        return False
    lo, hi = points.min(axis=0), points.max(axis=0)
    axes = [np.linspace(a, b, 10) for a, b in zip(lo, hi)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    grid = grid[(grid @ mine.equations[:, :3].T + mine.equations[:, 3]).max(axis=1) <= 1e-9]
    if not len(grid):
        return False
    depth = (grid @ theirs.equations[:, :3].T + theirs.equations[:, 3]).max(axis=1)
    return bool(np.mean(depth < -0.005) > INSIDE_FRACTION)


def _lands_on(xy, points: np.ndarray) -> bool:
    """Whether the point (x, y) (or None) lies inside the footprint of ``points`` (N, 3)."""
    if xy is None:
        return False
    try:
        hull = ConvexHull(points[:, :2])
    except QhullError:  # a flat footprint (a card seen edge on) holds nothing
        return False
    return bool(np.all(hull.equations[:, :2] @ np.asarray(xy) + hull.equations[:, 2] <= 0.0))


def _start(xy, views: list[View], size_m: float):
    """Where to start a standing fit: a little behind the mask's foot, away from the camera."""
    if xy is None:
        cam = views[0].world_from_cv
        ahead = cam[:3, 2].copy()
        ahead[2] = 0.0
        return cam[:2, 3] + ahead[:2] / max(np.linalg.norm(ahead[:2]), 1e-9) * 0.5
    toward = np.asarray(xy) - views[0].world_from_cv[:2, 3]
    return np.asarray(xy) + 0.3 * size_m * toward / max(np.linalg.norm(toward), 1e-9)


def _object_width_m(view: View, xy) -> float:
    """The mask's width at its foot's depth [m] (a start for sizes)."""
    ys, xs = np.nonzero(view.mask)
    if xy is None or not len(xs):
        return 0.1
    foot = se3.invert(view.world_from_cv) @ np.array([xy[0], xy[1], 0.0, 1.0])
    return float(xs.max() - xs.min()) * foot[2] / view.K[0, 0]


def size_prior(typ, size_given_m: float | None, scale_uncertainty: float) -> tuple[np.ndarray, Callable]:
    """Where a category's primitive fit starts (its typical dimensions, scaled to ``size_m`` where
    given) and its size cost: with ``size_m``, that largest dimension known to ``GIVEN_SIZE_SIGMA``
    and the world's scale together, the proportions to the category's spread; without, every
    dimension to the category's spread and the world's scale together."""
    dims = np.asarray(typ.dims, float)
    if size_given_m:
        sigma = float(np.hypot(GIVEN_SIZE_SIGMA, scale_uncertainty))
        return dims * float(size_given_m) / typ.size_m, log_normal_given_size(
            typ.kind, dims, float(size_given_m), sigma, typ.sigma
        )
    return dims, log_normal_sizes(dims, float(np.hypot(typ.sigma, scale_uncertainty)))


GIVEN_SIZE_SIGMA = 0.05
"""Relative one-sigma of a primitive's largest dimension around a given ``size_m``."""


def _fit_primitive(ctx, spec, views, masks, picked, xy, support_z, cameras, scale):
    typ, known = typical(spec.category)
    if not known:
        shaped = ", ".join(sorted(k for k in TYPICAL if k != "generic"))
        ctx.warn(
            f"object {spec.name!r}: no primitive for category {spec.category!r}: a box stands in for it; give"
            f" [[objects]] name = {spec.name!r} a category in {ctx.case.settings_file.name} (one of: {shaped})"
        )
    width = _object_width_m(views[0], xy)
    expected, size_cost = size_prior(typ, spec.overrides.get("size_m"), scale.uncertainty)
    kind, fit = None, None
    first = views[0]
    for candidate in resting_kinds(typ.kind):  # a can standing, or lying where that fits clearly better
        xy0, yaws, _ = resting_start(
            candidate, first.mask, first.K, first.world_from_cv, _start(xy, views, width), support_z
        )
        tried = fit_standing(
            lambda d, candidate=candidate: hull_points(candidate, d),
            expected,
            views,
            xy0,
            support_z=support_z,
            yaws=yaws,
            turn=turns(candidate),
            convex=True,
            size_cost=size_cost,
        )
        if fit is None or tried.iou > fit.iou + RESTING_MARGIN:
            kind, fit = candidate, tried
    v, f = primitive_mesh(kind, fit.size, segments=48)
    v, f = _dense(v, f, 0.008)
    pose = fit.pose(support_z)
    colors = vertex_colors(se3.transform_points(pose, v), f, picked, ctx.case.rgb, masks, cameras)
    mesh = MeshData(vertices=v, faces=f, vertex_colors=colors)
    physics, mass = physics_for(spec, v, f, ctx)
    size = largest_dimension(kind, fit.size)
    fact = {
        "shape": "primitive",
        "proxy": True,
        "primitive": kind.value,
        "dims_m": [round(float(d), 5) for d in fit.size],
        "size_m": round(size, 5),
        "size_given_m": spec.overrides.get("size_m"),
        "typical_size_m": typ.size_m,
        "silhouette_iou": round(fit.iou, 4),
        "fit_cost": round(fit.cost, 5),
        "yaw_deg": round(float(np.degrees(fit.yaw)), 2),
        "held": False,
    }
    return ObjectModel(spec.name, mesh, pose, mass, physics), fact, ("primitive", True, kind.value, fit.iou)


def _fit_mesh(ctx, spec, path, views, masks, picked, xy, support_z, cameras):
    """The object's mesh file fitted to its silhouettes, standing (and free when metric: held in
    the air when that fits better), scaled, decimated and colored: (model, fact, shape)."""
    scfg = ctx.config.silhouette
    imp = read_imported(path, spec.overrides.get("mesh_up"))
    for repair in imp.repairs:
        ctx.warn(f"object {spec.name!r} ({path.name}): {repair}")
    extent = float(np.max(imp.vertices.max(axis=0) - imp.vertices.min(axis=0)))
    unit = file_unit(extent, imp.normalized, spec.overrides.get("mesh_units"))
    metric = unit.meters is not None
    if metric:
        imp = replace(imp, vertices=imp.vertices * unit.meters)
    if unit.guessed:
        ctx.warn(
            f"object {spec.name!r} ({path.name}): the mesh is {unit.describe(extent)}:"
            ' write mesh_units = "m", "cm", "mm" or "in" in its [[objects]] entry if it is not'
        )
    width = _object_width_m(views[0], xy)
    small = trimesh.Trimesh(imp.vertices, imp.faces, process=False)
    if len(small.faces) > 1500:
        small = decimate(small, 1500, check=False)
    sv, sf = np.asarray(small.vertices, float), np.asarray(small.faces, np.int64)
    fit, rot, base, axis = _fit_mesh_standing(imp, sv, sf, metric, width, views, xy, support_z)
    rho = float(fit.size[0])
    # world_from_mesh frame (the file's frame scaled to meters by rho)
    pose = fit.pose(support_z) @ se3.make_pose(rot, -rho * base)
    held, free_iou = False, None
    if metric:
        free_pose, free_iou = _fit_mesh_free(sv, sf, views, scfg.free_directions)
        if free_pose is not None and (free_iou > fit.iou + scfg.held_margin or fit.iou < 0.6):
            held = True
            pose = free_pose
    iou = free_iou if held else fit.iou
    vertices = rho * imp.vertices
    surface = imp.surface.scaled(rho * (unit.meters if metric else 1.0)) if imp.surface is not None else None
    pose, turn = turned_by_colour(vertices, imp.faces, surface, imp.colors, pose, picked, ctx.case.rgb, masks, cameras)
    tm = decimate(trimesh.Trimesh(vertices, imp.faces, process=False), ctx.config.max_triangles)
    v, f = np.asarray(tm.vertices, float), np.asarray(tm.faces, np.int64)
    if imp.colors is not None:
        colors = transfer_colors(v, vertices, imp.colors)
    else:
        colors = vertex_colors(se3.transform_points(pose, v), f, picked, ctx.case.rgb, masks, cameras)
    mesh = MeshData(vertices=v, faces=f, vertex_colors=colors)
    physics, mass = physics_for(spec, v, f, ctx)
    if held:
        ctx.warn(
            f"object {spec.name!r} is held in the air in its first frames (free pose IoU {free_iou:.2f} against"
            f" standing {fit.iou:.2f}): its frame-0 pose is not on the support"
        )
    fact = {
        "shape": "mesh",
        "mesh_file": str(path),
        "proxy": False,
        "metric_mesh": metric,
        "mesh_units": unit.name,
        "units_guessed": unit.guessed,
        "rho": round(rho * (unit.meters or 1.0), 9),
        "size_m": round(float(np.ptp(vertices, axis=0).max()), 5),
        "size_given_m": spec.overrides.get("size_m"),
        "up_axis": axis_name(axis),
        "standing_iou": round(fit.iou, 4),
        "fit_cost": round(fit.cost, 5),
        "free_iou": None if free_iou is None else round(free_iou, 4),
        "held": held,
        "silhouette_iou": round(float(iou), 4),
        "repairs": imp.repairs,
        "colour_turn": turn,
    }
    fact["visual"] = "file texture" if surface is not None else "vertex colors"
    return ObjectModel(spec.name, mesh, pose, mass, physics, surface), fact, ("imported", False, "", iou)


def _fit_mesh_standing(imp, sv, sf, metric: bool, width: float, views, xy, support_z: float):
    """The mesh (decimated: ``sv``, ``sf``) standing on the support, fitted for each candidate up
    axis (only the given one for a metric mesh with mesh_up): the best (fit, rotation (3, 3) from
    the file's frame to up, base point (3,) of the upright mesh, up axis)."""
    best = None
    for axis in up_candidates(imp)[: 1 if metric and imp.up_given else 6]:
        rot = world_from_up(axis)
        rot = level_rotation(imp.vertices @ rot.T, imp.faces) @ rot
        up_v = sv @ rot.T
        base = np.array([*(0.5 * (up_v.min(axis=0) + up_v.max(axis=0)))[:2], up_v[:, 2].min()])
        rho0 = 1.0 if metric else width / max(float(np.ptp(up_v, axis=0).max()), 1e-9)

        def shape(r, up_v=up_v, base=base):
            return r[0] * (up_v - base), sf

        fit = fit_standing(
            shape,
            np.array([rho0]),
            views,
            _start(xy, views, width),
            support_z=support_z,
            yaws=tuple(np.radians([0.0, 90.0, 180.0, 270.0])),
            free_size=np.array([not metric]),
            maxfev=250,
        )
        if best is None or fit.iou > best[0].iou + 0.01:
            best = (fit, rot, base, axis)
        if metric and imp.up_given:
            break
    return best


def _fit_mesh_free(sv, sf, views, directions: int):
    """The metric mesh (decimated: ``sv``, ``sf``) fitted free (6-DoF) from the best three of
    ``directions`` orientations searched in the first view: (pose (4, 4), IoU), or (None, None)."""
    found = search_free(sv, sf, views[0], directions=directions, rolls=12)
    if not found:
        return None, None
    free_pose, free_iou = fit_free(sv, sf, views, found[0][1])
    for _, start in found[1:3]:
        p2, i2 = fit_free(sv, sf, views, start)
        if i2 > free_iou:
            free_pose, free_iou = p2, i2
    return free_pose, free_iou
