"""Procedural, seeded albedo textures (8-bit sRGB images) for tables, floors and walls."""

from __future__ import annotations

import cv2
import numpy as np


def value_noise(rng: np.random.Generator, size: int, cells: int) -> np.ndarray:
    """Smooth noise in [0, 1], shape (size, size), with about ``cells`` features per side; tileable."""
    grid = rng.random((cells, cells))
    tiled = np.tile(grid, (3, 3))
    up = cv2.resize(tiled, (3 * size, 3 * size), interpolation=cv2.INTER_CUBIC)
    return np.clip(up[size : 2 * size, size : 2 * size], 0.0, 1.0)


def wood(rng: np.random.Generator, size: int = 512) -> np.ndarray:
    """Wood-grain planks: sRGB uint8 (size, size, 3)."""
    base = np.array(rng.choice([[150, 104, 66], [176, 132, 88], [120, 80, 50], [196, 160, 118]]), dtype=float)
    y, x = np.mgrid[0:size, 0:size] / size
    warp = value_noise(rng, size, 6) * 0.15
    rings = 0.5 + 0.5 * np.sin((y + warp) * 2 * np.pi * rng.uniform(14, 22))
    planks = (np.floor(x * 4) % 2) * 0.08
    shade = 0.82 + 0.18 * rings - planks + 0.08 * (value_noise(rng, size, 24) - 0.5)
    gaps = (np.abs((x * 4) % 1.0 - 0.0) < 0.006) | (np.abs((x * 4) % 1.0 - 1.0) < 0.006)
    shade = np.where(gaps, 0.55, shade)
    return np.clip(base[None, None] * shade[..., None], 0, 255).astype(np.uint8)


def tiles(rng: np.random.Generator, size: int = 512, n: int = 4) -> np.ndarray:
    """Floor tiles with grout and per-tile tint: sRGB uint8 (size, size, 3)."""
    base = np.array(rng.choice([[200, 196, 188], [170, 176, 180], [150, 140, 128], [208, 200, 176]]), dtype=float)
    y, x = np.mgrid[0:size, 0:size] / size
    ix, iy = np.floor(x * n).astype(int), np.floor(y * n).astype(int)
    tint = rng.uniform(0.88, 1.06, size=(n, n))[iy, ix]
    grain = 0.94 + 0.06 * value_noise(rng, size, 32)
    grout = (np.minimum((x * n) % 1.0, 1 - (x * n) % 1.0) < 0.02) | (
        np.minimum((y * n) % 1.0, 1 - (y * n) % 1.0) < 0.02
    )
    img = base[None, None] * (tint * grain)[..., None]
    img[grout] = base * 0.55
    return np.clip(img, 0, 255).astype(np.uint8)


def plaster(rng: np.random.Generator, size: int = 256) -> np.ndarray:
    """A painted wall with low-contrast mottling: sRGB uint8 (size, size, 3)."""
    base = np.array(rng.choice([[214, 210, 198], [188, 200, 206], [206, 190, 176], [196, 206, 188]]), dtype=float)
    shade = 0.93 + 0.07 * value_noise(rng, size, 8)
    return np.clip(base[None, None] * shade[..., None], 0, 255).astype(np.uint8)


def checker(size: int = 256, n: int = 8, colors=((230, 230, 230), (40, 40, 40))) -> np.ndarray:
    """A checkerboard: sRGB uint8 (size, size, 3)."""
    y, x = np.mgrid[0:size, 0:size] * n // size
    mask = ((x + y) % 2).astype(bool)
    img = np.empty((size, size, 3), np.uint8)
    img[~mask] = colors[0]
    img[mask] = colors[1]
    return img


def marble(rng: np.random.Generator, size: int = 512) -> np.ndarray:
    """Light stone with soft veins: sRGB uint8 (size, size, 3)."""
    base = np.array(rng.choice([[226, 222, 214], [200, 204, 208], [214, 200, 186]]), dtype=float)
    y, x = np.mgrid[0:size, 0:size] / size
    turb = value_noise(rng, size, 5) + 0.5 * value_noise(rng, size, 11)
    veins = np.abs(np.sin((x + y + 0.9 * turb) * 2 * np.pi * rng.uniform(2.0, 3.5))) ** 0.25
    shade = 0.72 + 0.28 * veins + 0.04 * (value_noise(rng, size, 40) - 0.5)
    return np.clip(base[None, None] * shade[..., None], 0, 255).astype(np.uint8)


def cloth(rng: np.random.Generator, size: int = 512) -> np.ndarray:
    """A woven tablecloth: two-color weave with a plaid: sRGB uint8 (size, size, 3)."""
    palette = rng.choice(
        [[[178, 52, 48], [236, 228, 214]], [[52, 88, 150], [230, 230, 226]], [[70, 120, 80], [228, 222, 200]]]
    )
    a, b = (np.array(c, dtype=float) for c in palette)
    y, x = np.mgrid[0:size, 0:size] / size
    n = int(rng.integers(5, 9))
    stripes = ((np.floor(x * n * 2) % 2) + (np.floor(y * n * 2) % 2)) / 2.0
    weave = 0.9 + 0.1 * np.sin(x * size * np.pi / 2) * np.sin(y * size * np.pi / 2)
    img = (a[None, None] * stripes[..., None] + b[None, None] * (1 - stripes[..., None])) * weave[..., None]
    return np.clip(img, 0, 255).astype(np.uint8)


TABLE_TEXTURES = {"wood": wood, "marble": marble, "cloth": cloth}


def felt(rng: np.random.Generator, size: int = 512) -> np.ndarray:
    """A plain grey or beige cloth with a fine weave and soft folds: sRGB uint8 (size, size, 3)."""
    base = np.array(rng.choice([[128, 128, 126], [150, 146, 138], [104, 108, 112], [170, 160, 140]]), dtype=float)
    y, x = np.mgrid[0:size, 0:size]
    weave = 0.94 + 0.06 * ((x // 2 + y // 2) % 2)
    folds = 0.9 + 0.1 * value_noise(rng, size, 4) + 0.05 * (value_noise(rng, size, 48) - 0.5)
    return np.clip(base[None, None] * (weave * folds)[..., None], 0, 255).astype(np.uint8)


def _print_ink(u: np.ndarray, v: np.ndarray, rng: np.random.Generator, line_m: float = 0.008) -> np.ndarray:
    """Where text-like print is, for surface coordinates u, v [m]: lines of glyph-sized blocks
    with word gaps."""
    table = rng.random((64, 256))
    line = np.floor(v / line_m).astype(int)
    char = np.floor(u / 0.003).astype(int)
    in_line = (v / line_m) % 1.0 < 0.45
    return in_line & (table[line % 64, char % 256] < 0.62) & (table[(line + 7) % 64, (char // 5) % 256] < 0.85)


def object_colors(vertices: np.ndarray, shape: str, base_linear, rng: np.random.Generator) -> np.ndarray:
    """Linear RGB per vertex for a target object in its own frame (origin at the bottom center,
    +Z up): a speckled glaze for a mug, a printed label around a can, a printed panel on a box."""
    from rose_usd.core.color import srgb_to_linear

    v = np.asarray(vertices, float)
    base = np.asarray(base_linear, float)
    colors = np.repeat(base[None], len(v), axis=0)
    height = float(v[:, 2].max() - v[:, 2].min())
    angle = np.arctan2(v[:, 1], v[:, 0])
    radius = np.hypot(v[:, 0], v[:, 1])
    ink = srgb_to_linear(np.array(rng.choice([[20, 20, 24], [240, 240, 236], [30, 40, 110]]), float) / 255.0)
    if shape == "mug":
        # speckles: small dots, lighter and darker than the glaze
        n = 900
        centers = v[rng.integers(len(v), size=n)] + rng.normal(scale=0.002, size=(n, 3))
        from scipy.spatial import cKDTree

        dist, idx = cKDTree(centers).query(v)
        spot = dist < rng.uniform(0.0012, 0.0022)
        light = idx % 3 != 0
        colors[spot & light] = np.clip(base * 0.3 + 0.7, 0, 1)
        colors[spot & ~light] = base * 0.35
    elif shape == "can":
        band = (v[:, 2] > 0.15 * height) & (v[:, 2] < 0.85 * height)
        colors[~band] = srgb_to_linear(np.array([190, 192, 196]) / 255.0)
        u = (angle + np.pi) * np.maximum(radius, 1e-6)
        label = srgb_to_linear(np.array(rng.choice([[236, 232, 220], [250, 210, 60], [40, 120, 70]]), float) / 255.0)
        colors[band] = label
        text = band & _print_ink(u, v[:, 2], rng) & ((angle + np.pi) % np.pi < 2.2)
        colors[text] = ink
        logo = (
            band
            & (np.abs(v[:, 2] - 0.5 * height) < 0.18 * height)
            & (np.abs(np.angle(np.exp(1j * (angle - 1.0)))) < 0.5)
        )
        colors[logo] = base
    else:  # box: a printed panel on the four sides, text on it
        ext = v.max(axis=0) - v.min(axis=0)
        side_x = np.abs(np.abs(v[:, 0]) - 0.5 * ext[0]) < 1e-4
        side_y = np.abs(np.abs(v[:, 1]) - 0.5 * ext[1]) < 1e-4
        u = np.where(side_x, v[:, 1], v[:, 0]) + 0.5 * max(ext[0], ext[1])
        panel = (side_x | side_y) & (v[:, 2] > 0.25 * height) & (v[:, 2] < 0.8 * height)
        colors[panel] = np.clip(base * 0.25 + 0.7, 0, 1)
        colors[panel & _print_ink(u, v[:, 2], rng, line_m=0.007)] = ink
    return colors
