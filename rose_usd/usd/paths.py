"""Names defined once: layer files, their order, prim paths, and which stage owns which specs.

No other module builds a prim path by hand; they call these getters.
"""

from __future__ import annotations

import fnmatch
import posixpath
from dataclasses import dataclass

from pxr import Sdf

from rose_usd.errors import ConfigError

# ----------------------------------------------------------------------------- layers
ROOT_FILE = "rose.usda"
LAYERS_DIR = "layers"
ROBOMIMIC_FILE = "robomimic.hdf5"
"""The collect stage's rollouts as robomimic HDF5, beside its LeRobot dataset (dataset/lerobot/)."""


def robomimic_beside(lerobot_info: str) -> str:
    """The robomimic file written beside a LeRobot dataset, from that dataset's meta/info.json
    path (``dataset/lerobot/meta/info.json`` -> ``dataset/robomimic.hdf5``)."""
    return posixpath.join(posixpath.dirname(posixpath.dirname(posixpath.dirname(lerobot_info))), ROBOMIMIC_FILE)


# subLayers of the root, strongest first (architecture.md, section 2)
LAYER_ORDER = ("gate", "robot", "trajectory", "object", "scene", "masks", "world")


def layer_file(layer: str) -> str:
    """Path of a stage's layer relative to the output folder, e.g. ``layers/world.usda``."""
    if layer not in LAYER_ORDER:
        raise ValueError(f"unknown layer {layer!r}")
    return f"{LAYERS_DIR}/{layer}.usda"


# ----------------------------------------------------------------------------- prims
WORLD = Sdf.Path("/World")
PHYSICS_SCENE = WORLD.AppendChild("PhysicsScene")
CAMERAS = WORLD.AppendChild("Cameras")
CAMERA = CAMERAS.AppendChild("Camera")
SCENE = WORLD.AppendChild("Scene")
SCENE_VISUAL = SCENE.AppendChild("Visual")
SCENE_COLLISION = SCENE.AppendChild("Collision")
SCENE_LIGHTS = SCENE.AppendChild("Lights")
SCENE_LOOKS = SCENE.AppendChild("Looks")
OBJECTS = WORLD.AppendChild("Objects")
MASKS = WORLD.AppendChild("Masks")
OBJECT_MASKS = MASKS.AppendChild("Objects")
INTERACTOR_MASK = MASKS.AppendChild("Interactor")
GATE = WORLD.AppendChild("Gate")
ROBOTS = WORLD.AppendChild("Robots")

# the object pose: one translate and one orient op (double precision), default = frame 0
OBJECT_POSE_OPS = ("xformOp:translate", "xformOp:orient")


def check_name(name: str, *, what: str = "object name") -> str:
    """Return ``name`` if it is a valid USD prim name, else raise ConfigError."""
    if not Sdf.Path.IsValidIdentifier(name):
        raise ConfigError(
            f"{what} {name!r} is not a valid USD prim name",
            hint="use letters, digits and underscores, not starting with a digit (e.g. 'Mug' or 'red_cup')",
        )
    return name


RESERVED_NAMES = frozenset(
    p.name
    for p in (
        WORLD,
        PHYSICS_SCENE,
        CAMERAS,
        CAMERA,
        SCENE,
        SCENE_VISUAL,
        SCENE_COLLISION,
        SCENE_LIGHTS,
        SCENE_LOOKS,
        OBJECTS,
        MASKS,
        INTERACTOR_MASK,
        GATE,
        ROBOTS,
    )
)
"""Prim names rose_usd itself uses: an object named like one would share its prim, mask key or
folder (an object named ``Interactor`` lost its masks to the hand's)."""


def check_object_name(name: str) -> str:
    """Return ``name`` if it can name an object: a valid prim name that is none of
    :data:`RESERVED_NAMES` (in any letter case: folders are named after objects); else ConfigError."""
    check_name(name)
    if name.lower() in {r.lower() for r in RESERVED_NAMES}:
        raise ConfigError(
            f"object name {name!r} is reserved",
            hint=f"rose_usd itself uses {', '.join(sorted(RESERVED_NAMES))}; call the object e.g. {name}Object",
        )
    return name


def object_path(name: str) -> Sdf.Path:
    return OBJECTS.AppendChild(check_name(name))


def object_visual(name: str) -> Sdf.Path:
    return object_path(name).AppendChild("Visual")


def object_collision(name: str) -> Sdf.Path:
    return object_path(name).AppendChild("Collision")


def object_looks(name: str) -> Sdf.Path:
    return object_path(name).AppendChild("Looks")


def object_mask(name: str) -> Sdf.Path:
    return OBJECT_MASKS.AppendChild(check_name(name))


def robot_path(name: str) -> Sdf.Path:
    """A robot of the collect stage, e.g. ``/World/Robots/Panda``."""
    return ROBOTS.AppendChild(check_name(name, what="robot name"))


def robot_link(robot: str, link: str) -> Sdf.Path:
    """One link of a robot; its geometry sits under it."""
    return robot_path(robot).AppendChild(check_name(link, what="robot link name"))


def scene_part(name: str) -> Sdf.Path:
    """A visual part of the scene (when the scene keeps parts with their own materials)."""
    return SCENE_VISUAL.AppendChild(check_name(name, what="scene part name"))


# ----------------------------------------------------------------------------- ownership
@dataclass(frozen=True)
class Claim:
    """Specs a stage may author: prims at or under ``prefix`` (or exactly at it if ``exact``),
    with ``properties`` restricted to these glob patterns (None: any property)."""

    prefix: Sdf.Path
    exact: bool = False
    properties: tuple[str, ...] | None = None
    may_define: bool = True

    def covers_prim(self, path: Sdf.Path) -> bool:
        return path == self.prefix if self.exact else path.HasPrefix(self.prefix)

    def covers_property(self, prim_path: Sdf.Path, name: str) -> bool:
        if not self.covers_prim(prim_path):
            return False
        return self.properties is None or any(fnmatch.fnmatchcase(name, pat) for pat in self.properties)


_WORLD_PROPS = ("rose:world:*", "xformOp:*", "xformOpOrder")
OWNERSHIP: dict[str, tuple[Claim, ...]] = {
    "world": (
        Claim(WORLD, exact=True, properties=_WORLD_PROPS),
        Claim(PHYSICS_SCENE),
        Claim(CAMERAS),
    ),
    "masks": (Claim(MASKS),),
    "scene": (Claim(SCENE),),
    "object": (Claim(OBJECTS),),
    # the trajectory overrides only the pose ops and its own schema on existing object prims
    "trajectory": (
        Claim(OBJECTS, properties=OBJECT_POSE_OPS + ("xformOpOrder", "rose:trajectory:*"), may_define=False),
    ),
    "gate": (Claim(GATE),),
    "robot": (Claim(ROBOTS),),
}


def ownership_violations(layer: Sdf.Layer, layer_name: str) -> list[str]:
    """Specs in ``layer`` that the stage writing ``layer_name`` does not own (empty when clean).

    Ancestors that are plain ``over`` specs with nothing authored (they only hold owned children)
    are allowed; so are ``apiSchemas`` metadata on owned prims.
    """
    claims = OWNERSHIP.get(layer_name)
    if claims is None:
        raise ValueError(f"unknown layer {layer_name!r}")
    problems: list[str] = []

    def visit(spec: Sdf.PrimSpec) -> None:
        path = spec.path
        prim_claims = [c for c in claims if c.covers_prim(path)]
        authored_here = spec.specifier != Sdf.SpecifierOver or bool(spec.typeName)
        if authored_here and not any(c.may_define for c in prim_claims):
            problems.append(f"{path}: defined by layer {layer_name!r}, which may not define it")
        for prop in spec.properties:
            if not any(c.covers_property(path, prop.name) for c in prim_claims):
                problems.append(f"{path}.{prop.name}: authored by layer {layer_name!r}, which does not own it")
        for child in spec.nameChildren:
            visit(child)

    for root_spec in layer.rootPrims:
        visit(root_spec)
    return problems
