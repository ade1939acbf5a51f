"""Many rollouts at once on a GPU: N copies of the collect world in one Newton model, each its own
MuJoCo world (SolverMuJoCo on mujoco_warp), stepped together.

The contact settings are the one-world simulator's (``collect/world.py``). What differs: each
rollout's plan is fixed before the simulation starts. The follow is planned from the grasp as
planned (the tool at its grasp pose, the object where the reconstruction puts it), not from where
the simulated grasp landed, so one IK solve serves every perturbation of a grasp; a perturbed
object is then carried a few millimetres off its path (the perturbation), inside the success
limits. Rollouts are logged per control tick as on the CPU and judged by the same ``judge``;
the links' poses, needed only for the best rollout's robot layer, come from forward kinematics.
"""

from __future__ import annotations

import time

import numpy as np

from rose_usd.collect import motion
from rose_usd.collect.config import CollectConfig
from rose_usd.collect.rollout import (
    FLUNG_M,
    Perturbation,
    Rollout,
    diverged,
    judge,
    mujoco_solver,
    perturbed_pose,
    pose7_to_matrix,
)
from rose_usd.collect.world import World
from rose_usd.sim import panda


def cuda_available() -> bool:
    """Whether Warp sees a CUDA device (the batched simulator needs one)."""
    from rose_usd.sim.engine import warp

    return warp().get_cuda_device_count() > 0


class BatchSimulator:
    """SolverMuJoCo on mujoco_warp over every world of ``world.model``."""

    def __init__(self, world: World, dt_s: float, iterations: int, contacts_per_world: int):
        import warp as wp

        self.world, self.dt_s, self._wp = world, dt_s, wp
        self.contacts_per_world = contacts_per_world
        self.solver, self.scene_geoms, self.mover_geoms = mujoco_solver(
            world,
            iterations,
            separate_worlds=True,
            nconmax=contacts_per_world,
            njmax=6 * contacts_per_world + 64,
        )
        self.most_contacts = 0

    def set_objects(self, mass_kg: np.ndarray, friction: np.ndarray) -> None:
        """Each world's object mass [kg] and the friction of its object and scene, (N,) each."""
        from rose_usd.sim.engine import newton as load_newton

        newton = load_newton()
        w, model = self.world, self.world.model
        nb, ns = w.bodies_per_world, model.shape_count // w.worlds
        mass = model.body_mass.numpy().reshape(w.worlds, nb).copy()
        inertia = model.body_inertia.numpy().reshape(w.worlds, nb, 3, 3).copy()
        scale = np.asarray(mass_kg, dtype=float) / max(w.object_mass_kg, 1e-9)
        base_mass, base_inertia = mass[0, w.object_body], inertia[0, w.object_body].copy()
        mass[:, w.object_body] = base_mass * scale
        inertia[:, w.object_body] = base_inertia[None] * scale[:, None, None]
        model.body_mass.assign(mass.reshape(-1).astype(np.float32))
        model.body_inv_mass.assign(
            np.where(mass > 0, 1.0 / np.maximum(mass, 1e-12), 0.0).reshape(-1).astype(np.float32)
        )
        model.body_inertia.assign(inertia.reshape(-1, 3, 3).astype(np.float32))
        inv = np.linalg.inv(inertia[:, w.object_body])
        all_inv = model.body_inv_inertia.numpy().reshape(w.worlds, nb, 3, 3).copy()
        all_inv[:, w.object_body] = inv
        model.body_inv_inertia.assign(all_inv.reshape(-1, 3, 3).astype(np.float32))
        mu = model.shape_material_mu.numpy().reshape(w.worlds, ns).copy()
        mu[:, w.object_shapes + w.scene_shapes] = np.asarray(friction, dtype=np.float32)[:, None]
        model.shape_material_mu.assign(mu.reshape(-1))
        self.solver.notify_model_changed(
            newton.ModelFlags.BODY_INERTIAL_PROPERTIES | newton.ModelFlags.SHAPE_PROPERTIES
        )

    def penetration(self) -> np.ndarray:
        """(N,) the deepest penetration [m] of a robot or object geom into a scene geom in each world now."""
        data = self.solver.mjw_data
        n = int(data.nacon.numpy()[0])
        self.most_contacts = max(self.most_contacts, n)
        out = np.zeros(self.world.worlds)
        if n == 0:
            return out
        geom = data.contact.geom.numpy()[:n]
        dist = data.contact.dist.numpy()[:n]
        world = data.contact.worldid.numpy()[:n]
        pair = (self.scene_geoms[geom[:, 0]] & self.mover_geoms[geom[:, 1]]) | (
            self.scene_geoms[geom[:, 1]] & self.mover_geoms[geom[:, 0]]
        )
        deep = pair & (dist < 0)
        np.maximum.at(out, world[deep], -dist[deep])
        return out


def full_plan(
    base_pose: np.ndarray,
    grasp_tcp: np.ndarray,
    path: np.ndarray,
    rate: float,
    cfg: CollectConfig,
    route,
    opening_m: float,
) -> motion.Plan:
    """Approach, grasp, lift, follow, place and release, planned for a grasp's world tool pose (4, 4),
    its pre-shape ``opening_m`` and the object's path (N, 4, 4) as reconstructed; ``route`` as for
    :func:`motion.approach_plan`."""
    plan = motion.approach_plan(base_pose, grasp_tcp, rate, cfg.approach_s, route, opening_m)
    follow = motion.lifted(motion.follow_poses(path, path[0], grasp_tcp), cfg.lift_m)
    motion.carry_plan(plan, base_pose, follow, cfg.lift_m)
    return plan


def run_batch(
    sim: BatchSimulator,
    plans: list[motion.Plan],
    plan_of: list[int],
    perturbations: list[Perturbation],
    path: np.ndarray,
    cfg: CollectConfig,
) -> list[Rollout]:
    """Every world's rollout at once: world w follows ``plans[plan_of[w]]`` with ``perturbations[w]``;
    all plans have the same length. Returns the judged rollouts in world order."""
    from rose_usd.sim.engine import newton as load_newton

    newton = load_newton()
    t_wall = time.perf_counter()
    w, model, n = sim.world, sim.world.model, sim.world.worlds
    q_plans = np.stack([np.asarray(p.q, dtype=np.float32) for p in plans])[np.asarray(plan_of)]  # (N, T, 9)
    sim.set_objects(np.array([p.mass_kg for p in perturbations]), np.array([p.friction for p in perturbations]))
    state, nxt, control = model.state(), model.state(), model.control()
    sim.solver.reset(state)
    joint_q = model.joint_q.numpy().reshape(n, w.coords_per_world).copy()
    for k, pert in enumerate(perturbations):
        pose = perturbed_pose(joint_q[k, w.object_q0 : w.object_q0 + 7], pert)
        joint_q[k, w.object_q0 : w.object_q0 + 7] = pose
    state.joint_q.assign(joint_q.reshape(-1).astype(np.float32))
    state.joint_qd.zero_()
    newton.eval_fk(model, state.joint_q, state.joint_qd, state)

    rate = plans[0].rate_hz
    substeps = max(1, int(round(1.0 / (rate * sim.dt_s))))
    dt = 1.0 / (rate * substeps)
    q0, d0, joints = w.robot_q0, w.robot_d0, len(panda.JOINTS)
    target_q = model.joint_q.numpy().reshape(n, w.coords_per_world).copy()
    target_qd = np.zeros((n, w.dofs_per_world), np.float32)
    ticks = q_plans.shape[1]
    log_q = np.zeros((ticks, n, joints), np.float32)
    log_qd = np.zeros((ticks, n, joints), np.float32)
    log_tcp = np.zeros((ticks, n, 7), np.float32)
    log_obj = np.zeros((ticks, n, 7), np.float32)
    deepest = np.zeros(n)
    q_prev = q_plans[:, 0]
    tcp_body, obj_body = w.robot_bodies[panda.TCP_LINK], w.object_body
    for t in range(ticks):
        q_next = q_plans[:, t]
        target_qd[:, d0 : d0 + 7] = (q_next[:, :7] - q_prev[:, :7]) * rate
        for i in range(substeps):
            a = (i + 1) / substeps
            target_q[:, q0 : q0 + joints] = q_prev + a * (q_next - q_prev)
            control.joint_target_q.assign(target_q.reshape(-1))
            control.joint_target_qd.assign(target_qd.reshape(-1))
            sim.solver.step(state, nxt, control, None, dt)
            state, nxt = nxt, state
        q_prev = q_next
        body_q = state.body_q.numpy().reshape(n, w.bodies_per_world, 7)
        jq = state.joint_q.numpy().reshape(n, w.coords_per_world)
        log_q[t] = jq[:, q0 : q0 + joints]
        log_qd[t] = state.joint_qd.numpy().reshape(n, w.dofs_per_world)[:, d0 : d0 + joints]
        log_tcp[t], log_obj[t] = body_q[:, tcp_body], body_q[:, obj_body]
        deepest = np.maximum(deepest, sim.penetration())
    wall = (time.perf_counter() - t_wall) / n
    return [
        _rollout(
            plans[plan_of[k]],
            plan_of[k],
            perturbations[k],
            path,
            cfg,
            k,
            log_q,
            log_qd,
            log_tcp,
            log_obj,
            deepest[k],
            wall,
            ticks * substeps * dt,
        )
        for k in range(n)
    ]


def _rollout(plan, grasp, pert, path, cfg, k, log_q, log_qd, log_tcp, log_obj, deepest, wall, sim_s) -> Rollout:
    """World k's log as a judged ``Rollout``."""
    r = Rollout(grasp=grasp, perturbation=pert, rate_hz=plan.rate_hz)
    bad = diverged(np.stack([log_tcp[:, k], log_obj[:, k]], axis=1))
    t = int(np.argmax(bad)) if bad.any() else len(bad)
    r.q, r.qd = log_q[:t, k].astype(float), log_qd[:t, k].astype(float)
    r.tcp, r.object_pose = (
        pose7_to_matrix(log_tcp[:t, k].astype(float)),
        pose7_to_matrix(log_obj[:t, k].astype(float)),
    )
    r.action_q = np.asarray(plan.q[:t], dtype=float)
    r.action_tcp = np.asarray(plan.tcp[:t], dtype=float)
    r.phase = list(plan.phase[:t])
    r.frame = plan.video_frames()[:t]
    r.penetration_m, r.ik_error_m, r.ik_error_deg = float(deepest), plan.ik_error_m, plan.ik_error_deg
    r.approach = plan.approach
    r.wall_s, r.sim_s = wall, sim_s
    if t < len(bad):
        r.reason = (
            f"the simulation diverged (a body's pose not finite or {FLUNG_M:g} m away) in phase {plan.phase[t]!r}"
        )
        return r
    carry_from = int(plan.phase_ticks("lift")[0])
    judge(r, path, carry_from, cfg)
    return r


def link_poses(rollout: Rollout, base_pose: np.ndarray) -> np.ndarray:
    """(T, L, 4, 4) world poses of the Panda's links over a rollout, by forward kinematics of its
    logged joint positions (a batch keeps no link poses)."""
    return np.einsum("ij,tljk->tlik", base_pose, panda.chain().forward(rollout.q))
