"""Objects are put in contact with what supports them (sim.settle), up or down, stacks from
the lowest up; what is far from any contact is left alone."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import trimesh

from rose_usd.core import se3
from rose_usd.sim.settle import CLEARANCE_M, settle
from rose_usd.usd.geom import MeshData


def _table():
    slab = trimesh.creation.box(extents=(0.6, 0.6, 0.2))
    slab.apply_translation([0.0, 0.0, -0.1])  # top at z = 0
    return np.asarray(slab.vertices), np.asarray(slab.faces)


def _box(name: str, bottom_z: float, size: float = 0.06):
    box = trimesh.creation.box(extents=(size, size, size))  # object frame at its center
    return SimpleNamespace(
        name=name,
        mesh=MeshData(np.asarray(box.vertices), np.asarray(box.faces)),
        world_from_object_0=se3.make_pose(np.eye(3), np.array([0.0, 0.0, bottom_z + 0.5 * size])),
    )


def _bottom(model) -> float:
    return float(se3.transform_points(model.world_from_object_0, model.mesh.vertices)[:, 2].min())


@pytest.mark.parametrize("bottom_z", [-0.004, 0.006])
def test_an_object_inside_or_above_the_table_is_put_on_it(bottom_z):
    model = _box("Box", bottom_z)
    moves = settle([model], _table())
    assert _bottom(model) == pytest.approx(CLEARANCE_M, abs=2e-4)
    assert moves["Box"] == pytest.approx(CLEARANCE_M - bottom_z, abs=2e-4)


def test_contact_and_what_is_far_from_contact_are_left_alone():
    touching, held = _box("Touching", 0.0005), _box("Held", 0.05)
    moves = settle([touching, held], _table())
    assert moves == {"Touching": 0.0, "Held": 0.0}
    sunk = _box("Sunk", -0.05)
    assert np.isnan(settle([sunk], _table())["Sunk"])  # a wrong pose, not a contact error: the caller warns


def test_the_collider_not_the_mesh_is_put_on_the_table():
    """A box whose mesh touches the table but whose collider (CoACD's parts bulge past a mesh)
    reaches 0.7 mm into it is lifted until the collider clears it; a penetration under SUNK_M is
    contact."""
    model = _box("Box", 0.0)
    bulge = model.mesh.vertices[model.mesh.vertices[:, 2] < 0] - np.array([0.0, 0.0, 0.0007])
    moves = settle([model], _table(), collider_points={"Box": bulge})
    assert moves["Box"] == pytest.approx(0.0007 + CLEARANCE_M, abs=2e-4)
    lowest = se3.transform_points(model.world_from_object_0, bulge)[:, 2].min()
    assert lowest == pytest.approx(CLEARANCE_M, abs=2e-4)
    assert settle([_box("Box", -0.0001)], _table()) == {"Box": 0.0}


def test_a_stack_settles_from_the_lowest_up():
    base, top = _box("Base", -0.003), _box("Top", 0.06 + 0.004)  # base sunk 3 mm, top 4 mm over it
    settle([top, base], _table())
    assert _bottom(base) == pytest.approx(CLEARANCE_M, abs=2e-4)
    assert _bottom(top) == pytest.approx(_bottom(base) + 0.06 + CLEARANCE_M, abs=2e-4)  # on the settled base


def test_an_object_pressed_into_a_neighbour_beside_it_is_pushed_out_sideways():
    """A box resting on the table whose side sinks 3 mm into a block beside it (a cup the scene
    holds, next to the ball that is the object): it is moved out sideways and stays on the table,
    not lifted 3 mm over it (from there it fell against the block's slope and rolled away)."""
    table_v, table_f = _table()
    block = trimesh.creation.box(extents=(0.1, 0.3, 0.1))
    block.apply_translation([0.08, 0.0, 0.05])  # its face at x = 0.03
    scene = trimesh.util.concatenate([trimesh.Trimesh(table_v, table_f), block])
    model = _box("Box", 0.0003)
    model.world_from_object_0[0, 3] = 0.003  # the box's side at x = 0.033: 3 mm into the block
    settle([model], (np.asarray(scene.vertices), np.asarray(scene.faces)))
    world = se3.transform_points(model.world_from_object_0, model.mesh.vertices)
    assert world[:, 0].max() <= 0.03 + 1e-4  # out of the block
    assert _bottom(model) == pytest.approx(0.0003, abs=3e-4)  # still on the table
