"""Generate one seeded synthetic case: a tabletop room, a target object moved by a hand proxy,
filmed by a hand-held camera, rendered with Mitsuba (RGB, metric depth, object and interactor
masks) and written in the case layout with full ground truth (rose_usd.case.gt).
"""

from __future__ import annotations

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
from rose_usd.synth import shapes, textures
from rose_usd.synth.motion import Task, hand_trajectory, handheld_camera, task_motion
from rose_usd.usd.geom import MeshData

OBJECT_LABEL = 1
INTERACTOR_LABEL = 2
SKIN_LINEAR = tuple(srgb_to_linear(np.array([224, 172, 140]) / 255.0).tolist())


@dataclass(frozen=True)
class GenerateConfig:
    """What to generate."""

    task: Task = Task.PUSH
    """Manipulation task staged in the video."""
    shape: shapes.ObjectShape = shapes.ObjectShape.BOX
    """Target object shape."""
    seed: int = 0
    """Seed of every random choice (scene, object, motion, camera)."""
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


@dataclass
class _Part:
    name: str
    mesh: trimesh.Trimesh
    color_linear: tuple[float, float, float] | None = None
    texture: np.ndarray | None = None
    uv: np.ndarray | None = None


def _planar_uv(vertices: np.ndarray, axes: tuple[int, int], meters_per_tile: float) -> np.ndarray:
    return np.stack([vertices[:, axes[0]], vertices[:, axes[1]]], axis=1) / meters_per_tile


def _random_color(rng: np.random.Generator, *, saturated: bool) -> tuple[float, float, float]:
    import colorsys

    h = rng.uniform(0, 1)
    s = rng.uniform(0.55, 0.9) if saturated else rng.uniform(0.05, 0.3)
    v = rng.uniform(0.55, 0.9)
    return tuple(srgb_to_linear(np.array(colorsys.hsv_to_rgb(h, s, v))).tolist())


def _static_scene(rng: np.random.Generator) -> tuple[list[_Part], dict]:
    """Table (top at z = 0), legs, floor, four walls, clutter. Returns parts and layout facts."""
    parts: list[_Part] = []
    top_x, top_y = rng.uniform(1.0, 1.3), rng.uniform(0.7, 0.9)
    thickness = 0.04
    height = rng.uniform(0.72, 0.78)
    cx, cy = rng.uniform(-0.12, 0.12), rng.uniform(-0.08, 0.08)  # table center (the object is at the origin)
    top = shapes.box((top_x, top_y, thickness), center=(cx, cy, -thickness / 2))
    parts.append(_Part("TableTop", top, texture=textures.wood(rng), uv=_planar_uv(top.vertices, (0, 1), 0.6)))
    leg_color = tuple(srgb_to_linear(np.array([60, 48, 40]) / 255.0).tolist())
    legs = []
    for sx in (-1, 1):
        for sy in (-1, 1):
            legs.append(shapes.box((0.05, 0.05, height - thickness), center=(cx + sx * (top_x / 2 - 0.06), cy + sy * (top_y / 2 - 0.06), -thickness - (height - thickness) / 2)))
    parts.append(_Part("TableLegs", trimesh.util.concatenate(legs), color_linear=leg_color))
    room = 5.0
    floor = shapes.box((room, room, 0.05), center=(cx, cy, -height - 0.025))
    parts.append(_Part("Floor", floor, texture=textures.tiles(rng), uv=_planar_uv(floor.vertices, (0, 1), 1.2)))
    wall_tex = textures.plaster(rng)
    wall_h = 2.6
    for i, (dx, dy, ex, ey) in enumerate(((room / 2, 0, 0.1, room), (-room / 2, 0, 0.1, room), (0, room / 2, room, 0.1), (0, -room / 2, room, 0.1))):
        wall = shapes.box((ex, ey, wall_h), center=(cx + dx, cy + dy, -height + wall_h / 2))
        axes = (1, 2) if ex < ey else (0, 2)
        parts.append(_Part(f"Wall{i}", wall, texture=wall_tex, uv=_planar_uv(wall.vertices, axes, 1.5)))
    # clutter on the table, away from the object's workspace around the origin
    n_clutter = int(rng.integers(2, 4))
    placed: list[tuple[float, float, float]] = []
    for k in range(n_clutter):
        for _ in range(200):
            x = rng.uniform(cx - top_x / 2 + 0.1, cx + top_x / 2 - 0.1)
            y = rng.uniform(cy - top_y / 2 + 0.1, cy + top_y / 2 - 0.1)
            if np.hypot(x, y) > 0.32 and all(np.hypot(x - px, y - py) > pr + 0.1 for px, py, pr in placed):
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
    return parts, {"table_center": (cx, cy), "table_half_extent": (top_x / 2, top_y / 2), "table_height": height}


def _lighting(rng: np.random.Generator) -> Lighting:
    ambient = rng.uniform(0.35, 0.5)
    az = rng.uniform(-np.pi, np.pi)
    pos = np.array([0.8 * np.cos(az), 0.8 * np.sin(az), rng.uniform(1.3, 1.8)])
    irradiance = rng.uniform(0.5, 0.7)  # at the object, facing the light
    intensity = irradiance * float(pos @ pos)
    warm = np.array([1.0, rng.uniform(0.93, 1.0), rng.uniform(0.85, 0.97)])
    return Lighting(ambient=(ambient,) * 3, points=(PointLight(tuple(pos.tolist()), tuple((intensity * warm).tolist())),))


def _intrinsics(rng: np.random.Generator, width: int, height: int) -> np.ndarray:
    hfov = np.radians(rng.uniform(58.0, 66.0))
    f = width / (2.0 * np.tan(hfov / 2.0))
    return np.array([[f, 0.0, (width - 1) / 2.0 + rng.uniform(-2, 2)], [0.0, f, (height - 1) / 2.0 + rng.uniform(-2, 2)], [0.0, 0.0, 1.0]])


def _mesh_data(part: _Part, texture_path: Path | None) -> MeshData:
    return MeshData(
        vertices=np.asarray(part.mesh.vertices, dtype=float),
        faces=np.asarray(part.mesh.faces, dtype=np.int64),
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
    write_obj(gt_dir / rel_mesh, part.mesh.vertices, part.mesh.faces, uv=part.uv if part.texture is not None else None,
              color_linear=part.color_linear, texture_file=Path(texture_rel).name if texture_rel else None)
    return gtfmt.Appearance(part.color_linear, texture_rel), texture_path


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

    parts, layout = _static_scene(rng)
    lighting = _lighting(rng)
    K = _intrinsics(rng, W, H)

    # the target object, resting at the origin with a random yaw
    spec = shapes.sample_object(config.shape, rng)
    category = shapes.SHAPE_CATEGORY[config.shape]
    prior = PRIORS[category]
    name = config.shape.value.capitalize()
    start = se3.make_pose(se3.rotation_about([0, 0, 1], rng.uniform(-np.pi, np.pi)), [0.0, 0.0, 0.0])
    motion = task_motion(config.task, n, start, spec.size_m, rng, table_half_extent=layout["table_half_extent"])
    hand_poses = hand_trajectory(motion, n)
    density = float(rng.uniform(*prior.density_range_kg_m3))
    obj_part = _Part(name, spec.mesh, color_linear=_random_color(rng, saturated=True))
    hand_part = _Part("Interactor", shapes.hand_proxy(), color_linear=SKIN_LINEAR)

    # camera: looks at the middle of the object's path, from a hand-held path
    path_center = motion.world_from_object[:, :3, 3].mean(axis=0) + np.array([0.0, 0.0, 0.5 * spec.size_m[2]])
    cam_poses = handheld_camera(n, path_center, rng, fps=config.fps)

    # ---------------------------------------------------------------- ground truth files
    items = []
    part_entries = []
    for part in parts:
        rel = f"meshes/{part.name}.obj"
        appearance, tex_path = _write_part(gt_dir, rel, part)
        part_entries.append(gtfmt.part_json(part.name, rel, appearance))
        items.append(RenderItem(part.name, _mesh_data(part, tex_path)))
    obj_rel = f"objects/{name}.obj"
    obj_appearance, _ = _write_part(gt_dir, obj_rel, obj_part)
    items.append(RenderItem(name, _mesh_data(obj_part, None), label=OBJECT_LABEL, pose=motion.world_from_object[0]))
    hand_appearance, _ = _write_part(gt_dir, "interactor.obj", hand_part)
    items.append(RenderItem("Interactor", _mesh_data(hand_part, None), label=INTERACTOR_LABEL, pose=hand_poses[0]))

    timestamps = np.arange(n) / config.fps
    write_tum(gt_dir / "camera.tum", timestamps, cam_poses, header="world_from_camera, OpenCV camera axes")
    write_tum(gt_dir / f"objects/{name}.tum", timestamps, motion.world_from_object, header=f"world_from_object of {name}")
    write_tum(gt_dir / "interactor.tum", timestamps, hand_poses, header="world_from_interactor")
    np.savetxt(gt_dir / "K.txt", K, fmt="%.9f")
    np.savetxt(tmp_dir / "cam_K.txt", K, fmt="%.9f")
    np.savetxt(gt_dir / "gravity.txt", np.array([[0.0, 0.0, -1.0]]), fmt="%.9f", header="unit gravity (down) direction in the world frame")
    mp = mass_properties(spec.mesh.vertices, spec.mesh.faces, density)
    gt_object = gtfmt.GtObject(
        name=name,
        category=category,
        mesh=obj_rel,
        trajectory=f"objects/{name}.tum",
        appearance=obj_appearance,
        density_kg_m3=density,
        friction=float(np.clip(rng.normal(prior.friction, prior.friction_sigma / 2), 0.2, 1.0)),
        restitution=float(np.clip(rng.normal(prior.restitution, prior.restitution_sigma / 2), 0.0, 0.8)),
        hollow=prior.hollow,
        shell_thickness_m=prior.shell_thickness_m,
    )
    gtfmt.write_manifest(
        gt_dir,
        {
            "generator": {"task": config.task.value, "shape": config.shape.value, "seed": config.seed, "spp": config.spp},
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
            "objects": [dict(gtfmt.object_json(gt_object), mass_kg=mp.mass_kg, size_m=list(spec.size_m))],
            "interactor": gtfmt.interactor_json(gtfmt.GtInteractor("interactor.obj", "interactor.tum", hand_appearance)),
        },
    )

    # ---------------------------------------------------------------- render
    scene = RenderScene(items, lighting)
    first_box = None
    visible = np.zeros(n, dtype=int)
    for t in progress(range(n), "render", total=n):
        scene.set_pose(name, motion.world_from_object[t])
        scene.set_pose("Interactor", hand_poses[t])
        rgb = scene.render_srgb8(cam_poses[t], K, W, H, spp=config.spp, seed=t)
        depth, labels = scene.depth_and_labels(cam_poses[t], K, W, H)
        stem = f"{t:06d}"
        images.write_rgb(tmp_dir / "rgb" / f"{stem}.png", rgb)
        images.write_depth_mm(tmp_dir / "depth" / f"{stem}.png", depth)
        obj_mask = labels == OBJECT_LABEL
        images.write_mask(gt_dir / "masks" / name / f"{stem}.png", obj_mask)
        images.write_mask(gt_dir / "masks" / "interactor" / f"{stem}.png", labels == INTERACTOR_LABEL)
        visible[t] = int(obj_mask.sum())
        if first_box is None and obj_mask.any():
            ys, xs = np.nonzero(obj_mask)
            first_box = (t, [int(xs.min()), int(ys.min()), int(xs.max()) + 1, int(ys.max()) + 1])
    if first_box is None:
        raise RuntimeError(f"generator bug: the object is never visible (seed {config.seed})")

    prompt_frame, box = first_box
    (tmp_dir / "rose.toml").write_text(
        f"# synthetic case: task {config.task.value}, shape {config.shape.value}, seed {config.seed}\n"
        f"fps = {config.fps:g}\n\n[[objects]]\nname = \"{name}\"\ncategory = \"{category}\"\n"
        f"prompt = {{ frame = {prompt_frame}, box = [{box[0]}, {box[1]}, {box[2]}, {box[3]}] }}\n"
    )
    tmp_dir.rename(out_dir)
    say(f"wrote {out_dir} ({n} frames {W}x{H}, object visible in {int((visible > 0).sum())} frames)")
    return out_dir
