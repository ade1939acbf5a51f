"""Generate one seeded synthetic case: a tabletop room, one or two target objects, a hand proxy
that performs one of the paper's five tasks, and a hand-held camera. It is rendered with Mitsuba
(RGB, clean metric depth, a depth sensor's reading, and the object and interactor masks) and written
in the case layout with full ground truth (rose_usd.case.gt).

The written case is the ``rgbd`` perception mode: ``depth/`` holds sensor depth with realistic
errors (rose_usd.synth.sensor), seen from a depth camera slightly off its calibrated pose. Clean
depth from the color camera is ground truth, in ``gt/depth/``. Other modes are
derived from this case by rose_usd.bench.modes.
"""

from __future__ import annotations

import colorsys
import dataclasses
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from rose_usd.case import gt as gtfmt
from rose_usd.core import se3
from rose_usd.core.color import srgb_to_linear
from rose_usd.core.inertia import mass_properties
from rose_usd.errors import ConfigError, InputError
from rose_usd.io import images
from rose_usd.io.meshfile import write_obj
from rose_usd.io.tum import write_tum
from rose_usd.object.priors import PRIORS
from rose_usd.progress import progress, say
from rose_usd.render.lighting import Lighting, PointLight
from rose_usd.render.scene import RenderItem, RenderScene
from rose_usd.synth import hand as handmod
from rose_usd.synth import shapes, textures
from rose_usd.synth.motion import Task, hand_trajectory, handheld_camera, phases, task_motion
from rose_usd.synth.sensor import sample_depth_extrinsic, sensor_depth
from rose_usd.usd.geom import MeshData

INTERACTOR_LABEL = 255
SKIN_LINEAR = tuple(srgb_to_linear(np.array([224, 172, 140]) / 255.0).tolist())
GENERATOR_VERSION = 4
"""Bumped whenever a change to the generator changes the cases it writes."""


@dataclass(frozen=True)
class GenerateConfig:
    """What to generate."""

    task: Task = Task.PUSH
    """Manipulation task staged in the video."""
    shape: shapes.ObjectShape = shapes.ObjectShape.BOX
    """Shape of the manipulated object (UNSTACK adds a box underneath it)."""
    seed: int = 0
    """Seed of every random choice (scene, objects, motion, camera, sensor)."""
    n_frames: int = 48
    """Number of video frames."""
    width: int = 320
    """Image width [px]."""
    height: int = 240
    """Image height [px]."""
    fps: float = 30.0
    """Frame rate [1/s]."""
    spp: int = 16
    """Samples per pixel of the RGB renders (anti-aliasing only: the shading is noise-free)."""
    realistic: bool = False
    """A case as hard as a real video: a hand with fingers wrapped around the object, in a skin
    tone and a sleeve, casting shadows; printed and speckled objects; a cloth under the object;
    clutter in the object's colors; a can's label is paper, not metal, to the depth sensor."""
    static_camera: bool = False
    """The camera stands on a tripod (no sweep, no shake)."""
    lying: bool = False
    """The manipulated object starts lying on its side (cans and mugs; a pen always does)."""


@dataclass
class _Part:
    name: str
    mesh: trimesh.Trimesh
    color_linear: tuple[float, float, float] | None = None
    texture: np.ndarray | None = None
    uv: np.ndarray | None = None
    vertex_colors: np.ndarray | None = None
    """Rendered only; the written mesh carries ``color_linear`` (their mean)."""


@dataclass
class _Object:
    name: str
    spec: shapes.ShapeSpec
    part: _Part
    category: str
    density: float
    friction: float
    restitution: float
    specular: bool
    poses: np.ndarray
    label: int


def _planar_uv(vertices: np.ndarray, axes: tuple[int, int], meters_per_tile: float) -> np.ndarray:
    return np.stack([vertices[:, axes[0]], vertices[:, axes[1]]], axis=1) / meters_per_tile


def _random_color(rng: np.random.Generator, *, saturated: bool) -> tuple[float, float, float]:
    h = rng.uniform(0, 1)
    s = rng.uniform(0.55, 0.9) if saturated else rng.uniform(0.05, 0.3)
    v = rng.uniform(0.55, 0.9)
    return tuple(srgb_to_linear(np.array(colorsys.hsv_to_rgb(h, s, v))).tolist())


def _static_scene(rng: np.random.Generator, keep_clear_m: float) -> tuple[list[_Part], dict]:
    """Table (top at z = 0), legs, floor, four walls, clutter outside ``keep_clear_m`` of the origin."""
    parts: list[_Part] = []
    top_x, top_y = rng.uniform(1.0, 1.3), rng.uniform(0.75, 0.9)
    thickness = 0.04
    height = rng.uniform(0.72, 0.78)
    cx, cy = rng.uniform(-0.12, 0.12), rng.uniform(-0.06, 0.06)  # table center (the object is at the origin)
    top = shapes.box((top_x, top_y, thickness), center=(cx, cy, -thickness / 2))
    kind = str(rng.choice(list(textures.TABLE_TEXTURES)))
    parts.append(
        _Part(
            "TableTop",
            top,
            texture=textures.TABLE_TEXTURES[kind](rng),
            uv=_planar_uv(top.vertices, (0, 1), rng.uniform(0.5, 0.8)),
        )
    )
    leg_color = tuple(srgb_to_linear(np.array([60, 48, 40]) / 255.0).tolist())
    legs = []
    for sx in (-1, 1):
        for sy in (-1, 1):
            legs.append(
                shapes.box(
                    (0.05, 0.05, height - thickness),
                    center=(
                        cx + sx * (top_x / 2 - 0.06),
                        cy + sy * (top_y / 2 - 0.06),
                        -thickness - (height - thickness) / 2,
                    ),
                )
            )
    parts.append(_Part("TableLegs", trimesh.util.concatenate(legs), color_linear=leg_color))
    room = 5.0
    floor = shapes.box((room, room, 0.05), center=(cx, cy, -height - 0.025))
    parts.append(_Part("Floor", floor, texture=textures.tiles(rng), uv=_planar_uv(floor.vertices, (0, 1), 1.2)))
    wall_tex = textures.plaster(rng)
    wall_h = 2.6
    for i, (dx, dy, ex, ey) in enumerate(
        ((room / 2, 0, 0.1, room), (-room / 2, 0, 0.1, room), (0, room / 2, room, 0.1), (0, -room / 2, room, 0.1))
    ):
        wall = shapes.box((ex, ey, wall_h), center=(cx + dx, cy + dy, -height + wall_h / 2))
        axes = (1, 2) if ex < ey else (0, 2)
        parts.append(_Part(f"Wall{i}", wall, texture=wall_tex, uv=_planar_uv(wall.vertices, axes, 1.5)))
    n_clutter = int(rng.integers(2, 4))
    placed: list[tuple[float, float, float]] = []
    for k in range(n_clutter):
        for _ in range(200):
            x = rng.uniform(cx - top_x / 2 + 0.1, cx + top_x / 2 - 0.1)
            y = rng.uniform(cy - top_y / 2 + 0.1, cy + top_y / 2 - 0.1)
            if np.hypot(x, y) > keep_clear_m and all(np.hypot(x - px, y - py) > pr + 0.1 for px, py, pr in placed):
                break
        kind = rng.choice(["box", "cylinder", "sphere"])
        if kind == "box":
            ext = rng.uniform(0.05, 0.14, size=3)
            mesh = shapes.box(ext, center=(0, 0, ext[2] / 2))
            mesh.apply_transform(se3.make_pose(se3.rotation_about([0, 0, 1], rng.uniform(0, np.pi)), [x, y, 0]))
            radius = 0.5 * np.hypot(ext[0], ext[1])
        elif kind == "cylinder":
            radius, h = rng.uniform(0.03, 0.06), rng.uniform(0.05, 0.18)
            mesh = shapes.cylinder(radius, h, sections=48)
            mesh.apply_translation([x, y, 0])
        else:
            radius = rng.uniform(0.03, 0.055)
            mesh = shapes.sphere(radius, (x, y, radius))
        placed.append((x, y, radius))
        parts.append(_Part(f"Clutter{k}", mesh, color_linear=_random_color(rng, saturated=bool(rng.random() < 0.5))))
    layout = {
        "table_center": (cx, cy),
        "table_half_extent": (top_x / 2, top_y / 2),
        "table_height": height,
        "table_texture": kind,
    }
    return parts, layout


def _lighting(rng: np.random.Generator) -> Lighting:
    ambient = rng.uniform(0.35, 0.5)
    lights = []
    for i in range(int(rng.integers(1, 3))):
        az = rng.uniform(-np.pi, np.pi)
        pos = np.array([rng.uniform(0.5, 1.0) * np.cos(az), rng.uniform(0.5, 1.0) * np.sin(az), rng.uniform(1.3, 1.9)])
        irradiance = rng.uniform(0.45, 0.65) / (1.0 + 0.6 * i)  # at the object, facing the light
        warm = np.array([1.0, rng.uniform(0.93, 1.0), rng.uniform(0.85, 0.97)])
        lights.append(PointLight(tuple(pos.tolist()), tuple((irradiance * float(pos @ pos) * warm).tolist())))
    return Lighting(ambient=(ambient,) * 3, points=tuple(lights))


def _intrinsics(rng: np.random.Generator, width: int, height: int) -> np.ndarray:
    hfov = np.radians(rng.uniform(58.0, 66.0))
    f = width / (2.0 * np.tan(hfov / 2.0))
    scale = width / 640.0
    return np.array(
        [
            [f, 0.0, (width - 1) / 2.0 + rng.uniform(-4, 4) * scale],
            [0.0, f, (height - 1) / 2.0 + rng.uniform(-4, 4) * scale],
            [0.0, 0.0, 1.0],
        ]
    )


def _mesh_data(part: _Part, texture_path: Path | None) -> MeshData:
    return MeshData(
        vertices=np.asarray(part.mesh.vertices, dtype=float),
        faces=np.asarray(part.mesh.faces, dtype=np.int64),
        vertex_colors=part.vertex_colors,
        color=part.color_linear,
        uv=part.uv,
        texture=texture_path,
    )


def _write_part(gt_dir: Path, rel_mesh: str, part: _Part) -> tuple[gtfmt.Appearance, Path | None]:
    texture_rel = None
    texture_path = None
    if part.texture is not None:
        texture_rel = str(Path(rel_mesh).with_suffix(".png"))
        texture_path = gt_dir / texture_rel
        images.write_rgb(texture_path, part.texture)
    write_obj(
        gt_dir / rel_mesh,
        part.mesh.vertices,
        part.mesh.faces,
        uv=part.uv if part.texture is not None else None,
        color_linear=part.color_linear,
        texture_file=Path(texture_rel).name if texture_rel else None,
    )
    return gtfmt.Appearance(part.color_linear, texture_rel), texture_path


def _make_object(rng, shape: shapes.ObjectShape, name: str, label: int) -> _Object:
    spec = shapes.sample_object(shape, rng)
    category = shapes.SHAPE_CATEGORY[shape]
    prior = PRIORS[category]
    return _Object(
        name=name,
        spec=spec,
        part=_Part(name, spec.mesh, color_linear=_random_color(rng, saturated=True)),
        category=category,
        density=float(rng.uniform(*prior.density_range_kg_m3)),
        friction=float(np.clip(rng.normal(prior.friction, prior.friction_sigma / 2), 0.2, 1.0)),
        restitution=float(np.clip(rng.normal(prior.restitution, prior.restitution_sigma / 2), 0.0, 0.8)),
        specular=shape is shapes.ObjectShape.CAN,  # metal cans mirror the depth sensor's pattern away
        poses=np.zeros((0, 4, 4)),
        label=label,
    )


def _lying_rotation(mesh: trimesh.Trimesh, rng: np.random.Generator) -> np.ndarray:
    """A rotation that lays an object (built standing, +Z up) on its side, resting on its body
    and, for a mug, on its handle too (the stable way a mug lies)."""
    lay = np.array([[0.0, 0.0, 1.0], [0.0, -1.0, 0.0], [1.0, 0.0, 0.0]])  # object X up, object Z along world X
    v = np.asarray(mesh.vertices, float)
    radial = np.hypot(v[:, 0], v[:, 1])
    body_r = float(np.percentile(radial[v[:, 0] <= 0], 99)) if (v[:, 0] <= 0).any() else float(radial.max())
    handle = radial > body_r + 0.002
    roll = 0.0
    if handle.any():
        # roll about the (now horizontal) axis until the handle's lowest point meets the table
        best = np.inf
        for a in np.radians(np.arange(90.0, 180.0, 0.5)):
            z = (v @ (se3.rotation_about([1, 0, 0], a) @ lay).T)[:, 2]
            gap = abs(z[handle].min() - z[~handle].min())
            if gap < best:
                best, roll = gap, a
    roll *= float(rng.choice([-1.0, 1.0])) if handle.any() else 1.0
    return se3.rotation_about([1, 0, 0], roll) @ lay


def _realistic_scene(parts: list[_Part], objects: list[_Object], rng: np.random.Generator) -> list[_Part]:
    """Make a generated scene as hard as a real one: the table gets a cloth under the objects
    (the table top sinks by its thickness), the clutter takes the manipulated object's hues, and
    the objects are printed or speckled (per-vertex colors on a 2 mm mesh)."""
    thickness = 0.004
    for part in parts:
        if part.name == "TableTop":
            part.mesh.apply_translation([0.0, 0.0, -thickness])
    ext = (rng.uniform(0.36, 0.46), rng.uniform(0.28, 0.36), thickness)
    cloth = shapes.box(ext, center=(0.0, 0.0, -thickness / 2))
    cloth.apply_transform(
        se3.make_pose(se3.rotation_about([0, 0, 1], rng.uniform(-0.4, 0.4)), [*rng.uniform(-0.03, 0.03, 2), 0.0])
    )
    parts.append(_Part("Cloth", cloth, texture=textures.felt(rng), uv=_planar_uv(cloth.vertices, (0, 1), 0.3)))
    hue = colorsys.rgb_to_hsv(*np.clip(np.asarray(objects[-1].part.color_linear) ** (1 / 2.2), 0, 1))[0]
    for part in parts:
        if part.name.startswith("Clutter"):
            h = (hue + rng.uniform(-0.05, 0.05)) % 1.0
            rgb = colorsys.hsv_to_rgb(h, rng.uniform(0.5, 0.9), rng.uniform(0.45, 0.9))
            part.color_linear = tuple(srgb_to_linear(np.array(rgb)).tolist())
    for obj in objects:
        obj.specular = False  # a printed paper label covers most of a can: the sensor sees it
        mesh = obj.spec.mesh.subdivide_to_size(0.002, max_iter=12)
        obj.spec = dataclasses.replace(obj.spec, mesh=mesh)
        obj.part.mesh = mesh
        obj.part.vertex_colors = textures.object_colors(mesh.vertices, obj.spec.shape.value, obj.part.color_linear, rng)
        obj.part.color_linear = tuple(float(c) for c in obj.part.vertex_colors.mean(axis=0))
    return parts


def generate_case(config: GenerateConfig, out_dir: str | Path, *, overwrite: bool = False) -> Path:
    """Write one synthetic case to ``out_dir`` (created; must not exist unless ``overwrite``)."""
    if config.n_frames < 10:
        raise ConfigError(f"{config.n_frames} frames are too few to stage a task", hint="generate at least 10 frames")
    if min(config.width, config.height) < 32:
        raise ConfigError(f"{config.width}x{config.height} is too small", hint="generate at least 32x32 pixels")
    out_dir = Path(out_dir)
    if out_dir.exists():
        if not overwrite:
            raise InputError("output folder exists", path=out_dir, hint="pass --overwrite or choose a new folder")
        shutil.rmtree(out_dir)
    tmp_dir = out_dir.with_name(f".{out_dir.name}.partial")
    shutil.rmtree(tmp_dir, ignore_errors=True)
    tmp_dir.mkdir(parents=True)
    rng = np.random.default_rng(config.seed)
    n, W, H = config.n_frames, config.width, config.height
    gt_dir = tmp_dir / "gt"

    parts, layout = _static_scene(rng, keep_clear_m=0.36)
    lighting = _lighting(rng)
    K = _intrinsics(rng, W, H)
    table = {"table_center": layout["table_center"], "table_half_extent": layout["table_half_extent"]}

    # ---------------------------------------------------------------- objects and their motion
    objects: list[_Object] = []
    if config.task is Task.UNSTACK:
        base = _make_object(rng, shapes.ObjectShape.BOX, "Base", 1)
        ext = (rng.uniform(0.10, 0.14), rng.uniform(0.10, 0.14), rng.uniform(0.05, 0.08))
        base.spec = shapes.ShapeSpec(shapes.ObjectShape.BOX, shapes.box(ext, center=(0.0, 0.0, ext[2] / 2)), ext)
        base.part.mesh = base.spec.mesh
        base_pose = se3.make_pose(se3.rotation_about([0, 0, 1], rng.uniform(-np.pi, np.pi)), [0.0, 0.0, 0.0])
        base.poses = np.repeat(base_pose[None], n, axis=0)
        top = _make_object(rng, config.shape, "Top", 2)
        top_start = se3.make_pose(se3.rotation_about([0, 0, 1], rng.uniform(-np.pi, np.pi)), [0.0, 0.0, ext[2]])
        motion = task_motion(
            config.task,
            n,
            top_start,
            top.spec.size_m,
            rng,
            support=(np.zeros(2), 0.5 * float(np.hypot(ext[0], ext[1]))),
            **table,
        )
        top.poses = motion.world_from_object
        objects = [base, top]
        manipulated = top
    else:
        obj = _make_object(rng, config.shape, config.shape.value.capitalize(), 1)
        start = se3.make_pose(se3.rotation_about([0, 0, 1], rng.uniform(-np.pi, np.pi)), [0.0, 0.0, 0.0])
        if config.lying or config.shape is shapes.ObjectShape.PEN:
            start[:3, :3] = start[:3, :3] @ _lying_rotation(obj.spec.mesh, rng)
            start[2, 3] = -float((obj.spec.mesh.vertices @ start[:3, :3].T)[:, 2].min())
        motion = task_motion(config.task, n, start, obj.spec.size_m, rng, **table)
        obj.poses = motion.world_from_object
        objects = [obj]
        manipulated = obj
    if config.realistic:
        parts = _realistic_scene(parts, objects, rng)
        contact = motion.world_from_object[phases(n).contact]
        hand_mesh, hand_colors = handmod.build_hand(
            manipulated.spec.mesh,
            motion.object_from_hand,
            contact[:3, :3].T @ np.array([0.0, 0.0, 1.0]),
            handmod.Grip.CLAW if config.task is Task.ROTATE else handmod.Grip.WRAP,
            handmod.sample_look(rng),
            rng,
            avoid=np.array([1.0, 0.0, 0.0]) if manipulated.spec.shape is shapes.ObjectShape.MUG else None,
        )
        hand_part = _Part(
            "Interactor",
            hand_mesh,
            color_linear=tuple(float(c) for c in hand_colors.mean(axis=0)),
            vertex_colors=hand_colors,
        )
    else:
        hand_part = _Part("Interactor", shapes.hand_proxy(), color_linear=SKIN_LINEAR)

    # camera: looks at the middle of the manipulated object's path, from a hand-held path
    path_center = manipulated.poses[:, :3, 3].mean(axis=0) + np.array([0.0, 0.0, 0.5 * manipulated.spec.size_m[2]])
    cam_poses = handheld_camera(
        n,
        path_center,
        rng,
        fps=config.fps,
        distance_m=(0.55, 0.85),
        elevation_deg=(28.0, 50.0),
        sweep_deg=float(rng.uniform(8.0, 20.0)),
        shake_m=float(rng.uniform(0.002, 0.004)),
        shake_deg=float(rng.uniform(0.3, 0.6)),
    )
    if config.static_camera:
        cam_poses = np.repeat(cam_poses[n // 2][None], n, axis=0)

    # the hand reaches in from above and from the far side of the objects, not past the camera
    away = manipulated.poses[0, :3, 3] - cam_poses[:, :3, 3].mean(axis=0)
    away[2] = 0.0
    approach = 0.5 * away / max(float(np.linalg.norm(away)), 1e-9) + np.array([0.0, 0.0, 1.0])
    hand_poses = hand_trajectory(dataclasses.replace(motion, approach_dir=approach / np.linalg.norm(approach)), n)

    # ---------------------------------------------------------------- ground truth files
    items = []
    part_entries = []
    for part in parts:
        rel = f"meshes/{part.name}.obj"
        appearance, tex_path = _write_part(gt_dir, rel, part)
        part_entries.append(gtfmt.part_json(part.name, rel, appearance))
        items.append(RenderItem(part.name, _mesh_data(part, tex_path), moves=False))
    timestamps = np.arange(n) / config.fps
    object_entries = []
    for obj in objects:
        rel = f"objects/{obj.name}.obj"
        appearance, _ = _write_part(gt_dir, rel, obj.part)
        items.append(RenderItem(obj.name, _mesh_data(obj.part, None), label=obj.label, pose=obj.poses[0]))
        write_tum(gt_dir / f"objects/{obj.name}.tum", timestamps, obj.poses, header=f"world_from_object of {obj.name}")
        truth = gtfmt.GtObject(
            name=obj.name,
            category=obj.category,
            mesh=rel,
            trajectory=f"objects/{obj.name}.tum",
            appearance=appearance,
            density_kg_m3=obj.density,
            friction=obj.friction,
            restitution=obj.restitution,
            hollow=PRIORS[obj.category].hollow,
            shell_thickness_m=PRIORS[obj.category].shell_thickness_m,
        )
        mp = mass_properties(obj.spec.mesh.vertices, obj.spec.mesh.faces, obj.density)
        object_entries.append(
            dict(
                gtfmt.object_json(truth),
                mass_kg=mp.mass_kg,
                size_m=list(obj.spec.size_m),
                specular=obj.specular,
                label=obj.label,
            )
        )
    hand_appearance, _ = _write_part(gt_dir, "interactor.obj", hand_part)
    # the plain interactor proxy casts no shadow: the reconstruction does not contain the hand,
    # and a shadow of it is not something a perfect reconstruction could reproduce, so it would
    # only blur what the SSIM gate measures; a realistic case's hand casts one, as a real hand does
    items.append(
        RenderItem(
            "Interactor",
            _mesh_data(hand_part, None),
            label=INTERACTOR_LABEL,
            pose=hand_poses[0],
            casts_shadow=config.realistic,
        )
    )
    write_tum(gt_dir / "camera.tum", timestamps, cam_poses, header="world_from_camera, OpenCV camera axes")
    write_tum(gt_dir / "interactor.tum", timestamps, hand_poses, header="world_from_interactor")
    np.savetxt(gt_dir / "K.txt", K, fmt="%.9f")
    np.savetxt(tmp_dir / "cam_K.txt", K, fmt="%.9f")
    np.savetxt(
        gt_dir / "gravity.txt",
        np.array([[0.0, 0.0, -1.0]]),
        fmt="%.9f",
        header="unit gravity (down) direction in the world frame",
    )
    color_from_depth = sample_depth_extrinsic(rng)
    gtfmt.write_manifest(
        gt_dir,
        {
            "generator": {
                "version": GENERATOR_VERSION,
                "task": config.task.value,
                "shape": config.shape.value,
                "seed": config.seed,
                "spp": config.spp,
                **(
                    {"realistic": True, "static_camera": config.static_camera, "lying": config.lying}
                    if config.realistic or config.static_camera or config.lying
                    else {}
                ),
                "color_from_depth_camera": color_from_depth.tolist(),
            },
            "fps": config.fps,
            "width": W,
            "height": H,
            "n_frames": n,
            "K": K.tolist(),
            "camera": "camera.tum",
            "gravity_direction": [0.0, 0.0, -1.0],
            "gravity_magnitude": 9.81,
            "lighting": lighting.to_json(),
            "layout": {k: list(v) if isinstance(v, tuple) else v for k, v in layout.items()},
            "parts": part_entries,
            "objects": object_entries,
            "interactor": gtfmt.interactor_json(
                gtfmt.GtInteractor("interactor.obj", "interactor.tum", hand_appearance)
            ),
            "depth": "depth",
            "interactor_label": INTERACTOR_LABEL,
        },
    )

    # ---------------------------------------------------------------- render
    scene = RenderScene(items, lighting)
    specular = frozenset(obj.label for obj in objects if obj.specular)
    first_box: dict[str, tuple[int, list[int]]] = {}
    visible = {obj.name: 0 for obj in objects}
    for t in progress(range(n), "render", total=n):
        for obj in objects:
            scene.set_pose(obj.name, obj.poses[t])
        scene.set_pose("Interactor", hand_poses[t])
        rgb = scene.render_srgb8(cam_poses[t], K, W, H, spp=config.spp, seed=t)
        surface = scene.surface(cam_poses[t], K, W, H)
        seen_by_sensor = scene.surface(cam_poses[t] @ color_from_depth, K, W, H, with_albedo=True)
        stem = f"{t:06d}"
        images.write_rgb(tmp_dir / "rgb" / f"{stem}.png", rgb)
        images.write_depth_mm(gt_dir / "depth" / f"{stem}.png", surface.depth)
        images.write_depth_mm(
            tmp_dir / "depth" / f"{stem}.png", sensor_depth(seen_by_sensor, rng, specular_labels=specular)
        )
        for obj in objects:
            mask = surface.labels == obj.label
            images.write_mask(gt_dir / "masks" / obj.name / f"{stem}.png", mask)
            if mask.any():
                visible[obj.name] += 1
                if obj.name not in first_box:
                    ys, xs = np.nonzero(mask)
                    first_box[obj.name] = (t, [int(xs.min()), int(ys.min()), int(xs.max()) + 1, int(ys.max()) + 1])
        images.write_mask(gt_dir / "masks" / "interactor" / f"{stem}.png", surface.labels == INTERACTOR_LABEL)
    missing = [obj.name for obj in objects if obj.name not in first_box]
    if missing:
        raise RuntimeError(f"generator bug: object(s) {missing} never visible (seed {config.seed})")

    toml = [
        f"# synthetic case: task {config.task.value}, shape {config.shape.value}, seed {config.seed}",
        f"fps = {config.fps:g}",
        "",
    ]
    for obj in objects:
        frame, box = first_box[obj.name]
        toml += [
            "[[objects]]",
            f'name = "{obj.name}"',
            f'category = "{obj.category}"',
            f"prompt = {{ frame = {frame}, box = [{box[0]}, {box[1]}, {box[2]}, {box[3]}] }}",
            "",
        ]
    (tmp_dir / "rose.toml").write_text("\n".join(toml))
    tmp_dir.rename(out_dir)
    seen = ", ".join(f"{k} visible in {v} frames" for k, v in visible.items())
    say(f"wrote {out_dir} ({config.task.value}, {n} frames {W}x{H}, {seen})")
    return out_dir
