"""The tsdf scene's support-hole filling: the table under an object that never moved is never
seen, and the collider must not have a hole there (Newton dropped a box through one)."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from rose_usd.scene.fused import fill_support_holes


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


def test_a_pad_lays_the_support_flat_under_an_object_and_leaves_the_rest():
    """Bumps of 5-11 mm under a resting object (MegaSaM's table under push-box) are replaced by a
    flat pad at the surface's height over its footprint grown by the margin; the table around it,
    and what stands above the band, keep their points."""
    from rose_usd.scene.fused import SupportPad, _footprint, lay_pads

    pts = _table(z=0.0, hole=(0, 0, 0, 0))
    rng = np.random.default_rng(0)
    under = np.linalg.norm(pts[:, :2] - 0.5, axis=1) < 0.06
    pts[under, 2] += rng.uniform(0.005, 0.011, under.sum())
    wall = np.column_stack([np.full(20, 0.5), np.full(20, 0.5), np.linspace(0.05, 0.1, 20)])  # above the band
    pts = np.concatenate([pts, wall])
    seen = 0.5 + 0.04 * np.column_stack([np.cos(np.linspace(0, 2 * np.pi, 90)), np.sin(np.linspace(0, 2 * np.pi, 90))])
    pad = SupportPad("Can", 0.0, _footprint(seen, 0.02, 0.004), 0.004)
    # the footprint: the seen disc (r 4 cm) grown by 2 cm, on a 4 mm grid
    r = np.linalg.norm(pad.xy - 0.5, axis=1)
    assert r.max() < 0.06 + 0.006 and pad.area_m2 > 0.9 * np.pi * 0.06**2
    colors, normals = np.full((len(pts), 3), 0.5), np.tile([0.0, 0.0, 1.0], (len(pts), 1))
    out, out_colors, out_normals, replaced = lay_pads(pts, colors, normals, [pad])
    assert replaced > 0 and len(out) == len(out_colors) == len(out_normals)
    inside = np.linalg.norm(out[:, :2] - 0.5, axis=1) < 0.055
    low = inside & (out[:, 2] < 0.03)
    assert np.abs(out[low, 2]).max() < 1e-9  # flat where the bumps were
    assert (out[:, 2] >= 0.05).sum() == 20  # the wall above the band stays
    far = np.linalg.norm(pts[:, :2] - 0.5, axis=1) > 0.1
    assert len(np.intersect1d(pts[far].view([("", float)] * 3), out.view([("", float)] * 3))) == far.sum()


def test_the_wrapped_collider_is_exactly_flat_over_a_pad_and_still_valid():
    """The alpha wrap of a flat pad is flat only to its vertices' scatter: on push-mug's
    MegaSaM pad its top dipped up to 0.48 mm between 13 vertices, triangles tilted 0.9 deg, and
    Newton's mug rocked on the ridge (1.8 deg, 5.2 mm in 1 s; 0.06 deg once flattened). After
    the wrap, the top over a pad's footprint is set at the pad's height; the rest is untouched
    and the collider stays closed and free of self-intersections."""
    import trimesh

    from rose_usd.core.metrics import SurfaceDistance
    from rose_usd.core.watertight import collider_problems
    from rose_usd.geometry.mesh import self_intersects
    from rose_usd.geometry.wrap import alpha_wrap
    from rose_usd.scene.fused import SupportPad, _footprint, flatten_pads

    rng = np.random.default_rng(1)
    g = np.arange(0.0, 0.4, 0.004)
    x, y = np.meshgrid(g, g, indexing="ij")
    top = np.column_stack([x.ravel(), y.ravel(), rng.normal(0.0, 0.0007, x.size)])  # a table, noisy as fused depth
    pad = SupportPad("Mug", 0.0, _footprint(0.2 + 0.04 * rng.uniform(-1, 1, (200, 2)), 0.03, 0.004), 0.004)
    top = np.concatenate(
        [top[cKDTree(pad.xy).query(top[:, :2])[0] > 0.003], np.column_stack([pad.xy, np.zeros(len(pad.xy))])]
    )
    vertices, faces = alpha_wrap(np.concatenate([top - [0, 0, 0.002], top - [0, 0, 0.022]]), 0.03, 0.002)
    inner = _footprint(0.2 + 0.04 * np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]]), 0.02, 0.004)  # well inside the pad
    probe = np.column_stack([inner, np.full(len(inner), 0.1)])
    before = probe[:, 2] - SurfaceDistance(vertices, faces).drop(probe)
    # a vertex of the wrap over the footprint 6 mm off the pad (beyond the band kept around it)
    # is still the pad's: nothing else was wrapped there
    inside = np.flatnonzero((cKDTree(pad.xy).query(vertices[:, :2])[0] < 0.003) & (np.abs(vertices[:, 2]) < 0.005))
    vertices = vertices.copy()
    vertices[inside[0], 2] = 0.006
    flat, moved = flatten_pads(vertices, faces, [pad], band_m=0.004, over_band_m=0.01)
    after = probe[:, 2] - SurfaceDistance(flat, faces).drop(probe)
    assert np.ptp(before) > 1e-3  # the wrap alone is not flat there (3 mm here)
    # flat to the ray cast's float32 precision (0.01 mm over the 10 cm drop)
    assert moved > 0 and np.abs(after).max() < 5e-5, (np.ptp(before), np.abs(after).max())
    far = cKDTree(pad.xy).query(vertices[:, :2])[0] > 0.08  # beyond a triangle of the pad
    assert np.array_equal(flat[far], vertices[far])  # nothing outside the pad moves
    assert (flat[:, 2] < -0.01).sum() == (vertices[:, 2] < -0.01).sum() and np.array_equal(
        flat[vertices[:, 2] < -0.01], vertices[vertices[:, 2] < -0.01]
    )  # nor the slab's underside
    assert not collider_problems(flat, faces) and not self_intersects(flat, faces)
    assert trimesh.Trimesh(flat, faces, process=False).is_watertight


def test_only_triangles_facing_a_camera_are_textured_and_the_rest_keep_their_vertices():
    """A slab seen from above and one side: its top and that side face the cameras; its underside
    and the far sides do not (a closed mesh hides them from every camera)."""
    import trimesh

    from rose_usd.geometry.mesh import faces_facing, submesh

    slab = trimesh.creation.box(extents=[1.0, 1.0, 0.02])
    centers = np.array([[0.0, -1.0, 1.0], [1.0, -1.2, 0.8]])  # above, in front (-y), the second right of it (+x)
    facing = faces_facing(slab.vertices, slab.faces, centers)
    normals = slab.face_normals
    assert (
        facing[normals[:, 2] > 0.9].all() and facing[normals[:, 1] < -0.9].all() and facing[normals[:, 0] > 0.9].all()
    )
    assert (
        not facing[normals[:, 2] < -0.9].any()
        and not facing[normals[:, 1] > 0.9].any()
        and not facing[normals[:, 0] < -0.9].any()
    )
    v, f = submesh(slab.vertices, slab.faces, facing)
    assert len(f) == facing.sum() and f.max() == len(v) - 1
    assert np.allclose(v[f], slab.vertices[slab.faces[facing]])


def _plane_depth(world_from_cv: np.ndarray, K: np.ndarray, w: int, h: int) -> np.ndarray:
    """Metric depth of the plane z = 0 (0 where a ray misses it)."""
    v, u = np.mgrid[0:h, 0:w]
    rays = np.stack([u, v, np.ones_like(u)], axis=-1) @ np.linalg.inv(K).T @ world_from_cv[:3, :3].T
    t = -world_from_cv[2, 3] / rays[..., 2]
    return np.where(t > 0, t, 0.0)


def test_the_fused_surface_comes_out_the_same_from_the_same_frames():
    # Open3D allocates the grid's blocks from several threads: before the sort, the same frames
    # gave the same points in a different order, which everything downstream would take in
    from rose_usd.core import se3
    from rose_usd.scene.fused import Fusion

    w, h = 160, 120
    K = np.array([[120.0, 0, 80], [0, 120.0, 60], [0, 0, 1]])
    rgb = np.tile(np.arange(w, dtype=np.uint8)[None, :, None], (h, 1, 3))
    frames = []
    for yaw in np.radians(np.arange(0, 360, 45)):
        eye = np.array([0.8 * np.cos(yaw), 0.8 * np.sin(yaw), 0.6])
        forward = -eye / np.linalg.norm(eye)
        right = np.cross(forward, [0.0, 0.0, 1.0])
        right /= np.linalg.norm(right)
        pose = se3.make_pose(np.column_stack([right, np.cross(forward, right), forward]), eye)
        frames.append((_plane_depth(pose, K, w, h), pose))
    runs = []
    for _ in range(3):
        fusion = Fusion(0.01, 3.0)
        for depth, pose in frames:
            fusion.add(depth, rgb, K, pose)
        runs.append((*fusion.oriented_points(), *fusion.mesh()))
    assert len(runs[0][0]) > 10_000
    for other in runs[1:]:
        for a, b in zip(runs[0], other):
            assert np.array_equal(a, b)
