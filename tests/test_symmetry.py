"""Shape symmetries of meshes and the choice among them by colour (geometry.symmetry)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import trimesh

from rose_usd.core import se3
from rose_usd.core.color import linear_to_srgb8, srgb8_to_linear
from rose_usd.geometry.symmetry import coloured_samples, shape_symmetries, symmetric_look, symmetry_scores
from rose_usd.trajectory.colour_turns import symmetry_path

FACE_COLOURS = np.array(
    [[220, 40, 40], [40, 200, 60], [40, 60, 220], [230, 220, 40], [200, 60, 200], [40, 210, 210]], np.uint8
)


def _faceted_box(extents) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A box with each of its 6 sides' 4 corners its own (so vertex colours can differ per side):
    vertices (24, 3), faces (12, 3) wound outwards, the side of each vertex (24,)."""
    box = trimesh.creation.box(extents=extents)
    vertices, faces, side = [], [], []
    groups = trimesh.grouping.group_rows(np.round(box.face_normals, 6), require_count=2)
    for k, pair in enumerate(groups):
        corners = np.unique(box.faces[pair])
        index = {int(c): len(vertices) + j for j, c in enumerate(corners)}
        vertices.extend(box.vertices[corners])
        side.extend([k] * len(corners))
        faces.extend([[index[int(c)] for c in tri] for tri in box.faces[pair]])
    return np.asarray(vertices), np.asarray(faces), np.asarray(side)


def _turned(vertices: np.ndarray, pose: np.ndarray) -> np.ndarray:
    return se3.transform_points(pose, vertices)


GENERIC = se3.make_pose(
    se3.rotation_about(np.array([0.3, -0.8, 0.5]) / np.linalg.norm([0.3, -0.8, 0.5]), 0.7), np.array([0.1, -0.2, 0.05])
)


@pytest.mark.parametrize(("extents", "count"), [((1, 1, 1), 24), ((1, 1, 2), 8), ((1, 2, 3), 4)])
def test_a_box_has_the_turns_of_its_sides(extents, count):
    vertices, faces, _ = _faceted_box(np.asarray(extents) * 0.05)
    vertices = _turned(vertices, GENERIC)  # the mesh's frame is not the box's
    syms = shape_symmetries(vertices, faces)
    assert len(syms) == count
    np.testing.assert_allclose(syms[0], np.eye(4), atol=1e-9)
    tree_points = np.round(vertices, 9)
    for sym in syms:  # each maps the corners onto corners
        moved = se3.transform_points(sym, vertices)
        d = np.linalg.norm(moved[:, None] - tree_points[None], axis=-1).min(axis=1)
        assert d.max() < 1e-6
        np.testing.assert_allclose(sym[:3, :3] @ sym[:3, :3].T, np.eye(3), atol=1e-9)


def test_a_shape_without_symmetry_has_the_identity_alone():
    cube = trimesh.creation.box(extents=(0.08, 0.08, 0.08))
    bump = trimesh.creation.box(extents=(0.02, 0.02, 0.03))
    bump.apply_translation((0.02, 0.01, 0.05))
    lopsided = trimesh.util.concatenate([cube, bump])
    syms = shape_symmetries(lopsided.vertices, lopsided.faces)
    assert len(syms) == 1
    np.testing.assert_allclose(syms[0], np.eye(4))


def _painted(vertices, faces, side, world_from_object, K, shape) -> np.ndarray:
    """The box drawn side by side, farthest first (painter's order), each side filled flat with its
    colour: an image made without the module under test."""
    image = np.full((*shape, 3), 128, np.uint8)
    cam = se3.transform_points(world_from_object, vertices)
    order = []
    for k in range(6):
        corners = np.flatnonzero(side == k)
        tri = faces[np.isin(faces, corners).all(axis=1)][0]
        normal = np.cross(cam[tri[1]] - cam[tri[0]], cam[tri[2]] - cam[tri[0]])
        if normal @ cam[tri[0]] < 0:  # faces the camera
            order.append((cam[corners, 2].mean(), k, corners))
    for _, k, corners in sorted(order, reverse=True):
        px = cam[corners, :2] / cam[corners, 2:] * K[0, 0] + K[:2, 2]
        hull = cv2.convexHull(np.round(px).astype(np.int32))
        cv2.fillConvexPoly(image, hull, tuple(int(c) for c in FACE_COLOURS[k]))
    return image


@pytest.mark.parametrize("true_index", [0, 5, 17])
def test_colours_pick_the_turn_the_video_shows(true_index):
    vertices, faces, side = _faceted_box((0.08, 0.08, 0.08))
    linear = srgb8_to_linear(FACE_COLOURS[side])
    samples = coloured_samples(vertices, faces, linear_colours=linear, count=20000)
    syms = shape_symmetries(vertices, faces)
    assert len(syms) == 24
    K = np.array([[500.0, 0, 160], [0, 500.0, 120], [0, 0, 1]])
    turn = se3.rotation_about(np.array([1.0, 1.0, 0.2]) / np.linalg.norm([1.0, 1.0, 0.2]), 0.9)
    fitted = se3.make_pose(turn, np.array([0.0, 0.0, 0.5]))  # what a silhouette fit found
    truth = fitted @ syms[true_index]  # the same outline, another side towards the camera
    image = _painted(vertices, faces, side, truth, K, (240, 320))
    mask = np.any(image != 128, axis=-1)
    scores = symmetry_scores(symmetric_look(samples, syms), fitted, np.eye(4), K, image, mask)
    assert scores is not None and int(np.argmax(scores)) == true_index
    assert scores[true_index] > 0.95
    assert np.sort(scores)[-2] < scores[true_index] - 0.2


def test_texture_colours_follow_the_uv():
    vertices = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    uv = vertices[:, :2].copy()  # origin bottom-left
    image = np.zeros((64, 64, 3), np.uint8)
    image[:, :32] = (255, 0, 0)  # left half red
    image[:32, :, 2] = 255  # the image's top rows (uv's v near 1) get blue
    s = coloured_samples(vertices, faces, uv=uv, image=image, count=4000)
    inner = (np.abs(s.points[:, 0] - 0.5) > 0.05) & (np.abs(s.points[:, 1] - 0.5) > 0.05)
    red = s.colours[:, 0] > 128
    blue = s.colours[:, 2] > 128
    assert np.array_equal(red[inner], s.points[inner, 0] < 0.5)
    assert np.array_equal(blue[inner], s.points[inner, 1] > 0.5)


def test_vertex_colours_come_back_as_srgb8():
    vertices, faces, side = _faceted_box((0.05, 0.05, 0.05))
    s = coloured_samples(vertices, faces, linear_colours=srgb8_to_linear(FACE_COLOURS[side]), count=3000)
    assert np.abs(s.colours[:, None] - FACE_COLOURS[None].astype(float)).sum(-1).min(axis=1).max() < 2
    assert linear_to_srgb8(srgb8_to_linear(FACE_COLOURS)).tolist() == FACE_COLOURS.tolist()


def _cube_symmetries() -> np.ndarray:
    vertices, faces, _ = _faceted_box((0.08, 0.08, 0.08))
    return shape_symmetries(vertices, faces)


def _spin(angles_rad) -> np.ndarray:
    return np.stack([se3.make_pose(se3.rotation_about(np.array([0.0, 0.0, 1.0]), a), np.zeros(3)) for a in angles_rad])


def _quarter_about_z(syms: np.ndarray) -> int:
    want = se3.rotation_about(np.array([0.0, 0.0, 1.0]), np.pi / 2)
    return int(np.argmin([np.abs(s[:3, :3] - want).sum() for s in syms]))


def test_a_track_that_jumps_a_quarter_turn_is_turned_back():
    syms = _cube_symmetries()
    q = _quarter_about_z(syms)
    truth = np.linspace(0.0, 0.5, 30)  # the cube turns slowly about z
    tracked = truth.copy()
    tracked[12:] -= np.pi / 2  # the track jumps to another orientation with the same outline
    path = symmetry_path(_spin(tracked), syms, np.zeros((30, len(syms))), turn_cost=0.5)
    assert path[:12].tolist() == [0] * 12
    assert path[12:].tolist() == [q] * 18
    fixed = np.einsum("nij,njk->nik", _spin(tracked), syms[path])
    np.testing.assert_allclose(fixed, _spin(truth), atol=1e-9)


def test_a_track_that_lags_a_turn_follows_the_colours():
    syms = _cube_symmetries()
    q = _quarter_about_z(syms)
    tracked = np.zeros(40)  # the hand turns the cube a quarter turn over frames 10-20; the track stays
    scores = np.full((40, len(syms)), 0.1)
    scores[::3, 0] = np.where(np.arange(0, 40, 3) < 20, 0.8, 0.2)
    scores[::3, q] = np.where(np.arange(0, 40, 3) < 20, 0.2, 0.8)
    path = symmetry_path(_spin(tracked), syms, scores, turn_cost=0.5)
    assert path[0] == 0 and path[-1] == q
    assert set(path[:10].tolist()) == {0} and set(path[22:].tolist()) == {q}
    # with colours that say nothing, nothing changes
    assert not symmetry_path(_spin(tracked), syms, np.zeros_like(scores), turn_cost=0.5).any()
