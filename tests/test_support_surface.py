"""The support surface under each place (geometry.support): a table that is not the world's
z = 0 plane (tilted, with a notebook on it) still gives every point its height above what is
under it."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from rose_usd.core import se3
from rose_usd.geometry.support import SupportSurface

K = np.array([[400.0, 0.0, 160.0], [0.0, 400.0, 120.0], [0.0, 0.0, 1.0]])
W, H = 320, 240


def _render_depth(mesh: trimesh.Trimesh, world_from_cv: np.ndarray) -> np.ndarray:
    """Depth along the optical axis [m] of ``mesh`` seen by an OpenCV camera (0 where nothing)."""
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(
        o3d.core.Tensor(np.asarray(mesh.vertices, np.float32)), o3d.core.Tensor(np.asarray(mesh.faces, np.uint32))
    )
    v, u = np.mgrid[0:H, 0:W]
    dirs = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u, float)], axis=-1)
    world_dirs = dirs.reshape(-1, 3) @ world_from_cv[:3, :3].T
    origins = np.broadcast_to(world_from_cv[:3, 3], world_dirs.shape)
    rays = o3d.core.Tensor(np.concatenate([origins, world_dirs], axis=1).astype(np.float32))
    t = scene.cast_rays(rays)["t_hit"].numpy().reshape(H, W)  # along dirs, whose z is 1: t is the depth
    return np.where(np.isfinite(t), t, 0.0).astype(np.float32)


def _scene(tilt: float, notebook_mm: float, box_h: float) -> trimesh.Trimesh:
    """A table tilted by ``tilt`` (rise per metre along x) with a notebook ``notebook_mm`` thick on
    its x < -0.05 part and a box ``box_h`` tall at the origin."""
    grid = trimesh.creation.box(extents=(0.8, 0.8, 0.02)).subdivide().subdivide().subdivide()
    top = grid.vertices[:, 2] > 0
    v = grid.vertices.copy()
    v[:, 2] = np.where(top, 0.0, -0.02)
    table = trimesh.Trimesh(v, grid.faces)
    book = trimesh.creation.box(extents=(0.25, 0.3, notebook_mm / 1000))
    book.apply_translation((-0.2, 0.0, notebook_mm / 2000))
    box = trimesh.creation.box(extents=(0.06, 0.06, box_h))
    box.apply_translation((0.0, 0.0, box_h / 2))
    scene = trimesh.util.concatenate([table, book, box])
    scene.vertices[:, 2] += tilt * scene.vertices[:, 0]
    return scene


def test_heights_are_over_the_surface_under_each_point_not_over_z0():
    """The table rises 3 cm over a metre (1.7 deg off the world's plane) and a 6 mm notebook
    lies on it: over z = 0 the table reads -9 to +9 mm and the notebook more; over the support
    surface they read within 1.5 mm of 0, and the box's top its own 3 cm."""
    scene = _scene(tilt=0.03, notebook_mm=6.0, box_h=0.03)
    eyes = [(0.35, -0.45, 0.35), (-0.3, -0.5, 0.3), (0.05, -0.55, 0.45), (0.4, 0.3, 0.4)]
    poses = np.stack([se3.look_at(e, (0.0, 0.0, 0.0)) for e in eyes])
    depths = [_render_depth(scene, p) for p in poses]
    support = SupportSurface(lambda t: depths[t], poses, K, list(range(len(poses))), band_m=0.03)
    table = np.array([[0.15, 0.1, 0.0045], [-0.1, -0.2, -0.003], [0.2, -0.15, 0.006]])  # on the tilted table
    notebook = np.array([[-0.2, 0.05, 0.006 - 0.006], [-0.25, -0.1, 0.006 - 0.0075]])
    box_top = np.array([[0.0, 0.0, 0.03]])
    assert np.all(np.abs(support.height_above(table)) < 0.0015)
    assert np.all(np.abs(support.height_above(notebook)) < 0.0015)
    assert abs(float(support.height_above(box_top)[0]) - 0.03) < 0.002  # under the box: filled from around it
    assert abs(table[0, 2] - table[2, 2]) > 0.001  # they differ over z = 0


def test_a_flat_table_is_z0_and_nothing_seen_is_zero():
    scene = _scene(tilt=0.0, notebook_mm=0.001, box_h=0.05)
    pose = se3.look_at((0.3, -0.4, 0.4), (0.0, 0.0, 0.0))
    depth = _render_depth(scene, pose)
    support = SupportSurface(lambda t: depth, pose[None], K, [0])
    pts = np.array([[0.1, 0.1, 0.0], [-0.12, 0.05, 0.0]])
    assert np.all(np.abs(support.height_of(pts)) < 0.0005)
    empty = SupportSurface(lambda t: np.zeros((H, W), np.float32), pose[None], K, [0])
    assert float(empty.height_of(pts).max()) == 0.0 and empty.relief_mm() == [0.0, 0.0, 0.0]


def test_ransac_finds_the_plane_and_repeats():
    """A 20 x 20 cm table at z = 0.3 m (2 000 points, 1 mm noise) among 1 000 points strewn over a
    1 m cube: the plane within 2 deg and 2 mm (a three-point hypothesis: fit_planes refits it), all
    its points counted, and the same plane from the same seed."""
    import numpy as np

    from rose_usd.capture.gravity import ransac_plane

    rng = np.random.default_rng(5)
    table = np.column_stack([rng.uniform(-0.1, 0.1, (2000, 2)), 0.3 + rng.normal(0, 0.001, 2000)])
    clutter = rng.uniform(-0.5, 0.5, (1000, 3))
    points = np.vstack([table, clutter])
    normal, offset, count = ransac_plane(points, 0.005, np.random.default_rng(0))
    normal, offset = (normal, offset) if normal[2] > 0 else (-normal, -offset)
    assert np.degrees(np.arccos(min(1.0, normal[2]))) < 2.0
    assert abs(offset - 0.3) < 0.002
    assert 2000 <= count < 2000 + 20
    again = ransac_plane(points, 0.005, np.random.default_rng(0))
    assert again[2] == count and abs(abs(again[1]) - abs(offset)) == 0.0


def test_a_plane_is_one_connected_patch_not_a_slab_through_two_surfaces():
    """A sparse, noisy map's near table (400 points, 1.2 cm noise) and a counter 1 m beyond it and
    15 cm higher: one RANSAC slab through both is tilted 8 deg and holds the most points; as
    connected patches each surface is its own plane, within 2 deg of level."""
    from rose_usd.capture.gravity import fit_planes

    rng = np.random.default_rng(1)

    def patch(x0, z):
        p = np.column_stack([rng.uniform(x0, x0 + 0.3, 400), rng.uniform(-0.15, 0.15, 400), np.full(400, z)])
        p[:, 2] += rng.normal(0, 0.012, 400)
        return p

    points = np.vstack([patch(0.0, 0.0), patch(1.0, 0.15)])
    viewpoint = np.array([0.0, 0.0, 1.0])

    def tilts(planes):
        return [np.degrees(np.arccos(min(1.0, abs(p.normal[2])))) for p in planes]

    slab = fit_planes(points, viewpoint, min_points=50, distance_m=0.03)
    assert tilts(slab)[0] > 6.0 and slab[0].inliers > 600
    patches = fit_planes(points, viewpoint, min_points=50, distance_m=0.03, connected_m=0.1)
    assert len(patches) == 2 and max(tilts(patches)) < 2.0
    assert sorted(abs(p.offset) for p in patches) == pytest.approx([0.0, 0.15], abs=0.01)


def test_the_planes_scatter_is_the_gravity_uncertainty():
    """Parallel planes agree (0 deg); planes 0 and 6 deg off up, equally weighted, scatter by
    sqrt(18) = 4.24 deg RMS; a wall (90 deg) is not a horizontal plane and does not count."""
    from rose_usd.capture.gravity import Plane, disagreement_deg

    up = np.array([0.0, 0.0, 1.0])
    tilted = np.array([np.sin(np.radians(6.0)), 0.0, np.cos(np.radians(6.0))])
    wall = np.array([1.0, 0.0, 0.0])
    assert disagreement_deg(up, [Plane(up, 0.0, 100, 0.0), Plane(up, 0.7, 50, 0.0)]) == 0.0
    planes = [Plane(up, 0.0, 100, 0.0), Plane(tilted, 0.1, 100, 0.0), Plane(wall, 1.0, 500, 0.0)]
    assert disagreement_deg(up, planes) == pytest.approx(np.sqrt(18.0), abs=1e-6)
