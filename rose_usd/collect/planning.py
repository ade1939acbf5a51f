"""A collision-free joint-space route for the approach (home -> pre-grasp), around the scene.

The arm is points on each link's collision mesh (:func:`rose_usd.collect.author.link_meshes`,
about ``spacing_m`` apart, their vertices included), placed by the Panda's forward kinematics. A
configuration is clear when every point lies at least ``clearance_m`` outside the obstacles: the
scene collider and the objects where they stand at frame 0 (signed distances to their closed
meshes, Open3D's raycasting scene, five rays voting on the sign). The base link, bolted to the
support, is not checked, and a link whose points' bounding sphere keeps 5 cm from everything is
not checked point by point (``ArmChecker.clearance``).

The straight line in joint space is kept when it is clear at every ``step_rad`` (largest joint
change). Otherwise OMPL's RRTConnect searches around it in the arm's 7-D joint space within its
limits for ``time_s``, and OMPL's simplifier shortens what it found. OMPL's random numbers are
seeded once per process (``OMPL_SEED``), so a run that finds its routes within the time gives the
same routes every time. When it finds nothing (or
an end is itself not clear) the straight line stays and the route says so.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from rose_usd.core.metrics import SignedDistance
from rose_usd.sim import panda

ARM = 7
OMPL_SEED = 1


@functools.cache
def _seed_ompl() -> None:
    """Seed OMPL's random numbers, once per process (OMPL takes a seed only before its first
    random number)."""
    from ompl import util as ou

    ou.setLogLevel(ou.LOG_WARN)
    ou.RNG.setSeed(OMPL_SEED)


@dataclass(frozen=True)
class Route:
    """Joint-space waypoints (K, 7) from start to goal and how they were found."""

    waypoints: np.ndarray
    how: str
    """``straight`` (the line is clear), ``planned`` (OMPL went around), ``blocked`` (no clear route
    found: the straight line), ``start-blocked`` or ``goal-blocked`` (an end is not clear)."""
    clearance_m: float
    """The smallest clearance of the arm along the route, checked every ``step_rad`` [m]."""


class ArmChecker:
    """Clearance of the Panda arm (joint coordinates, its base at ``base_pose``) from obstacle meshes."""

    def __init__(
        self,
        base_pose: np.ndarray,
        obstacles: list[tuple[np.ndarray, np.ndarray]],
        *,
        clearance_m: float = 0.005,
        spacing_m: float = 0.015,
        skip_links: tuple[str, ...] = ("panda_link0",),
        seed: int = 0,
    ):
        from rose_usd.collect.author import link_meshes
        from rose_usd.core.metrics import sample_surface

        chain = panda.chain()
        rng = np.random.default_rng(seed)
        link_index, points, self._links = [], [], []
        for link, mesh in link_meshes().items():
            if link in skip_links:
                continue
            self._links.append(chain.index(link))
            tri = mesh.vertices[mesh.faces]
            area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1).sum()
            count = int(np.clip(area / spacing_m**2, 20, 2000))
            pts = np.concatenate([sample_surface(mesh.vertices, mesh.faces, count, rng), mesh.vertices])
            link_index.append(np.full(len(pts), chain.index(link)))
            points.append(pts)
        self.link_of_point = np.concatenate(link_index)
        self.points = np.concatenate(points)
        # each link's points in a sphere: links far from every obstacle need no point checked
        self._link_points = points
        self._centres = np.array([p.mean(axis=0) for p in points])
        self._radii = np.array([np.linalg.norm(p - c, axis=1).max() for p, c in zip(points, self._centres)])
        self.base_pose = np.asarray(base_pose, dtype=float)
        self.clearance_m = clearance_m
        vertices, faces, offset = [], [], 0
        for v, f in obstacles:
            vertices.append(np.asarray(v, dtype=float))
            faces.append(np.asarray(f) + offset)
            offset += len(v)
        self.distance = SignedDistance(np.concatenate(vertices), np.concatenate(faces), rays=5) if vertices else None
        self.checks = 0
        """Configurations checked so far."""

    def world_points(self, q: np.ndarray) -> np.ndarray:
        """The arm's points (..., P, 3) in the world for joint coordinates q (..., 9)."""
        links = self.base_pose @ panda.chain().forward(q)  # (..., L, 4, 4)
        frames = links[..., self.link_of_point, :, :]
        return np.einsum("...pij,pj->...pi", frames[..., :3, :3], self.points) + frames[..., :3, 3]

    def clearance(self, q: np.ndarray, *, exact_m: float = 0.05) -> np.ndarray:
        """The smallest signed distance [m] of the arm from the obstacles, per configuration (...,):
        exact where it is under ``exact_m``, else a lower bound at least that large (a link's
        points are checked only where the sphere around them comes within ``exact_m``)."""
        q = np.asarray(q, dtype=float)
        if q.shape[-1] == ARM:
            q = np.concatenate([q, np.broadcast_to(panda.HOME_Q[ARM:], q.shape[:-1] + (2,))], axis=-1)
        batch = q.shape[:-1]
        self.checks += int(np.prod(batch))
        if self.distance is None:
            return np.full(batch, np.inf)
        frames = (self.base_pose @ panda.chain().forward(q.reshape(-1, q.shape[-1])))[:, self._links]  # (B, K, 4, 4)
        centres = np.einsum("bkij,kj->bki", frames[..., :3, :3], self._centres) + frames[..., :3, 3]
        bound = self.distance(centres.reshape(-1, 3)).reshape(centres.shape[:2]) - self._radii  # (B, K)
        for k, local in enumerate(self._link_points):
            near = np.flatnonzero(bound[:, k] < exact_m)
            if len(near):
                f = frames[near, k]
                pts = np.einsum("bij,pj->bpi", f[:, :3, :3], local) + f[:, None, :3, 3]
                bound[near, k] = self.distance(pts.reshape(-1, 3)).reshape(len(near), -1).min(axis=1)
        return bound.min(axis=1).reshape(batch)

    def line_clearance(self, q_from: np.ndarray, q_to: np.ndarray, step_rad: float) -> float:
        """The smallest clearance [m] along the straight joint-space line, every ``step_rad``."""
        q_from, q_to = np.asarray(q_from, dtype=float)[:ARM], np.asarray(q_to, dtype=float)[:ARM]
        n = max(2, int(np.ceil(np.abs(q_to - q_from).max() / step_rad)) + 1)
        s = np.linspace(0.0, 1.0, n)[:, None]
        return float(self.clearance(q_from + s * (q_to - q_from)).min())

    def route(self, q_from: np.ndarray, q_to: np.ndarray, *, time_s: float = 3.0, step_rad: float = 0.02) -> Route:
        """A clear route from ``q_from`` to ``q_to`` (9,) or (7,): the straight line if it is clear,
        else OMPL's RRTConnect (simplified); the straight line marked blocked when neither works."""
        a, b = np.asarray(q_from, dtype=float)[:ARM], np.asarray(q_to, dtype=float)[:ARM]
        straight = np.stack([a, b])
        line = self.line_clearance(a, b, step_rad)
        if line >= self.clearance_m:
            return Route(straight, "straight", line)
        ends = self.clearance(straight)
        if ends[0] < self.clearance_m:
            return Route(straight, "start-blocked", line)
        if ends[1] < self.clearance_m:
            return Route(straight, "goal-blocked", line)
        found = _rrt_connect(self, a, b, time_s=time_s, step_rad=step_rad)
        if found is None:
            return Route(straight, "blocked", line)
        worst = min(self.line_clearance(p, q, step_rad) for p, q in zip(found[:-1], found[1:], strict=True))
        return Route(found, "planned", worst)


def _rrt_connect(checker: ArmChecker, a: np.ndarray, b: np.ndarray, *, time_s: float, step_rad: float):
    """OMPL's RRTConnect from ``a`` to ``b`` (7,) in the arm's joint limits; the simplified
    waypoints (K, 7), None when it found no exact solution in ``time_s``."""
    from ompl import base as ob
    from ompl import geometric as og

    _seed_ompl()
    chain = panda.chain()
    space = ob.RealVectorStateSpace(ARM)
    bounds = ob.RealVectorBounds(ARM)
    for j in range(ARM):
        bounds.setLow(j, float(chain.lower[j]))
        bounds.setHigh(j, float(chain.upper[j]))
    space.setBounds(bounds)
    setup = og.SimpleSetup(space)

    def clear(state) -> bool:
        return bool(checker.clearance(np.array([state[j] for j in range(ARM)]))[()] >= checker.clearance_m)

    setup.setStateValidityChecker(clear)
    start, goal = space.allocState(), space.allocState()
    for j in range(ARM):
        start[j], goal[j] = float(a[j]), float(b[j])
    setup.setStartAndGoalStates(start, goal)
    info = setup.getSpaceInformation()
    # OMPL's resolution is a fraction of the space's extent (the joint box's diagonal)
    info.setStateValidityCheckingResolution(step_rad / float(np.linalg.norm(chain.upper[:ARM] - chain.lower[:ARM])))
    setup.setPlanner(og.RRTConnect(info))
    setup.setup()
    solved = setup.solve(time_s)
    if not solved or not setup.haveExactSolutionPath():
        return None
    setup.simplifySolution()  # to the end, not for a time: the same path under any load
    return np.array([[s[j] for j in range(ARM)] for s in setup.getSolutionPath().getStates()])
