"""Objects are put in contact with what supports them (object.settle), up or down, stacks from
the lowest up; what is far from any contact is left alone."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import trimesh

from rose_usd.core import se3
from rose_usd.object.settle import CLEARANCE_M, settle
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


def test_a_stack_settles_from_the_lowest_up():
    base, top = _box("Base", -0.003), _box("Top", 0.06 + 0.004)  # base sunk 3 mm, top 4 mm over it
    settle([top, base], _table())
    assert _bottom(base) == pytest.approx(CLEARANCE_M, abs=2e-4)
    assert _bottom(top) == pytest.approx(_bottom(base) + 0.06 + CLEARANCE_M, abs=2e-4)  # on the settled base
