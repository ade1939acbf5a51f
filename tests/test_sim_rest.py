"""The rest check's static meshes cut down to the objects' neighbourhood (sim.rest._keep_near)."""

from __future__ import annotations

import numpy as np
import pytest

newton = pytest.importorskip("newton")
wp = pytest.importorskip("warp")

from rose_usd.sim.rest import NEAR_M, _keep_near  # noqa: E402


def _grid(n: int, size: float, z: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """A flat square of 2 n^2 triangles, ``size`` m across, centred on the origin."""
    xs = np.linspace(-size / 2, size / 2, n + 1)
    gx, gy = np.meshgrid(xs, xs)
    vertices = np.column_stack([gx.ravel(), gy.ravel(), np.full(gx.size, z)])
    i = np.arange(n)[:, None] * (n + 1) + np.arange(n)[None, :]
    a, b, c, d = i, i + 1, i + n + 1, i + n + 2
    faces = np.concatenate([np.stack([a, b, d], -1).reshape(-1, 3), np.stack([a, d, c], -1).reshape(-1, 3)])
    return vertices, faces


def test_only_triangles_near_the_objects_are_kept_and_a_far_mesh_stops_colliding():
    builder = newton.ModelBuilder()
    v, f = _grid(40, 2.0)  # 5 cm cells
    floor = builder.add_shape_mesh(
        -1, xform=wp.transform((0.5, 0.0, 0.0), wp.quat_identity()), mesh=newton.Mesh(v, f.ravel())
    )
    far = builder.add_shape_mesh(
        -1, xform=wp.transform((5.0, 0.0, 0.0), wp.quat_identity()), mesh=newton.Mesh(*_grid(4, 0.2))
    )
    body = builder.add_body(xform=wp.transform((0.512, 0.012, 0.05), wp.quat_identity()))
    builder.add_shape_box(body, hx=0.05, hy=0.05, hz=0.05)
    lo, hi = np.array([0.462, -0.038, 0.0]), np.array([0.562, 0.062, 0.1])  # the box, in the world

    _keep_near(newton, builder, (lo, hi), NEAR_M)

    kept = builder.shape_source[floor]
    tris = np.asarray(kept.vertices)[np.asarray(kept.indices).reshape(-1, 3)] + np.array([0.5, 0.0, 0.0])
    # every kept triangle reaches within NEAR_M of the box: the 5 cm cells over x 0.412-0.612 and
    # y -0.088-0.112, 5 x 5 of them
    assert np.all(tris.max(axis=1)[:, :2] >= (lo - NEAR_M)[:2]) and np.all(tris.min(axis=1)[:, :2] <= (hi + NEAR_M)[:2])
    assert len(tris) == 2 * 5 * 5
    collides = int(newton.ShapeFlags.COLLIDE_SHAPES)
    assert not builder.shape_flags[far] & collides
    assert builder.shape_flags[floor] & collides
    builder.finalize(device="cpu")


def test_warp_starts_once_when_threads_ask_for_it_together():
    """The gate starts Newton's rest check on a thread while its renders begin: both ask for
    Warp in a fresh process at once. Two ``wp.init()`` running side by side build two runtimes,
    and the second marks every kernel module modified under a load in progress (Warp's
    ``KeyError: 1`` in ``Module.load``, seen in CI); ``engine.warp()`` starts it once."""
    import subprocess
    import sys

    script = """
import threading
import warp._src.context as ctx
from rose_usd.sim import engine
built, init = [], ctx.Runtime.__init__
def counted(self, *a, **k):
    built.append(1)
    init(self, *a, **k)
ctx.Runtime.__init__ = counted
start = threading.Barrier(4)
def ask():
    start.wait()
    engine.warp()
threads = [threading.Thread(target=ask) for _ in range(4)]
[t.start() for t in threads]
[t.join() for t in threads]
print(len(built))
"""
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split()[-1] == "1"
