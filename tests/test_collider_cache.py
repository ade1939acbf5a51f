"""CoACD's parts of an object's collider are made once and read back from the cache after."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from rose_usd.sim import collider
from rose_usd.usd.geom import MeshData


def _l_shape() -> MeshData:
    """Two boxes joined at a corner: not convex, so CoACD splits it."""
    a = trimesh.creation.box((0.06, 0.02, 0.02))
    b = trimesh.creation.box((0.02, 0.06, 0.02))
    b.apply_translation((-0.02, 0.02, 0.0))
    solid = trimesh.boolean.union([a, b], engine="manifold")
    return MeshData(vertices=np.asarray(solid.vertices), faces=np.asarray(solid.faces))


def test_parts_are_made_once_and_read_back(tmp_path, monkeypatch):
    monkeypatch.setenv("ROSE_USD_CACHE", str(tmp_path))
    mesh = _l_shape()
    made = collider.coacd_parts(mesh)
    assert len(made) >= 2
    assert len(list((tmp_path / "coacd").glob("*.parts.npz"))) == 1

    def no_coacd(*args):
        raise AssertionError("CoACD ran again for a mesh it had split")

    monkeypatch.setattr(collider, "_run_coacd", no_coacd)
    again = collider.coacd_parts(mesh)
    assert len(again) == len(made)
    for a, b in zip(made, again):
        np.testing.assert_array_equal(a, b)

    moved = MeshData(vertices=mesh.vertices + 0.001, faces=mesh.faces)
    with pytest.raises(AssertionError, match="CoACD ran again"):
        collider.coacd_parts(moved)  # another mesh: another entry


def test_an_unreadable_entry_is_made_again(tmp_path, monkeypatch):
    monkeypatch.setenv("ROSE_USD_CACHE", str(tmp_path))
    mesh = _l_shape()
    made = collider.coacd_parts(mesh)
    (entry,) = (tmp_path / "coacd").glob("*.parts.npz")
    entry.write_bytes(b"not an npz")
    again = collider.coacd_parts(mesh)
    assert [p.tolist() for p in again] == [p.tolist() for p in made]
    assert collider.load_arrays(entry) is not None


def test_an_unwritable_cache_is_no_error(tmp_path, monkeypatch):
    monkeypatch.setenv("ROSE_USD_CACHE", "/proc/rose-cache")
    assert len(collider.coacd_parts(_l_shape())) >= 2
