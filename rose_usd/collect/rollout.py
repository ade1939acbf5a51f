"""One rollout: the plan executed in the simulated world, logged per control tick, and judged.

A rollout succeeds when the object stays in the hand (its pose in the tool frame drifts less
than ``max_drift_m`` / ``max_drift_deg`` from the grasp to the end of the follow), tracks its
reconstructed path (mean position error over the follow and the error at its end within the
limits), nothing became NaN, and neither robot nor object went deeper than
``max_penetration_m`` into the scene. ``reason`` names the first test that failed.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field

import numpy as np

from rose_usd.collect import motion
from rose_usd.collect.config import CollectConfig
from rose_usd.collect.world import World
from rose_usd.core import se3
from rose_usd.sim import panda

FLUNG_M = 100.0
"""A body this far from the world's origin [m] means the simulation diverged (the object of a
table-top scene flung kilometres in a rollout)."""


def diverged(body_q: np.ndarray) -> np.ndarray:
    """For poses (..., B, 7) (position, quaternion) of B bodies: whether the simulation diverged,
    some body's pose not finite or ``FLUNG_M`` from the origin (shape (...))."""
    q = np.asarray(body_q, dtype=float)
    bad = ~np.isfinite(q).all(axis=-1) | (np.abs(np.nan_to_num(q[..., :3], nan=0.0)).max(axis=-1) > FLUNG_M)
    return bad.any(axis=-1)


@dataclass(frozen=True)
class Perturbation:
    """How one rollout's object differs from the reconstruction."""

    offset_m: np.ndarray
    """(3,) shift of the object's start position [m] (horizontal)."""
    yaw_deg: float
    mass_kg: float
    friction: float


@dataclass
class Rollout:
    """A rollout's log (per control tick) and verdict."""

    grasp: int
    perturbation: Perturbation
    rate_hz: float
    q: np.ndarray = field(default_factory=lambda: np.zeros((0, 9)))
    """(T, 9) joint positions after each tick."""
    qd: np.ndarray = field(default_factory=lambda: np.zeros((0, 9)))
    action_q: np.ndarray = field(default_factory=lambda: np.zeros((0, 9)))
    """(T, 9) joint targets of each tick."""
    action_tcp: np.ndarray = field(default_factory=lambda: np.zeros((0, 4, 4)))
    """(T, 4, 4) commanded tool pose in the world (NaN during joint-space moves)."""
    tcp: np.ndarray = field(default_factory=lambda: np.zeros((0, 4, 4)))
    """(T, 4, 4) the tool's world pose."""
    object_pose: np.ndarray = field(default_factory=lambda: np.zeros((0, 4, 4)))
    links: np.ndarray = field(default_factory=lambda: np.zeros((0, 0, 4, 4)))
    """(T, L, 4, 4) world poses of the Panda's links (:func:`rose_usd.sim.panda.chain` order)."""
    phase: list[str] = field(default_factory=list)
    frame: np.ndarray = field(default_factory=lambda: np.zeros(0))
    """(T,) the video frame (fractional) each tick stands for (``motion.Plan.video_frames``)."""
    follow_start: int = -1
    """Tick of video frame 0."""
    success: bool = False
    reason: str = ""
    mean_error_m: float = float("nan")
    final_error_m: float = float("nan")
    final_error_deg: float = float("nan")
    drift_m: float = float("nan")
    drift_deg: float = float("nan")
    penetration_m: float = 0.0
    ik_error_m: float = 0.0
    """Largest IK position error of the plan's Cartesian segments [m]."""
    ik_error_deg: float = 0.0
    approach: str = "straight"
    """How the approach's route was found (:class:`rose_usd.collect.planning.Route`)."""
    hand_lag_m: float = float("nan")
    """Largest distance of the tool from its commanded pose over the follow [m]."""
    hand_lag_deg: float = float("nan")
    wall_s: float = 0.0
    sim_s: float = 0.0

    @property
    def frames(self) -> int:
        return len(self.q)

    def ticks_of_frames(self, n: int) -> np.ndarray:
        """(n,) the first follow tick standing for each video frame 0..n-1 (the last tick where the
        log ends before it)."""
        follow = np.flatnonzero(np.asarray(self.phase) == "follow")
        at = np.searchsorted(self.frame[follow], np.arange(n) - 1e-6)
        return follow[np.minimum(at, len(follow) - 1)]


IMPRATIO = 100.0
"""MuJoCo's ratio of frictional to normal constraint impedance, with an elliptic friction cone
(``collect/world.py`` says why)."""


def mujoco_solver(world: World, iterations: int, **backend):
    """SolverMuJoCo on ``world.model`` with the collect stage's contact settings (``collect/world.py``
    says why each), on the backend ``backend`` names (``use_mujoco_cpu=True``, or mujoco_warp's
    ``separate_worlds`` and contact buffers); and the masks, per MuJoCo geom, of the scene's geoms and
    of the robot's and object's (for the penetration check)."""
    from newton.solvers import SolverMuJoCo

    solver = SolverMuJoCo(
        world.model,
        solver="newton",
        integrator="implicitfast",
        cone="elliptic",
        impratio=IMPRATIO,
        iterations=iterations,
        ls_iterations=50,
        enable_multiccd=True,
        **backend,
    )
    geom_shape = solver.mjc_geom_to_newton_shape.numpy()[0]
    scene = np.isin(geom_shape, world.scene_shapes)
    movers = np.isin(geom_shape, world.robot_shapes + world.object_shapes)
    return solver, scene, movers


class Simulator:
    """SolverMuJoCo on one world, reused for every rollout (state reset, mass and friction set)."""

    def __init__(self, world: World, dt_s: float, iterations: int):
        import warp as wp

        self.world, self.dt_s = world, dt_s
        model = world.model
        self.solver, self.scene_geoms, self.mover_geoms = mujoco_solver(world, iterations, use_mujoco_cpu=True)
        self.base_mass = model.body_mass.numpy().copy()
        self.base_inertia = model.body_inertia.numpy().copy()
        self.base_mu = model.shape_material_mu.numpy().copy()
        self._wp = wp

    def set_object(self, mass_kg: float, friction: float) -> None:
        from rose_usd.sim.engine import newton as load_newton

        newton = load_newton()
        w, model = self.world, self.world.model
        scale = mass_kg / max(w.object_mass_kg, 1e-9)
        mass, inertia = self.base_mass.copy(), self.base_inertia.copy()
        mass[w.object_body] *= scale
        inertia[w.object_body] *= scale
        model.body_mass.assign(mass)
        model.body_inv_mass.assign(np.where(mass > 0, 1.0 / np.maximum(mass, 1e-12), 0.0).astype(np.float32))
        model.body_inertia.assign(inertia)
        inv = np.zeros_like(inertia)
        for i, m in enumerate(inertia):
            if np.linalg.det(m) > 0:
                inv[i] = np.linalg.inv(m)
        model.body_inv_inertia.assign(inv)
        mu = self.base_mu.copy()
        mu[w.object_shapes + w.scene_shapes] = friction
        model.shape_material_mu.assign(mu)
        self.solver.notify_model_changed(
            newton.ModelFlags.BODY_INERTIAL_PROPERTIES | newton.ModelFlags.SHAPE_PROPERTIES
        )

    def penetration(self) -> float:
        """Deepest penetration [m] of a robot or object geom into a scene geom now (0 if none)."""
        data = self.solver.mj_data
        if data.ncon == 0:
            return 0.0
        geom = data.contact.geom[: data.ncon]
        dist = data.contact.dist[: data.ncon]
        pair = (self.scene_geoms[geom[:, 0]] & self.mover_geoms[geom[:, 1]]) | (
            self.scene_geoms[geom[:, 1]] & self.mover_geoms[geom[:, 0]]
        )
        return float(max(0.0, -dist[pair].min())) if pair.any() else 0.0


def pose7_to_matrix(q7: np.ndarray) -> np.ndarray:
    """(..., 7) position and quaternion xyzw (Newton's body_q) -> (..., 4, 4)."""
    return se3.make_pose(se3.matrix_from_quat_xyzw(q7[..., 3:7]), q7[..., :3])


def perturbed_pose(q7: np.ndarray, perturbation: Perturbation) -> np.ndarray:
    """A free joint's coordinates (7,: position, quaternion xyzw) turned by the perturbation's yaw
    and shifted by its offset [m]."""
    start = pose7_to_matrix(np.asarray(q7, dtype=float))
    turn = se3.make_pose(se3.rotation_about([0.0, 0.0, 1.0], np.radians(perturbation.yaw_deg)), np.zeros(3))
    moved = start.copy()
    moved[:3, :3] = turn[:3, :3] @ start[:3, :3]
    moved[:3, 3] = start[:3, 3] + perturbation.offset_m
    return np.concatenate([moved[:3, 3], se3.quat_xyzw_from_matrix(moved[:3, :3])])


def _perturbed_joint_q(joint_q: np.ndarray, object_q0: int, perturbation: Perturbation) -> np.ndarray:
    """The joint coordinates ``joint_q`` with the object's free joint (from ``object_q0``) perturbed
    (``perturbed_pose``; changed in place and returned)."""
    joint_q[object_q0 : object_q0 + 7] = perturbed_pose(joint_q[object_q0 : object_q0 + 7], perturbation)
    return joint_q


class _Ticks:
    """Executes a plan's ticks in the simulator (joint targets interpolated over ``substeps`` steps
    of ``dt`` [s], arm velocity feed-forward) and logs the robot and the object after each tick."""

    def __init__(self, sim: Simulator, plan: motion.Plan, state, nxt, control, substeps: int, dt: float):
        w, model = sim.world, sim.world.model
        self.sim, self.plan, self.substeps, self.dt = sim, plan, substeps, dt
        self.state, self.nxt, self.control = state, nxt, control
        self.target_q = model.joint_q.numpy().copy()
        self.target_qd = np.zeros(model.joint_dof_count, dtype=np.float32)
        self.link_bodies = [w.robot_bodies[name] for name in panda.chain().links]
        self.log_q, self.log_qd, self.log_tcp, self.log_obj, self.log_links, self.log_act = [], [], [], [], [], []
        self.deepest = 0.0
        self.q_prev = plan.q[0]
        self.tick = 0

    def execute(self, upto: int) -> bool:
        """Run the plan's ticks up to ``upto`` (exclusive); False once a body's pose is not finite or
        ``FLUNG_M`` from the origin (the simulation diverged)."""
        w, plan, rate, substeps = self.sim.world, self.plan, self.plan.rate_hz, self.substeps
        q0, d0, n = w.robot_q0, w.robot_d0, len(panda.JOINTS)
        while self.tick < upto:
            q_next = plan.q[self.tick]
            qd_ff = (q_next - self.q_prev) * rate
            for i in range(substeps):
                a = (i + 1) / substeps
                self.target_q[q0 : q0 + n] = self.q_prev + a * (q_next - self.q_prev)
                self.target_qd[d0 : d0 + 7] = qd_ff[:7]
                self.control.joint_target_q.assign(self.target_q.astype(np.float32))
                self.control.joint_target_qd.assign(self.target_qd)
                self.sim.solver.step(self.state, self.nxt, self.control, None, self.dt)
                self.state, self.nxt = self.nxt, self.state
            self.q_prev = q_next
            if not self._log(q_next):
                return False
            self.tick += 1
        return True

    def _log(self, q_next: np.ndarray) -> bool:
        """Log the state after a tick whose joint targets were ``q_next`` (9,); False if it diverged."""
        w, state = self.sim.world, self.state
        q0, d0, n = w.robot_q0, w.robot_d0, len(panda.JOINTS)
        body_q = state.body_q.numpy().astype(float)
        jq = state.joint_q.numpy().astype(float)
        if diverged(body_q):
            return False
        self.log_q.append(jq[q0 : q0 + n])
        self.log_qd.append(state.joint_qd.numpy().astype(float)[d0 : d0 + n])
        self.log_tcp.append(pose7_to_matrix(body_q[w.robot_bodies[panda.TCP_LINK]]))
        self.log_obj.append(pose7_to_matrix(body_q[w.object_body]))
        self.log_links.append(pose7_to_matrix(body_q[self.link_bodies]))
        self.log_act.append(q_next)
        self.deepest = max(self.deepest, self.sim.penetration())
        return True

    def fill(self, result: Rollout) -> None:
        """Copy the log (T ticks) and the plan's commands and IK errors into ``result``."""
        plan, t = self.plan, len(self.log_q)
        result.q, result.qd = np.array(self.log_q), np.array(self.log_qd)
        result.tcp, result.object_pose = np.array(self.log_tcp), np.array(self.log_obj)
        result.links = np.array(self.log_links)
        result.action_q = np.array(self.log_act)
        result.action_tcp = np.array(plan.tcp[:t])
        result.phase = list(plan.phase[:t])
        result.frame = plan.video_frames()[:t]
        result.penetration_m = self.deepest
        result.ik_error_m, result.ik_error_deg = plan.ik_error_m, plan.ik_error_deg
        result.approach = plan.approach
        result.sim_s = t * self.substeps * self.dt


def run_rollout(
    sim: Simulator,
    plan: motion.Plan,
    path: np.ndarray,
    perturbation: Perturbation,
    grasp: int,
    cfg: CollectConfig,
) -> Rollout:
    """Execute the approach ``plan`` (home to closed on the object), then plan and execute the
    carry along ``path`` (N, 4, 4), the object's reconstructed world poses, and judge it."""
    from rose_usd.sim.engine import newton as load_newton

    newton = load_newton()
    t_wall = time.perf_counter()
    # carried on below
    plan = dataclasses.replace(plan, q=list(plan.q), tcp=list(plan.tcp), phase=list(plan.phase), frame=list(plan.frame))
    w, model = sim.world, sim.world.model
    sim.set_object(perturbation.mass_kg, perturbation.friction)
    state, nxt, control = model.state(), model.state(), model.control()
    sim.solver.reset(state)
    joint_q = _perturbed_joint_q(model.joint_q.numpy().copy(), w.object_q0, perturbation)
    state.joint_q.assign(joint_q.astype(np.float32))
    state.joint_qd.zero_()
    newton.eval_fk(model, state.joint_q, state.joint_qd, state)

    rate = plan.rate_hz
    substeps = max(1, int(round(1.0 / (rate * sim.dt_s))))
    dt = 1.0 / (rate * substeps)
    ticks = _Ticks(sim, plan, state, nxt, control, substeps, dt)
    result = Rollout(grasp=grasp, perturbation=perturbation, rate_hz=rate)

    finite = ticks.execute(len(plan))
    carry_from = len(plan)
    if finite:
        # the follow, from where the object and the hand actually are once it is grasped
        tcp_grasp, obj_grasp = ticks.log_tcp[-1], ticks.log_obj[-1]
        follow = motion.lifted(motion.follow_poses(path, obj_grasp, tcp_grasp), cfg.lift_m)
        motion.carry_plan(plan, w.base_pose, follow, cfg.lift_m)
        finite = ticks.execute(len(plan))
    ticks.fill(result)
    if not finite:
        phase = plan.phase[min(ticks.tick, len(plan) - 1)]
        result.reason = f"the simulation diverged (a body's pose not finite or {FLUNG_M:g} m away) in phase {phase!r}"
    else:
        judge(result, path, carry_from, cfg)
    result.wall_s = time.perf_counter() - t_wall
    return result


def judge(r: Rollout, path: np.ndarray, carry_from: int, cfg: CollectConfig) -> None:
    """Fill in the rollout's errors and verdict."""
    follow = np.flatnonzero(np.asarray(r.phase) == "follow")
    r.follow_start = int(follow[0])
    obj, tcp = r.object_pose[follow], r.tcp[follow]
    err = np.linalg.norm(obj[:, :3, 3] - motion.poses_at(path, r.frame[follow])[:, :3, 3], axis=1)
    r.mean_error_m = float(err.mean())
    r.final_error_m = float(err[-1])
    r.final_error_deg = float(se3.rotation_angle_deg(obj[-1, :3, :3].T @ path[-1, :3, :3]))
    grasped = se3.invert(r.tcp[carry_from - 1]) @ r.object_pose[carry_from - 1]
    in_hand = np.einsum("nij,njk->nik", se3.invert(tcp), obj)
    r.drift_m = float(np.linalg.norm(in_hand[:, :3, 3] - grasped[:3, 3], axis=1).max())
    r.drift_deg = float(se3.rotation_angle_deg(np.einsum("ji,njk->nik", grasped[:3, :3], in_hand[:, :3, :3])).max())
    checks = [
        (r.drift_m < cfg.max_drift_m, f"the object slipped {100 * r.drift_m:.1f} cm in the hand"),
        (r.drift_deg < cfg.max_drift_deg, f"the object turned {r.drift_deg:.0f} deg in the hand"),
        (r.mean_error_m < cfg.max_mean_error_m, f"mean path error {100 * r.mean_error_m:.1f} cm"),
        (r.final_error_m < cfg.max_final_error_m, f"final path error {100 * r.final_error_m:.1f} cm"),
        (r.final_error_deg < cfg.max_final_error_deg, f"final rotation error {r.final_error_deg:.0f} deg"),
        (r.penetration_m < cfg.max_penetration_m, f"{100 * r.penetration_m:.1f} cm deep into the scene"),
    ]
    commanded = r.action_tcp[follow]
    r.hand_lag_m = float(np.linalg.norm(commanded[:, :3, 3] - tcp[:, :3, 3], axis=1).max())
    r.hand_lag_deg = float(
        se3.rotation_angle_deg(np.einsum("nji,njk->nik", commanded[:, :3, :3], tcp[:, :3, :3])).max()
    )
    failed = [why for ok, why in checks if not ok]
    if failed and (r.hand_lag_m > 0.01 or r.hand_lag_deg > 5.0):
        lag = f"the hand lagged its commanded path by {100 * r.hand_lag_m:.1f} cm, {r.hand_lag_deg:.0f} deg"
        speed = np.abs(np.diff(r.action_q[follow[0] - 1 : follow[-1] + 1, :7], axis=0)).max(axis=0) * r.rate_hz
        over = speed / np.asarray(panda.ARM_MAX_VELOCITY_RAD_S)
        if over.max() > 1.0:
            j = int(over.argmax())
            limit = panda.ARM_MAX_VELOCITY_RAD_S[j]
            lag += f" (the path needs joint {j + 1} at {speed[j]:.1f} rad/s, the Panda's limit is {limit})"
        failed.insert(0, lag)
    if failed and (r.ik_error_m > 0.01 or r.ik_error_deg > 5.0):
        failed.insert(
            0, f"the arm could not follow the path (IK {100 * r.ik_error_m:.1f} cm, {r.ik_error_deg:.0f} deg off)"
        )
    if failed and r.approach.endswith("blocked"):
        failed.insert(0, f"no clear approach from home ({r.approach}): the arm took the straight line")
    r.success = not failed
    r.reason = "; ".join(failed)
