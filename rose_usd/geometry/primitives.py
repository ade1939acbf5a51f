"""Category primitives: the shape that stands in for an object nobody scanned (a box, an upright
cylinder, a cup's frustum, a mug's cylinder with a handle, a pen's lying cylinder), and the
typical size of its category.

An RGB-only video measures no size: a monocular reconstruction is correct up to one scale. When
rose.toml gives neither ``size_m`` nor a metric mesh, the object's category gives a typical size
with an uncertainty (the table below, with where each figure comes from), and the capture stage
takes the world's metric scale from it. The object stage fits the same primitive to the masks
and marks it as a proxy (``RoseShapeAPI``).

Every primitive's frame: origin at the center of its bottom (what it stands on), +Z up; its
``size`` is its largest dimension [m], what ``size_m`` in rose.toml means.
"""

from __future__ import annotations

import enum
import functools
from dataclasses import dataclass

import numpy as np


class PrimitiveKind(enum.Enum):
    BOX = "box"  # dims: (x, y, z) extents
    CYLINDER = "cylinder"  # dims: (radius, height), axis +Z
    FRUSTUM = "frustum"  # dims: (bottom radius, top radius, height), axis +Z (a cup)
    MUG = "mug"  # dims: (radius, height, handle reach beyond the wall), axis +Z, the handle on +X
    LYING_CYLINDER = "lying-cylinder"  # dims: (radius, length), axis +X, lying on its side (a pen)


@dataclass(frozen=True)
class Typical:
    """A category's primitive and its typical dimensions, with their relative one-sigma spread
    and where the figures come from."""

    kind: PrimitiveKind
    dims: tuple[float, ...]
    sigma: float
    """Relative one-sigma of the category's size [-]."""
    source: str
    revolution: bool = False
    """A solid of revolution (a can, a cup; not a mug, whose handle breaks it): its outline does
    not show it turning about its axis."""

    @property
    def size_m(self) -> float:
        return largest_dimension(self.kind, np.asarray(self.dims))


TYPICAL: dict[str, Typical] = {
    "cup": Typical(
        PrimitiveKind.FRUSTUM,
        (0.030, 0.047, 0.121),
        0.15,
        "16 oz plastic party cup (Dart Solo P16R): 12.1 cm tall, 9.4 cm rim, 6.0 cm base, the manufacturer's"
        " spec sheet; paper coffee cups (8-16 oz) are 9-14 cm tall",
        revolution=True,
    ),
    "mug": Typical(
        PrimitiveKind.MUG,
        (0.041, 0.095, 0.037),
        0.12,
        "11 oz ceramic mug, the common sublimation blank: 9.5 cm tall, 8.2 cm across, 11.9 cm across its"
        " handle (vendors' spec sheets); 8-15 oz mugs are 8-12 cm tall",
    ),
    "can": Typical(
        PrimitiveKind.CYLINDER,
        (0.033, 0.122),
        0.15,
        "12 fl oz (355 ml) beverage can: 12.2 cm tall, 6.6 cm across (Ball Corporation's 211/202 can spec);"
        " other common cans: 330 ml 11.5 cm, 250 ml slim 13.4 cm, 473-500 ml 15.7-16.8 cm, soup cans about"
        " 10 cm tall",
        revolution=True,
    ),
    "bottle": Typical(
        PrimitiveKind.CYLINDER,
        (0.033, 0.21),
        0.2,
        "0.5 l PET water bottle: about 21 cm tall and 6.5 cm across (retail bottles, 0.33-0.75 l: 17-25 cm)",
        revolution=True,
    ),
    "marker": Typical(
        PrimitiveKind.LYING_CYLINDER,
        (0.008, 0.138),
        0.1,
        "permanent marker (Sharpie Fine Point): 13.8 cm long with its cap, 1.6 cm across (manufacturer's"
        " product data); whiteboard markers are 12-14 cm",
        revolution=True,
    ),
    "pen": Typical(
        PrimitiveKind.LYING_CYLINDER,
        (0.005, 0.145),
        0.1,
        "ballpoint pen: 14-15 cm long, about 1 cm across (BIC Cristal: 14.9 cm)",
        revolution=True,
    ),
    "book": Typical(PrimitiveKind.BOX, (0.15, 0.23, 0.03), 0.25, "paperback / A5-B5 book: 15 x 23 cm, 2-4 cm thick"),
    "block": Typical(PrimitiveKind.BOX, (0.04, 0.04, 0.04), 0.4, "toy wooden building block: 3-5 cm"),
    "box": Typical(PrimitiveKind.BOX, (0.12, 0.08, 0.06), 0.5, "small carton: no typical size, a wide guess"),
    "bowl": Typical(
        PrimitiveKind.FRUSTUM, (0.04, 0.075, 0.07), 0.25, "cereal bowl: 15 cm across, 7 cm tall", revolution=True
    ),
    "fruit": Typical(PrimitiveKind.CYLINDER, (0.04, 0.08), 0.2, "apple or orange: about 8 cm across", revolution=True),
    "toy": Typical(PrimitiveKind.BOX, (0.10, 0.06, 0.06), 0.5, "small toy: no typical size, a wide guess"),
    "generic": Typical(PrimitiveKind.BOX, (0.10, 0.08, 0.08), 0.6, "unknown category: a wide guess"),
}
"""Category -> its primitive and typical dimensions. Categories without an entry use ``generic``."""


RESTING_MARGIN = 0.05
"""Silhouette IoU by which a primitive's other way of resting must beat its usual one to be kept.
A lying can's outline fits a standing cylinder at IoU 0.51-0.94 (0.94 seen end on), a lying one
at 0.999; a standing can's silhouette seen from above a box it stands on, fitted on the table
below, fits lying 0.03 better than standing (the wrong support makes neither fit), which must not
turn it over."""

MUG_REACH_SIGMA = 0.2
"""Relative one-sigma of a mug's handle reach over its radius (0.9 for the typical mug; 8-15 oz
mugs' handles reach 2.8-4.5 cm beyond a 3.6-4.5 cm radius)."""


def turns(kind: PrimitiveKind) -> bool:
    """Whether the primitive's silhouette depends on its yaw (not a solid of revolution about +Z)."""
    return kind in (PrimitiveKind.BOX, PrimitiveKind.LYING_CYLINDER, PrimitiveKind.MUG)


def yaw_starts(kind: PrimitiveKind) -> tuple[float, ...]:
    """Where a standing fit's yaw starts [rad]: a mug's handle may point anywhere; a box repeats
    every 90 deg, a lying cylinder every 180; a solid of revolution needs none but 0."""
    if kind is PrimitiveKind.MUG:
        return tuple(np.radians([0.0, 90.0, 180.0, 270.0]))
    if kind is PrimitiveKind.LYING_CYLINDER:
        return tuple(np.radians([0.0, 30.0, 60.0, 90.0, 120.0, 150.0]))
    return tuple(np.radians([0.0, 30.0, 60.0])) if turns(kind) else (0.0,)


def resting_kinds(kind: PrimitiveKind) -> tuple[PrimitiveKind, ...]:
    """The ways a category's primitive may rest on a support, its usual one first: a cylinder (a
    can, a bottle) standing, or lying on its side with the same dims (radius, length). Each is
    fitted; a later one is kept where its silhouette IoU beats the kept one's by ``RESTING_MARGIN``."""
    return (kind, PrimitiveKind.LYING_CYLINDER) if kind is PrimitiveKind.CYLINDER else (kind,)


def typical(category: str) -> tuple[Typical, bool]:
    """The category's entry, and whether it has its own (False: the generic guess, also for
    ``generic``, rose.toml's default)."""
    key = category.strip().lower()
    return (TYPICAL[key], key != "generic") if key in TYPICAL else (TYPICAL["generic"], False)


def largest_dimension(kind: PrimitiveKind, dims: np.ndarray) -> float:
    """The primitive's largest dimension [m] (a box's longest side, a cylinder's diameter or height,
    a mug's width across its handle or height)."""
    d = np.asarray(dims, dtype=float)
    if kind is PrimitiveKind.BOX:
        return float(d.max())
    if kind is PrimitiveKind.CYLINDER:
        return float(max(2 * d[0], d[1]))
    if kind is PrimitiveKind.MUG:
        return float(max(2 * d[0] + d[2], d[1]))
    if kind is PrimitiveKind.FRUSTUM:
        return float(max(2 * d[0], 2 * d[1], d[2]))
    return float(max(2 * d[0], d[1]))


def primitive_mesh(kind: PrimitiveKind, dims, *, segments: int = 32) -> tuple[np.ndarray, np.ndarray]:
    """A closed, outward-wound triangle mesh of the primitive in its own frame (origin at the
    bottom's center, +Z up): vertices (V, 3) [m] and faces (F, 3)."""
    d = np.asarray(dims, dtype=float)
    if kind is PrimitiveKind.BOX:
        return box_mesh(d)
    if kind is PrimitiveKind.MUG:
        return mug_mesh(d[0], d[1], d[2], segments)
    return primitive_vertices(kind, d, segments=segments), _frustum_faces(segments).copy()


_LYING = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]]).T
"""Turns a standing cylinder's axis +Z to +X (applied as ``v @ _LYING``)."""


def primitive_vertices(kind: PrimitiveKind, dims, *, segments: int = 32) -> np.ndarray:
    """``primitive_mesh``'s vertices alone (not a mug's): what a convex silhouette fit needs, made
    thousands of times a fit."""
    d = np.asarray(dims, dtype=float)
    if kind is PrimitiveKind.BOX:
        return box_mesh(d)[0]
    if kind is PrimitiveKind.CYLINDER:
        return frustum_vertices(d[0], d[0], d[1], segments)
    if kind is PrimitiveKind.FRUSTUM:
        return frustum_vertices(d[0], d[1], d[2], segments)
    if kind is PrimitiveKind.MUG:
        raise ValueError("a mug's vertices come with its mesh (mug_mesh) or its hull (hull_points)")
    v = frustum_vertices(d[0], d[0], d[1], segments)  # a lying cylinder
    v = v - np.array([0.0, 0.0, 0.5 * d[1]])
    v = v @ _LYING  # axis +Z -> +X
    return v + np.array([0.0, 0.0, d[0]])


def box_mesh(extents) -> tuple[np.ndarray, np.ndarray]:
    """A box of ``extents`` (x, y, z) standing on z = 0, centered in x and y."""
    ex, ey, ez = (float(e) for e in extents)
    corners = np.array([[x, y, z] for z in (0.0, ez) for y in (-ey / 2, ey / 2) for x in (-ex / 2, ex / 2)])
    faces = np.array(
        [
            [0, 2, 1], [1, 2, 3],  # bottom (-z)
            [4, 5, 6], [5, 7, 6],  # top (+z)
            [0, 1, 4], [1, 5, 4],  # -y
            [2, 6, 3], [3, 6, 7],  # +y
            [0, 4, 2], [2, 4, 6],  # -x
            [1, 3, 5], [3, 7, 5],  # +x
        ]
    )  # fmt: skip
    return corners, faces


NO_FACES = np.zeros((0, 3), np.int64)


def hull_points(kind: PrimitiveKind, dims, *, segments: int = 32) -> tuple[np.ndarray, np.ndarray]:
    """Points with the primitive's convex hull, and no faces: what a convex silhouette fit
    (``fit_standing(convex=True)``) draws. A mug's are its body's rims and its handle's outer
    rim, not the joined solid (``mug_mesh``, 40x slower to make)."""
    d = np.asarray(dims, dtype=float)
    if kind is not PrimitiveKind.MUG:
        return primitive_vertices(kind, d, segments=segments), NO_FACES
    radius, height, reach = d
    a = 2 * np.pi * np.arange(segments) / segments
    rim = np.column_stack([radius * np.cos(a), radius * np.sin(a)])
    body = np.concatenate(
        [np.column_stack([rim, np.zeros(segments)]), np.column_stack([rim, np.full(segments, height)])]
    )
    bar, sunk, b = _handle(radius, height, reach)
    t = a[np.cos(a) >= 0]  # the loop's outer half-ellipse
    x, z = radius - sunk + (reach + sunk) * np.cos(t), 0.55 * height + b * np.sin(t)
    handle = np.concatenate([np.column_stack([x, np.full_like(x, y), z]) for y in (-bar / 2, bar / 2)])
    return np.concatenate([body, handle]), NO_FACES


def _handle(radius: float, height: float, reach: float) -> tuple[float, float, float]:
    """A mug handle's bar (width and thickness), how far its ends sink into the wall, and the
    loop's outer half-height [m]."""
    return 0.3 * reach, 0.15 * radius, 0.3 * height


def mug_mesh(radius: float, height: float, reach: float, segments: int = 32) -> tuple[np.ndarray, np.ndarray]:
    """A closed cylinder standing on z = 0, axis +Z, with a D-shaped handle on +X reaching ``reach``
    beyond its wall: a half-elliptical loop 0.6 of the height tall, centered 0.55 of it up, its bar
    0.3 ``reach`` wide and thick (one solid, joined by manifold3d)."""
    import manifold3d

    body = manifold3d.Manifold.cylinder(height, radius, radius, segments)
    bar, sunk, b = _handle(radius, height, reach)
    a = reach + sunk  # the loop's outer semi-axes (out, up): a, b
    ring = manifold3d.CrossSection.circle(1.0, segments).scale([a, b]) - manifold3d.CrossSection.circle(
        1.0, segments
    ).scale([max(a - bar, 1e-4), max(b - bar, 1e-4)])
    half = manifold3d.CrossSection.square([a + 1e-3, 2 * b + 2e-3]).translate([0.0, -b - 1e-3])
    handle = (ring ^ half).extrude(bar).translate([0.0, 0.0, -bar / 2]).rotate([90.0, 0.0, 0.0])
    solid = (body + handle.translate([radius - sunk, 0.0, 0.55 * height])).to_mesh()
    return np.asarray(solid.vert_properties, float)[:, :3], np.asarray(solid.tri_verts, np.int64)


def frustum_mesh(r_bottom: float, r_top: float, height: float, segments: int = 32) -> tuple[np.ndarray, np.ndarray]:
    """A closed frustum (a cylinder when the radii agree) standing on z = 0, axis +Z."""
    return frustum_vertices(r_bottom, r_top, height, segments), _frustum_faces(segments).copy()


def frustum_vertices(r_bottom: float, r_top: float, height: float, segments: int = 32) -> np.ndarray:
    """``frustum_mesh``'s vertices: the bottom ring, the top ring, the bottom's and the top's center."""
    ring = _unit_ring(segments)
    out = np.empty((2 * segments + 2, 3))
    out[:segments, :2] = r_bottom * ring
    out[:segments, 2] = 0.0
    out[segments : 2 * segments, :2] = r_top * ring
    out[segments : 2 * segments, 2] = height
    out[2 * segments :] = [[0.0, 0.0, 0.0], [0.0, 0.0, height]]
    return out


@functools.cache
def _unit_ring(segments: int) -> np.ndarray:
    a = np.linspace(0.0, 2 * np.pi, segments, endpoint=False)
    ring = np.column_stack([np.cos(a), np.sin(a)])
    ring.flags.writeable = False
    return ring


@functools.cache
def _frustum_faces(segments: int) -> np.ndarray:
    """``frustum_mesh``'s faces (outward): the side's quads as two triangles each, then the caps' fans."""
    i = np.arange(segments)
    j = (i + 1) % segments
    cb, ct = 2 * segments, 2 * segments + 1
    side = np.concatenate([np.column_stack([i, j, segments + j]), np.column_stack([i, segments + j, segments + i])])
    caps = np.concatenate(
        [
            np.column_stack([np.full(segments, cb), j, i]),
            np.column_stack([np.full(segments, ct), segments + i, segments + j]),
        ]
    )
    faces = np.concatenate([side, caps])
    faces.flags.writeable = False
    return faces
