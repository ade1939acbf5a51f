"""A hand that holds the object: palm, four fingers and a thumb wrapped around it, and a forearm
in a sleeve, as one rigid mesh with per-vertex colors (skin and cloth).

The hand is built in the object's frame at the moment of contact, around the object's actual
surface, then expressed in the interactor's frame (``object_from_hand``), so the generator moves
it like any rigid interactor. Two grips:

- ``wrap``: a power grasp around the object's Z axis (a standing can from the side, a lying mug
  from above, a box pushed from behind): the palm on the side that faces the hand, the fingers
  curled around the far side, the thumb around the near side, each finger a tube that follows
  the object's outline about 1 mm off its surface;
- ``claw``: from above (turning an object in place): five fingers over the rim and down the sides.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

import manifold3d
import numpy as np
import trimesh

from rose_usd.core import se3
from rose_usd.core.color import srgb_to_linear
from rose_usd.synth.shapes import from_manifold

FINGER_RADIUS_M = 0.0085
SKIN_TONES_SRGB = ((241, 194, 167), (224, 172, 140), (198, 134, 103), (161, 102, 73), (120, 76, 54), (88, 57, 40))
"""From light to dark, roughly the Fitzpatrick I-VI range of photographed skin."""
SLEEVE_SRGB = ((40, 44, 52), (70, 90, 130), (150, 40, 45), (200, 200, 195), (90, 110, 80), (120, 120, 125))


class Grip(enum.Enum):
    WRAP = "wrap"
    CLAW = "claw"


@dataclass(frozen=True)
class HandLook:
    skin_linear: tuple[float, float, float]
    sleeve_linear: tuple[float, float, float]


def sample_look(rng: np.random.Generator) -> HandLook:
    skin = np.array(SKIN_TONES_SRGB[int(rng.integers(len(SKIN_TONES_SRGB)))], float) / 255.0
    sleeve = np.array(SLEEVE_SRGB[int(rng.integers(len(SLEEVE_SRGB)))], float) / 255.0
    return HandLook(tuple(srgb_to_linear(skin).tolist()), tuple(srgb_to_linear(sleeve).tolist()))


def smooth_shade(points: np.ndarray, rng: np.random.Generator, *, amplitude: float, wavelength_m: float) -> np.ndarray:
    """A smooth random factor around 1 per 3D point (a sum of random plane waves), for blotchy
    variation of a surface color without a texture."""
    dirs = rng.normal(size=(6, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    freq = 2 * np.pi / (wavelength_m * rng.uniform(0.7, 1.4, size=6))
    phase = rng.uniform(0, 2 * np.pi, size=6)
    waves = np.sin((points @ dirs.T) * freq + phase).sum(axis=1) / np.sqrt(3.0)
    return 1.0 + amplitude * waves


def _tube(points: np.ndarray, radius: float) -> manifold3d.Manifold:
    """A rounded tube along a polyline: the union of the capsules between consecutive points."""
    spheres = [manifold3d.Manifold.sphere(radius, 16).translate(tuple(map(float, p))) for p in points]
    segments = [manifold3d.Manifold.batch_hull([a, b]) for a, b in zip(spheres[:-1], spheres[1:])]
    return manifold3d.Manifold.batch_boolean(segments, manifold3d.OpType.Add)


def _ellipsoid(center, axes: np.ndarray, radii) -> manifold3d.Manifold:
    """An ellipsoid with semi-axes ``radii`` along the columns of the rotation ``axes``."""
    m = manifold3d.Manifold.sphere(1.0, 32).scale(tuple(map(float, radii)))
    pose = se3.make_pose(axes, center)
    return m.transform(pose[:3, :4].tolist())


def _outline_radius(points: np.ndarray, center: np.ndarray, axis: np.ndarray, angles: np.ndarray, e1, e2) -> np.ndarray:
    """The object's radial extent about ``axis`` through ``center`` in each direction of ``angles``
    (the largest radius among surface points within 12 degrees of it)."""
    rel = points - center
    rel = rel - np.outer(rel @ axis, axis)
    r = np.linalg.norm(rel, axis=1)
    phi = np.arctan2(rel @ e2, rel @ e1)
    out = np.empty(len(angles))
    for i, a in enumerate(angles):
        near = np.abs(np.angle(np.exp(1j * (phi - a)))) < np.radians(12.0)
        out[i] = np.percentile(r[near], 97) if near.any() else np.percentile(r, 90)
    return out


def _arc_finger(points, center, axis, e1, e2, start, sweep, n=9) -> np.ndarray:
    angles = start + np.linspace(0.0, sweep, n)
    radius = _outline_radius(points, center, axis, angles, e1, e2) + FINGER_RADIUS_M + 0.001
    return center + radius[:, None] * (np.outer(np.cos(angles), e1) + np.outer(np.sin(angles), e2))


def build_hand(
    object_mesh: trimesh.Trimesh,
    object_from_hand: np.ndarray,
    up_in_object: np.ndarray,
    grip: Grip,
    look: HandLook,
    rng: np.random.Generator,
    avoid: np.ndarray | None = None,
) -> tuple[trimesh.Trimesh, np.ndarray]:
    """The hand mesh in the interactor's frame and its linear RGB per vertex.

    Args:
        object_mesh: the held object in its own frame.
        object_from_hand: the interactor's pose in the object frame while it holds it; its
            position is where the palm's center goes (the palm faces the object).
        up_in_object: world up, in the object frame, at contact.
        avoid: a direction in the object frame the fingers should not curl toward (a mug's handle).
    """
    pts = np.asarray(object_mesh.sample(4000, seed=int(rng.integers(1 << 31))), float)
    up = np.asarray(up_in_object, float) / np.linalg.norm(up_in_object)
    palm_at = object_from_hand[:3, 3]
    parts: list[manifold3d.Manifold] = []
    finger_len = rng.uniform(0.075, 0.088)
    if grip is Grip.WRAP:
        axis = np.array([0.0, 0.0, 1.0])
        z_lo, z_hi = float(pts[:, 2].min()), float(pts[:, 2].max())
        z_grip = float(np.clip(palm_at[2], z_lo + 0.012, z_hi - 0.008))
        center = np.array([0.0, 0.0, z_grip])
        p = palm_at - center
        p[2] = 0.0
        p /= np.linalg.norm(p)
        w = np.cross(axis, p)
        if abs(w @ up) > 0.3:
            if w @ up < 0:  # the wrist (-w) side would point up: curl the fingers the other way
                w = -w
        elif avoid is not None and w @ avoid > 0:
            w = -w
        r_palm = float(_outline_radius(pts, center, axis, np.array([0.0]), p, w)[0])
        parts.append(_ellipsoid(center + (r_palm + 0.02) * p, np.stack([p, w, axis], 1), (0.02, 0.045, 0.044)))
        spacing = min(0.019, max(0.015, (z_hi - z_lo - 0.02) / 3))
        heights = z_grip + spacing * (np.arange(4) - 1.5)
        heights = np.clip(heights, z_lo + FINGER_RADIUS_M + 0.002, z_hi - 0.004)
        for k, z in enumerate(heights):
            c = np.array([0.0, 0.0, z])
            length = finger_len * (0.82 if k in (0, 3) else 1.0)
            r0 = r_palm + FINGER_RADIUS_M + 0.001
            start = 0.035 / r0
            knuckle = c + (r_palm + 0.025) * p + 0.035 * w
            arc = _arc_finger(pts, c, axis, p, w, start, length / r0)
            parts.append(_tube(np.vstack([knuckle, arc]), FINGER_RADIUS_M * (0.9 if k == 3 else 1.0)))
        c = np.array([0.0, 0.0, heights[0] - 0.004])
        thumb = _arc_finger(pts, c, axis, p, w, -0.045 / r0, -0.055 / r0, n=6)
        parts.append(_tube(np.vstack([c + (r_palm + 0.03) * p - 0.03 * w, thumb]), FINGER_RADIUS_M * 1.1))
        wrist = center + (r_palm + 0.025) * p - 0.045 * w
        arm_dir = -0.7 * w + 0.5 * p + 0.6 * up
    else:
        top = float((pts @ up).max())
        e1 = np.cross(up, [1.0, 0.0, 0.0] if abs(up[0]) < 0.9 else [0.0, 1.0, 0.0])
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(up, e1)
        middle = pts - np.outer(pts @ up, up)
        center = middle.mean(axis=0)
        palm_center = center + (top + 0.022) * up
        parts.append(_ellipsoid(palm_center, np.stack([e1, e2, up], 1), (0.045, 0.04, 0.018)))
        near_top = pts[pts @ up > top - 0.03]
        for k, a in enumerate(np.radians([-140.0, -70.0, 0.0, 70.0, 140.0])):
            d = np.cos(a) * e1 + np.sin(a) * e2
            r = float(_outline_radius(near_top, center, up, np.array([a]), e1, e2)[0]) + FINGER_RADIUS_M + 0.001
            down = 0.03 if k != 2 else 0.02
            poly = [
                palm_center + 0.03 * d - 0.005 * up,
                center + r * d + (top + 0.008) * up,
                center + r * d + (top - down) * up,
            ]
            parts.append(_tube(np.array(poly), FINGER_RADIUS_M))
        wrist = palm_center - 0.04 * e1
        arm_dir = up - 0.8 * e1
    arm_dir = arm_dir / np.linalg.norm(arm_dir)
    elbow = wrist + 0.30 * arm_dir
    parts.append(_tube(np.array([wrist, elbow]), 0.03))
    hand = from_manifold(manifold3d.Manifold.batch_boolean(parts, manifold3d.OpType.Add))
    hand = hand.subdivide_to_size(0.006, max_iter=8)
    along = (hand.vertices - wrist) @ arm_dir
    skin = np.asarray(look.skin_linear) * smooth_shade(hand.vertices, rng, amplitude=0.07, wavelength_m=0.03)[:, None]
    colors = np.where((along > 0.07)[:, None], np.asarray(look.sleeve_linear)[None], np.clip(skin, 0.0, 1.0))
    hand_from_object = se3.invert(object_from_hand)
    hand.apply_transform(hand_from_object)
    return hand, colors
