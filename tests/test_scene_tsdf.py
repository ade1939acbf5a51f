"""The tsdf scene's support-hole filling: the table under an object that never moved is never
seen, and the collider must not have a hole there (Newton dropped a box through one)."""

from __future__ import annotations

import numpy as np

from rose_usd.scene.tsdf import fill_support_holes


def _table(z: float = -0.03, hole=(0.4, 0.6, 0.4, 0.6)) -> np.ndarray:
    """A 1 m x 1 m table at height z sampled every 5 mm, with a rectangular gap."""
    g = np.arange(0.0, 1.0, 0.005)
    x, y = np.meshgrid(g, g, indexing="ij")
    pts = np.column_stack([x.ravel(), y.ravel(), np.full(x.size, z)])
    x0, x1, y0, y1 = hole
    inside = (pts[:, 0] > x0) & (pts[:, 0] < x1) & (pts[:, 1] > y0) & (pts[:, 1] < y1)
    return pts[~inside]


def test_an_enclosed_hole_in_a_flat_support_is_filled_at_its_height():
    pts = _table()
    new = fill_support_holes(pts)
    assert len(new) > 0
    assert np.allclose(new[:, 2], -0.03, atol=1e-6)
    # every 1 cm cell of the 20 x 20 cm gap now has points, old or new
    both = np.concatenate([pts, new])
    gx = np.floor((both[:, 0] - 0.4) / 0.01).astype(int)
    gy = np.floor((both[:, 1] - 0.4) / 0.01).astype(int)
    covered = {(a, b) for a, b in zip(gx, gy) if 0 <= a < 20 and 0 <= b < 20}
    assert len(covered) == 400


def test_an_open_border_or_an_uneven_rim_is_left_alone():
    assert len(fill_support_holes(_table(hole=(0.8, 1.1, 0.4, 0.6)))) == 0  # open to the edge: not a hole
    pts = _table()
    ramp = pts[:, 0] > 0.5
    pts[ramp, 2] += 0.2 * (pts[ramp, 0] - 0.5)  # the rim climbs 2-4 cm across the gap
    assert len(fill_support_holes(pts)) == 0
    assert len(fill_support_holes(_table(hole=(0.1, 0.9, 0.1, 0.9)))) == 0  # 64 dm^2: a real opening
