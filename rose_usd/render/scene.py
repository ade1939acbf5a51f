"""A Mitsuba scene of triangle meshes, point lights and an ambient term, rendered from OpenCV cameras.

Shading model (documented in README "Rendering"): Lambertian surfaces lit by an ambient term (no
occlusion) plus point lights with hard shadows,

    L = albedo * (ambient + sum_k I_k * max(0, n . l_k) * V_k / r_k^2),

evaluated by Mitsuba's ray tracer and BSDF textures in a small custom integrator. It is exact per
sample (no Monte Carlo noise except pixel anti-aliasing), so the SSIM gate measures the geometry,
cameras and colors, not the renderer's noise. A mesh whose colors were baked from the video is
rendered with ``Lighting.unlit()`` (ambient 1, no lights): radiance = its baked color.
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass, field

import numpy as np

from rose_usd.core import se3
from rose_usd.core.color import linear_to_srgb8
from rose_usd.errors import EnvironmentProblem
from rose_usd.render.lighting import Lighting
from rose_usd.render.variant import mitsuba
from rose_usd.usd.geom import MeshData

# Mitsuba cameras look down +Z with +Y up and +X left: an OpenCV camera with x and y flipped.
_CV_TO_MITSUBA = np.diag([-1.0, -1.0, 1.0, 1.0])


@dataclass
class RenderItem:
    """One mesh to render. Vertices are in the item's local frame; ``pose`` places it in the world."""

    name: str
    mesh: MeshData
    label: int = 0
    """Value this mesh gets in label images (0 = background)."""
    pose: np.ndarray = field(default_factory=lambda: np.eye(4))
    """world_from_local (4, 4)."""
    casts_shadow: bool = True
    """Whether the item blocks the point lights (the benchmark's interactor proxy does not)."""
    moves: bool = True
    """Whether ``set_poses`` may move it. Items that never move are kept in a scene of their own,
    whose ray-tracing hierarchy re-posing the others does not rebuild."""


def _make_integrator_class(mi, dr):
    class RoseDirect(mi.SamplingIntegrator):
        """Ambient + point lights with hard shadows on Lambertian BSDFs (see module docstring)."""

        def __init__(self, props=mi.Properties()):
            super().__init__(props)
            self.ambient = mi.Color3f(1.0)
            self.lights: list[tuple] = []
            self.shadow_scene = None  # the scene shadow rays test (items that cast shadows)
            self.moving_scene = None  # the items that move, beside the scene rendered (``nearest``)
            self.coverage: list[tuple[int, list]] = []  # (label, its shapes): one AOV each while set

        def configure(self, lighting: Lighting) -> None:
            self.ambient = mi.Color3f(*lighting.ambient)
            self.lights = [(mi.Point3f(*p.position_m), mi.Color3f(*p.intensity)) for p in lighting.points]

        def nearest(self, scene, ray, active=True):
            """The nearest hit of the ray in ``scene`` or in the moving items' scene."""
            si = scene.ray_intersect(ray, active)
            if self.moving_scene is None:
                return si
            si_moving = self.moving_scene.ray_intersect(ray, active)
            nearer = si_moving.is_valid() & (~si.is_valid() | (si_moving.t < si.t))
            return dr.select(nearer, si_moving, si)

        def occluded(self, scene, ray, active):
            if self.shadow_scene is not None:
                return self.shadow_scene.ray_test(ray, active)
            hit = scene.ray_test(ray, active)
            return hit if self.moving_scene is None else hit | self.moving_scene.ray_test(ray, active)

        def sample(self, scene, sampler, ray, medium=None, active=True):
            si = self.nearest(scene, ray, active)
            valid = active & si.is_valid()
            bsdf = si.bsdf(ray)
            albedo = bsdf.eval_diffuse_reflectance(si, valid)
            n = si.sh_frame.n
            n = dr.select(dr.dot(n, -ray.d) < 0, -n, n)  # two-sided
            radiance = albedo * self.ambient
            for position, intensity in self.lights:
                to_light = position - si.p
                dist2 = dr.squared_norm(to_light)
                cos = dr.maximum(dr.dot(n, to_light * dr.rsqrt(dist2)), 0.0)
                lit = valid & (cos > 0)
                visible = lit & ~self.occluded(scene, si.spawn_ray_to(position), lit)
                radiance += dr.select(visible, albedo * intensity * cos / dist2, 0.0)
            covered = []
            for _, shapes in self.coverage:
                hit = dr.zeros(mi.Bool, dr.width(valid))
                for shape in shapes:
                    hit |= valid & (si.shape == shape)
                covered.append(dr.select(hit, 1.0, 0.0))
            return dr.select(valid, radiance, 0.0), valid, covered

        def aov_names(self):
            return [f"label{label}" for label, _ in self.coverage]

        def to_string(self):
            return "RoseDirect[]"

    return RoseDirect


class RenderScene:
    """Meshes + lighting in Mitsuba; render RGB, depth and labels from OpenCV cameras."""

    def __init__(self, items: list[RenderItem], lighting: Lighting):
        self.mi = mi = mitsuba()
        import drjit as dr

        self.dr = dr
        self.variant = mi.variant()
        self.items = {item.name: item for item in items}
        if len(self.items) != len(items):
            raise ValueError("RenderScene: item names must be unique")
        # the items that never move in one scene, those that may in another, so that re-posing
        # them rebuilds only their own ray-tracing hierarchy; with only one kind, one scene
        fixed = [item for item in items if not item.moves]
        moving = [item for item in items if item.moves]
        self.scene = mi.load_dict(self._scene_dict(fixed or moving))
        self.moving_scene = mi.load_dict(self._scene_dict(moving)) if fixed and moving else None
        self.params = mi.traverse(self.moving_scene if self.moving_scene is not None else self.scene)
        self.integrator = _make_integrator_class(mi, dr)()
        self.integrator.moving_scene = self.moving_scene
        self.lighting = lighting
        self.integrator.configure(lighting)
        self.shadow_params = None
        if not all(item.casts_shadow for item in items):
            # shadow rays test a third scene holding only the items that cast shadows
            self.integrator.shadow_scene = mi.load_dict(self._scene_dict([it for it in items if it.casts_shadow]))
            self.shadow_params = mi.traverse(self.integrator.shadow_scene)
        scenes = [self.scene] if self.moving_scene is None else [self.scene, self.moving_scene]
        self._shapes = {shape.id(): shape for scene in scenes for shape in scene.shapes()}
        self._rays = None  # (camera model, pixel directions, z per unit length): see _pixel_rays

    # ------------------------------------------------------------------ building
    def _scene_dict(self, items: list[RenderItem]) -> dict:
        return {"type": "scene", **{item.name: self._mesh(item) for item in items}}

    def _mesh(self, item: RenderItem):
        mi, dr = self.mi, self.dr
        mesh = item.mesh
        props = mi.Properties()
        props["bsdf"] = mi.load_dict({"type": "diffuse", "reflectance": self._reflectance(mesh)})
        has_uv = mesh.uv is not None and mesh.texture is not None
        m = mi.Mesh(
            item.name,
            len(mesh.vertices),
            len(mesh.faces),
            props=props,
            has_vertex_normals=False,
            has_vertex_texcoords=has_uv,
        )
        p = mi.traverse(m)
        p["vertex_positions"] = dr.ravel(mi.Point3f(self._world_vertices(mesh.vertices, item.pose).T.copy()))
        p["faces"] = dr.ravel(mi.Vector3u(np.ascontiguousarray(mesh.faces, dtype=np.uint32).T.copy()))
        if has_uv:
            uv = np.asarray(mesh.uv, dtype=np.float32).copy()
            uv[:, 1] = 1.0 - uv[:, 1]  # USD st has its origin bottom-left, Mitsuba's uv top-left
            p["vertex_texcoords"] = dr.ravel(mi.Point2f(uv.T.copy()))
        p.update()
        if mesh.vertex_colors is not None:
            m.add_attribute("vertex_color", 3, np.ascontiguousarray(mesh.vertex_colors, dtype=np.float32).reshape(-1))
        return m

    def _reflectance(self, mesh: MeshData) -> dict:
        if mesh.texture is not None and mesh.uv is not None:
            return {"type": "bitmap", "filename": str(mesh.texture), "filter_type": "bilinear", "wrap_mode": "repeat"}
        if mesh.vertex_colors is not None:
            return {"type": "mesh_attribute", "name": "vertex_color"}
        return {"type": "rgb", "value": list(mesh.mean_color)}

    @staticmethod
    def _world_vertices(vertices: np.ndarray, pose: np.ndarray) -> np.ndarray:
        return se3.transform_points(pose, vertices).astype(np.float32)

    # ------------------------------------------------------------------ animation
    def set_pose(self, name: str, world_from_local: np.ndarray) -> None:
        """Move an item (its local vertices) to a new pose before the next render."""
        self.set_poses({name: world_from_local})

    def set_poses(self, poses: dict[str, np.ndarray]) -> None:
        """Move items to new poses (name -> world_from_local), rebuilding the scene once."""
        moved = False
        for name, world_from_local in poses.items():
            item = self.items[name]
            if np.array_equal(item.pose, world_from_local):
                continue
            if not item.moves:
                raise ValueError(f"RenderScene: item {name!r} was made with moves=False")
            item.pose = np.array(world_from_local, dtype=float)
            positions = self.dr.ravel(self.mi.Point3f(self._world_vertices(item.mesh.vertices, item.pose).T.copy()))
            self.params[f"{name}.vertex_positions"] = positions
            if self.shadow_params is not None and item.casts_shadow:
                self.shadow_params[f"{name}.vertex_positions"] = positions
            moved = True
        if moved:
            self.params.update()
            if self.shadow_params is not None:
                self.shadow_params.update()

    # ------------------------------------------------------------------ rendering
    def _sensor(self, world_from_cv: np.ndarray, K: np.ndarray, width: int, height: int, spp: int, window=None):
        """A square-pixel camera; ``window`` (x0, y0, x1, y1) crops its film to those pixels."""
        fx, cx, cy = K[0, 0], K[0, 2], K[1, 2]
        film = {
            "type": "hdrfilm",
            "width": int(width),
            "height": int(height),
            "rfilter": {"type": "box"},
            "pixel_format": "rgb",
        }
        if window is not None:
            x0, y0, x1, y1 = (int(v) for v in window)
            film.update(crop_offset_x=x0, crop_offset_y=y0, crop_width=x1 - x0, crop_height=y1 - y0)
        to_world = np.asarray(world_from_cv, dtype=float) @ _CV_TO_MITSUBA
        return self.mi.load_dict(
            {
                "type": "perspective",
                "fov_axis": "x",
                "fov": float(np.degrees(2.0 * np.arctan(width / (2.0 * fx)))),
                "principal_point_offset_x": float((width / 2.0 - (cx + 0.5)) / width),
                "principal_point_offset_y": float((height / 2.0 - (cy + 0.5)) / height),
                "near_clip": 0.005,
                "far_clip": 1000.0,
                "to_world": self.mi.ScalarTransform4f(to_world.tolist()),
                "film": film,
                "sampler": {"type": "multijitter", "sample_count": int(spp)},
            }
        )

    def render_linear(
        self, world_from_cv: np.ndarray, K: np.ndarray, width: int, height: int, *, spp: int = 8, seed: int = 0
    ) -> np.ndarray:
        """Linear RGB image (H, W, 3) float32 seen by an OpenCV camera."""
        return self._render(world_from_cv, K, width, height, spp, seed)[..., :3]

    def render_srgb8(
        self, world_from_cv: np.ndarray, K: np.ndarray, width: int, height: int, *, spp: int = 8, seed: int = 0
    ) -> np.ndarray:
        """8-bit sRGB image (H, W, 3) seen by an OpenCV camera."""
        return linear_to_srgb8(self.render_linear(world_from_cv, K, width, height, spp=spp, seed=seed))

    def render_srgb8_and_labels(
        self, world_from_cv: np.ndarray, K: np.ndarray, width: int, height: int, *, spp: int = 8, seed: int = 0
    ) -> tuple[np.ndarray, np.ndarray]:
        """The 8-bit sRGB image and, from the same samples, item labels (H, W) uint8: per pixel the
        label whose items cover the most of its samples, where they cover at least half (else 0).
        One pass: no second ray per pixel."""
        with self.covering() as labels:
            img = self._render(world_from_cv, K, width, height, spp, seed)
        return linear_to_srgb8(img[..., :3]), self.labels_of(img, labels)

    @contextlib.contextmanager
    def covering(self):
        """While open, renders also hold one coverage channel per item label (after RGB); yields
        the labels in channel order."""
        labels = sorted({item.label for item in self.items.values() if item.label})
        self.integrator.coverage = [
            (label, [self.mi.ShapePtr(self._shapes[n]) for n, item in self.items.items() if item.label == label])
            for label in labels
        ]
        try:
            yield labels
        finally:
            self.integrator.coverage = []

    @staticmethod
    def labels_of(img: np.ndarray, labels: list[int]) -> np.ndarray:
        """Per pixel of a render made while ``covering``: the label covering most of its samples
        where that is at least half of them, else 0."""
        out = np.zeros(img.shape[:2], np.uint8)
        if labels:
            coverage = img[..., 3 : 3 + len(labels)]
            best = np.argmax(coverage, axis=-1)
            covered = np.take_along_axis(coverage, best[..., None], axis=-1)[..., 0] >= 0.5
            out[covered] = np.asarray(labels, np.uint8)[best[covered]]
        return out

    @staticmethod
    def square_pixels(K: np.ndarray, height: int) -> tuple[np.ndarray, int]:
        """Mitsuba's perspective camera has square pixels: for fx != fy, the camera matrix and
        height of a square-pixel image of the same field of view (resampled to ``height`` after)."""
        K = np.asarray(K, dtype=float)
        fx, fy = K[0, 0], K[1, 1]
        if abs(fx - fy) <= 1e-4 * fx:
            return K, height
        render_h = max(1, int(round(height * fx / fy)))
        K_render = K.copy()
        K_render[1, 1] = fx
        K_render[1, 2] = (K[1, 2] + 0.5) * render_h / height - 0.5
        return K_render, render_h

    def render_film(
        self, world_from_cv: np.ndarray, K_render: np.ndarray, width: int, height: int, spp: int, seed: int, window=None
    ) -> np.ndarray:
        """Every channel of a square-pixel film (``square_pixels``), (H, W, C) float32, or of its
        ``window`` (x0, y0, x1, y1) alone."""
        sensor = self._sensor(world_from_cv, K_render, width, height, spp, window)
        return np.asarray(
            self.mi.render(self.scene, sensor=sensor, integrator=self.integrator, seed=seed, spp=spp), dtype=np.float32
        )

    @staticmethod
    def resampled(img: np.ndarray, width: int, height: int) -> np.ndarray:
        """A square-pixel film's channels at the requested size (unchanged when it has it)."""
        if img.shape[:2] == (height, width):
            return img
        import cv2

        interpolation = cv2.INTER_AREA if img.shape[0] > height else cv2.INTER_LINEAR
        # OpenCV resizes at most 4 channels at once
        return np.concatenate(
            [
                cv2.resize(img[..., i : i + 3], (width, height), interpolation=interpolation).reshape(height, width, -1)
                for i in range(0, img.shape[-1], 3)
            ],
            axis=-1,
        )

    def _render(
        self, world_from_cv: np.ndarray, K: np.ndarray, width: int, height: int, spp: int, seed: int
    ) -> np.ndarray:
        """Every channel the film holds (H, W, C) float32: linear RGB, then the coverage AOVs the
        integrator is asked for (``covering``)."""
        K_render, render_h = self.square_pixels(K, height)
        return self.resampled(self.render_film(world_from_cv, K_render, width, render_h, spp, seed), width, height)

    def depth_and_labels(
        self, world_from_cv: np.ndarray, K: np.ndarray, width: int, height: int
    ) -> tuple[np.ndarray, np.ndarray]:
        """Z-depth [m] (0 where nothing is hit) and item labels, both (H, W), from one ray per pixel
        center (OpenCV convention: pixel (u, v) centered at integer coordinates)."""
        surface = self.surface(world_from_cv, K, width, height)
        return surface.depth, surface.labels

    def surface(
        self, world_from_cv: np.ndarray, K: np.ndarray, width: int, height: int, *, with_albedo: bool = False
    ) -> "Surface":
        """What one ray per pixel center sees: z-depth, labels and (optionally) albedo and the
        cosine between the surface normal and the ray (for sensor models). One kernel computes
        them all (each buffer read on its own would trace the rays again), from pixel directions
        made once per camera model."""
        mi, dr = self.mi, self.dr
        if not self.variant.startswith(("llvm", "cuda")):
            raise EnvironmentProblem(
                f"depth rendering needs a vectorized Mitsuba variant, not {self.variant}",
                hint="install Debian's libllvm19 (./dev.sh does) so the llvm_ad_rgb variant works",
            )
        d_cam, z_per_t = self._pixel_rays(K, width, height)
        pose = np.asarray(world_from_cv, dtype=np.float64)
        d_world = (d_cam @ pose[:3, :3].T).astype(np.float32)
        origin = np.empty((3, len(d_cam)), np.float32)
        origin[:] = pose[:3, 3, None]
        ray = mi.Ray3f(mi.Point3f(origin), mi.Vector3f(np.ascontiguousarray(d_world.T)))
        si = self.integrator.nearest(self.scene, ray)
        valid = si.is_valid()
        depth = dr.select(valid, si.t * z_per_t, 0.0)
        labels = dr.zeros(mi.UInt32, width * height)
        for name, item in self.items.items():
            if item.label:
                labels = dr.select(si.shape == mi.ShapePtr(self._shapes[name]), item.label, labels)
        buffers = [depth, labels]
        if with_albedo:
            buffers += [
                si.bsdf(ray).eval_diffuse_reflectance(si, valid),
                dr.select(valid, dr.abs(dr.dot(si.n, ray.d)), 0.0),
            ]
        dr.eval(*buffers)
        out = Surface(
            depth=np.asarray(depth, dtype=np.float32).reshape(height, width),
            labels=np.asarray(labels, dtype=np.uint8).reshape(height, width),
        )
        if with_albedo:
            # a Color3f of N lanes converts to a (3, N) array
            out.albedo = np.asarray(buffers[2], dtype=np.float32).reshape(3, -1).T.reshape(height, width, 3)
            out.cos_incidence = np.asarray(buffers[3], dtype=np.float32).reshape(height, width)
        return out

    def _pixel_rays(self, K: np.ndarray, width: int, height: int):
        """Unit ray directions through the pixel centers in camera axes ((N, 3) float64) and, per
        lane, the z-depth per unit of ray length (a Dr.Jit Float), made once per camera model."""
        K = np.asarray(K, dtype=np.float64)
        key = (int(width), int(height), K.tobytes())
        if self._rays is None or self._rays[0] != key:
            u, v = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
            d = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], axis=-1).reshape(-1, 3)
            norm = np.linalg.norm(d, axis=1)
            z_per_t = self.mi.Float((1.0 / norm).astype(np.float32))
            self._rays = (key, d / norm[:, None], z_per_t)
        return self._rays[1], self._rays[2]


@dataclass
class Surface:
    """Per-pixel buffers from :meth:`RenderScene.surface`."""

    depth: np.ndarray
    """Z-depth [m], (H, W), 0 where no surface."""
    labels: np.ndarray
    """Item label per pixel, (H, W) uint8."""
    albedo: np.ndarray | None = None
    """Linear RGB albedo, (H, W, 3)."""
    cos_incidence: np.ndarray | None = None
    """|cos| between the geometric normal and the ray, (H, W)."""
