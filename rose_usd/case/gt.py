"""Ground truth of a benchmark case (``<case>/gt/``), read only by ``oracle`` backends and metrics.

Layout (all in the contract's world frame: +Z up, meters, origin on the support surface under the
object at frame 0)::

    gt/scene.json            manifest: timing, K, gravity, lighting, parts, objects, interactor
    gt/K.txt                 3x3 intrinsics [px]
    gt/gravity.txt           unit gravity (down) vector in the world frame
    gt/camera.tum            world_from_camera (OpenCV axes), TUM format
    gt/meshes/<part>.obj     static scene parts in world coordinates (+ .mtl, texture .png)
    gt/objects/<Name>.obj    object meshes in the object frame (origin at the resting face's center)
    gt/objects/<Name>.tum    world_from_object, TUM format
    gt/interactor.obj/.tum   the interactor proxy and its poses
    gt/masks/<Name>/NNNNNN.png, gt/masks/interactor/NNNNNN.png   8-bit masks (255 = visible)
    gt/depth/NNNNNN.png      clean metric depth, uint16 millimeters (the case's depth/ is a sensor's)

Colors in scene.json are linear RGB; textures are sRGB PNGs with per-vertex UVs in the OBJ.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rose_usd.errors import InputError
from rose_usd.io.meshfile import read_mesh_file
from rose_usd.io.tum import read_tum
from rose_usd.usd.geom import MeshData

GT_VERSION = 1


@dataclass(frozen=True)
class Appearance:
    color_linear: tuple[float, float, float] | None
    texture: str | None
    """Texture path relative to gt/, or None."""


@dataclass(frozen=True)
class GtPart:
    name: str
    mesh: str
    appearance: Appearance


@dataclass(frozen=True)
class GtObject:
    name: str
    category: str
    mesh: str
    trajectory: str
    appearance: Appearance
    density_kg_m3: float
    friction: float
    restitution: float
    hollow: bool
    shell_thickness_m: float


@dataclass(frozen=True)
class GtInteractor:
    mesh: str
    trajectory: str
    appearance: Appearance


def _appearance(d: dict) -> Appearance:
    color = d.get("color_linear")
    return Appearance(tuple(float(c) for c in color) if color is not None else None, d.get("texture"))


def _appearance_json(a: Appearance) -> dict:
    return {"color_linear": list(a.color_linear) if a.color_linear is not None else None, "texture": a.texture}


class GroundTruth:
    """Read access to ``<case>/gt``; validates the manifest when opened."""

    def __init__(self, root: Path):
        self.root = Path(root)
        manifest = self.root / "scene.json"
        if not manifest.is_file():
            raise InputError(
                "case has no ground truth (gt/scene.json)",
                path=self.root,
                hint="oracle backends need a benchmark case; choose another backend with --backend STAGE=NAME",
            )
        try:
            data = json.loads(manifest.read_text())
        except json.JSONDecodeError as exc:
            raise InputError(
                f"not valid JSON ({exc})", path=manifest, hint="regenerate the case with rose-usd bench generate"
            ) from None
        if data.get("version") != GT_VERSION:
            raise InputError(
                f"ground-truth version {data.get('version')} is not {GT_VERSION}",
                path=manifest,
                hint="regenerate the case",
            )
        self.data = data
        self.fps = float(data["fps"])
        self.width, self.height = int(data["width"]), int(data["height"])
        self.n_frames = int(data["n_frames"])
        self.K = np.asarray(data["K"], dtype=float)
        self.gravity = np.asarray(data["gravity_direction"], dtype=float)
        self.lighting = data["lighting"]
        self.parts = [GtPart(p["name"], p["mesh"], _appearance(p)) for p in data["parts"]]
        self.objects = [
            GtObject(
                name=o["name"],
                category=o["category"],
                mesh=o["mesh"],
                trajectory=o["trajectory"],
                appearance=_appearance(o),
                density_kg_m3=float(o["density_kg_m3"]),
                friction=float(o["friction"]),
                restitution=float(o["restitution"]),
                hollow=bool(o["hollow"]),
                shell_thickness_m=float(o["shell_thickness_m"]),
            )
            for o in data["objects"]
        ]
        inter = data.get("interactor")
        self.interactor = GtInteractor(inter["mesh"], inter["trajectory"], _appearance(inter)) if inter else None

    # ------------------------------------------------------------------ poses
    def _poses(self, rel: str) -> np.ndarray:
        _, poses = read_tum(self.root / rel)
        if len(poses) != self.n_frames:
            raise InputError(
                f"has {len(poses)} poses, expected {self.n_frames}", path=self.root / rel, hint="regenerate the case"
            )
        return poses

    def camera_poses(self) -> np.ndarray:
        """world_from_camera (OpenCV) per frame, (N, 4, 4)."""
        return self._poses(self.data["camera"])

    def object(self, name: str) -> GtObject:
        for obj in self.objects:
            if obj.name == name:
                return obj
        raise InputError(
            f"no object named {name!r} in the ground truth",
            path=self.root / "scene.json",
            hint="check the object names in rose.toml",
        )

    def object_poses(self, name: str) -> np.ndarray:
        """world_from_object per frame, (N, 4, 4)."""
        return self._poses(self.object(name).trajectory)

    def interactor_poses(self) -> np.ndarray:
        return self._poses(self.interactor.trajectory)

    # ------------------------------------------------------------------ meshes
    def mesh(self, rel: str, appearance: Appearance) -> MeshData:
        tm = read_mesh_file(self.root / rel)
        uv = None
        texture = None
        if appearance.texture is not None:
            uv = np.asarray(tm.visual.uv, dtype=float)
            texture = self.root / appearance.texture
        return MeshData(
            vertices=np.asarray(tm.vertices, dtype=float),
            faces=np.asarray(tm.faces, dtype=np.int64),
            color=appearance.color_linear,
            uv=uv,
            texture=texture,
        )

    def part_mesh(self, part: GtPart) -> MeshData:
        return self.mesh(part.mesh, part.appearance)

    def object_mesh(self, name: str) -> MeshData:
        obj = self.object(name)
        return self.mesh(obj.mesh, obj.appearance)

    @property
    def depth_dir(self) -> Path:
        """Folder of clean depth maps (uint16 mm), one per frame."""
        return self.root / self.data.get("depth", "depth")

    def mask_dir(self, name: str) -> Path:
        """Folder of ground-truth masks of an object name or ``"interactor"``."""
        return self.root / "masks" / name


def write_manifest(root: Path, manifest: dict) -> None:
    """Write gt/scene.json (the generator's side)."""
    manifest = dict(manifest, version=GT_VERSION)
    (Path(root) / "scene.json").write_text(json.dumps(manifest, indent=2) + "\n")


def part_json(name: str, mesh: str, appearance: Appearance) -> dict:
    return {"name": name, "mesh": mesh, **_appearance_json(appearance)}


def object_json(obj: GtObject) -> dict:
    return {
        "name": obj.name,
        "category": obj.category,
        "mesh": obj.mesh,
        "trajectory": obj.trajectory,
        **_appearance_json(obj.appearance),
        "density_kg_m3": obj.density_kg_m3,
        "friction": obj.friction,
        "restitution": obj.restitution,
        "hollow": obj.hollow,
        "shell_thickness_m": obj.shell_thickness_m,
    }


def interactor_json(inter: GtInteractor) -> dict:
    return {"mesh": inter.mesh, "trajectory": inter.trajectory, **_appearance_json(inter.appearance)}
