"""Build a :class:`RenderScene` from a composed rose stage: every renderable mesh (guide purpose
excluded) with its look, the UsdLux lights, and the camera track."""

from __future__ import annotations

import numpy as np
from pxr import Sdf, Usd, UsdGeom, UsdLux

from rose_usd.errors import StageError
from rose_usd.render.lighting import Lighting, PointLight
from rose_usd.render.scene import RenderItem, RenderScene
from rose_usd.usd.geom import read_mesh


def _animated(prim: Usd.Prim) -> bool:
    """Whether the prim's world transform may change over time (it or an ancestor is animated)."""
    p = prim
    while p and not p.IsPseudoRoot():
        if p.IsA(UsdGeom.Xformable) and UsdGeom.Xformable(p).TransformMightBeTimeVarying():
            return True
        p = p.GetParent()
    return False


def read_lighting(stage: Usd.Stage) -> Lighting:
    """Lighting from UsdLux prims; a stage without lights renders unlit (radiance = albedo)."""
    ambient = np.zeros(3)
    points = []
    found = False
    for prim in stage.Traverse():
        if prim.IsA(UsdLux.DomeLight):
            light = UsdLux.DomeLight(prim)
            ambient += float(light.GetIntensityAttr().Get()) * np.asarray(light.GetColorAttr().Get(), dtype=float)
            found = True
        elif prim.IsA(UsdLux.SphereLight):
            light = UsdLux.SphereLight(prim)
            intensity = float(light.GetIntensityAttr().Get()) * np.asarray(light.GetColorAttr().Get(), dtype=float)
            pos = np.asarray(UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(Usd.TimeCode.Default()), dtype=float)[
                3, :3
            ]
            points.append(PointLight(tuple(pos.tolist()), tuple(intensity.tolist())))
            found = True
    if not found:
        return Lighting.unlit()
    return Lighting(ambient=tuple(ambient.tolist()), points=tuple(points))


class StageRenderer:
    """Renders a stage at its time codes: static meshes once, animated meshes re-posed per frame.
    ``extra`` items (not in the stage: a simulated robot's links) are drawn too, posed by the caller
    with ``scene.set_poses``."""

    def __init__(self, stage: Usd.Stage, extra: list[RenderItem] = (), labels: dict[str, int] | None = None):
        """``labels``: prim path -> label (1-255) of the meshes at or below it in label images."""
        self.stage = stage
        items = list(extra)
        roots = [(Sdf.Path(path), int(label)) for path, label in (labels or {}).items()]
        self._animated: dict[str, Usd.Prim] = {}
        purposes = {UsdGeom.Tokens.default_, UsdGeom.Tokens.render}
        for prim in stage.Traverse():
            if not prim.IsA(UsdGeom.Mesh):
                continue
            imageable = UsdGeom.Imageable(prim)
            if imageable.ComputePurpose() not in purposes or imageable.ComputeVisibility() == UsdGeom.Tokens.invisible:
                continue
            name = f"m{len(items)}"
            label = next((lab for root, lab in roots if prim.GetPath().HasPrefix(root)), 0)
            if _animated(prim):
                mesh = read_mesh(prim, world=False)
                pose = np.asarray(UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(Usd.TimeCode(0)), dtype=float).T
                self._animated[name] = prim
                items.append(RenderItem(name, mesh, label=label, pose=pose))
            else:
                items.append(RenderItem(name, read_mesh(prim, world=True), label=label, moves=False))
        if not items:
            raise StageError(
                "the stage has no renderable meshes",
                path=stage.GetRootLayer().identifier,
                hint="run the scene and object stages",
            )
        self.lighting = read_lighting(stage)
        self.scene = RenderScene(items, self.lighting)

    @property
    def animated(self) -> list[str]:
        """The render item names of the animated meshes."""
        return list(self._animated)

    def animated_under(self, path: str) -> dict[str, Usd.Prim]:
        """The animated meshes at or below prim ``path``: render item name -> prim."""
        root = Sdf.Path(path)
        return {name: prim for name, prim in self._animated.items() if prim.GetPath().HasPrefix(root)}

    def poses_at(self, t: int) -> dict[str, np.ndarray]:
        """The animated meshes' world poses at time code t (render item name -> (4, 4))."""
        code = Usd.TimeCode(t)
        return {
            name: np.asarray(UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(code), dtype=float).T
            for name, prim in self._animated.items()
        }

    def pose_at(self, t: int) -> None:
        """Move animated meshes to time code t."""
        self.scene.set_poses(self.poses_at(t))
