"""Batched inverse kinematics of the Panda's tool frame with ``newton.ik`` (Levenberg-Marquardt,
analytic Jacobians), on a robot-only model whose base is the origin: targets are given in the
robot base frame, so one solver serves every base placement. Errors are measured with the
URDF's forward kinematics (``rose_usd.sim.panda``)."""

from __future__ import annotations

import functools

import numpy as np

from rose_usd.core import se3
from rose_usd.sim import panda


@functools.cache
def _robot_model():
    from rose_usd.sim.engine import newton as load_newton

    newton = load_newton()
    b = newton.ModelBuilder()
    b.add_urdf(str(panda.panda_urdf()), floating=False, enable_self_collisions=False, hide_visuals=True)
    tcp = next(i for i, label in enumerate(b.body_label) if label.endswith("/" + panda.TCP_LINK))
    return b.finalize(device="cpu"), tcp


@functools.cache
def _solver(n_problems: int, n_seeds: int):
    import warp as wp
    from newton import ik

    model, tcp = _robot_model()
    with wp.ScopedDevice("cpu"):  # the model is on the CPU, whatever Warp's default device is
        return _objectives(ik, wp, model, tcp, n_problems, n_seeds)


def _objectives(ik, wp, model, tcp, n_problems: int, n_seeds: int):
    pos = ik.IKObjectivePosition(tcp, wp.vec3(0.0, 0.0, 0.0), wp.zeros(n_problems, dtype=wp.vec3))
    rot = ik.IKObjectiveRotation(tcp, wp.quat_identity(), wp.array([[0.0, 0.0, 0.0, 1.0]] * n_problems, dtype=wp.vec4))
    limits = ik.IKObjectiveJointLimit(model.joint_limit_lower, model.joint_limit_upper, weight=1.0)
    kwargs = {"sampler": ik.IKSampler.GAUSS, "n_seeds": n_seeds, "noise_std": 0.4} if n_seeds > 1 else {}
    solver = ik.IKSolver(model, n_problems, [pos, rot, limits], jacobian_mode=ik.IKJacobianType.ANALYTIC, **kwargs)
    return solver, pos, rot


def _bucket(n: int) -> int:
    """Problem counts are rounded up to a few sizes so solvers (and their kernels) are reused."""
    size = 8
    while size < n:
        size *= 2
    return size


def solve(
    base_from_tcp: np.ndarray, seeds: np.ndarray, *, n_seeds: int = 1, iterations: int = 60
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Joint coordinates reaching tool poses.

    Args:
        base_from_tcp: (n, 4, 4) target tool poses in the base frame.
        seeds: (n, 9) or (9,) starting joint coordinates (the first of ``n_seeds`` tries; the
            others are Gaussian around it).
        n_seeds: tries per target; the one of least cost wins.

    Returns:
        q (n, 9), position error (n,) [m], rotation error (n,) [deg].
    """
    import warp as wp

    targets = np.asarray(base_from_tcp, dtype=float)
    n = len(targets)
    if n == 0:
        return np.zeros((0, 9)), np.zeros(0), np.zeros(0)
    size = _bucket(n)
    solver, pos, rot = _solver(size, n_seeds)
    padded = np.concatenate([targets, np.broadcast_to(targets[-1], (size - n, 4, 4))])
    start = np.broadcast_to(np.asarray(seeds, dtype=float), (n, 9))
    start = np.concatenate([start, np.broadcast_to(start[-1], (size - n, 9))]).astype(np.float32)
    with wp.ScopedDevice("cpu"):  # the solver is on the CPU, whatever Warp's default device is
        pos.set_target_positions(wp.array(padded[:, :3, 3].astype(np.float32), dtype=wp.vec3))
        quats = se3.quat_xyzw_from_matrix(padded[:, :3, :3]).astype(np.float32)
        rot.set_target_rotations(wp.array(quats, dtype=wp.vec4))
        q = wp.array(start, dtype=wp.float32)
        solver.reset()
        solver.step(q, q, iterations=iterations)
    out = q.numpy().astype(float)[:n]
    out[:, :7] = np.clip(out[:, :7], panda.chain().lower[:7], panda.chain().upper[:7])
    out[:, 7:] = start[:n, 7:]
    reached = panda.chain().tcp(out)
    pos_err = np.linalg.norm(reached[:, :3, 3] - targets[:, :3, 3], axis=1)
    rot_err = se3.rotation_angle_deg(np.einsum("nji,njk->nik", reached[:, :3, :3], targets[:, :3, :3]))
    return out, pos_err, rot_err


def solve_path(base_from_tcp: np.ndarray, seed: np.ndarray, *, chunk: int = 8, iterations: int = 40):
    """Joint coordinates along a path of tool poses, each chunk warm-started from the previous
    chunk's last solution so the arm stays on one branch. Returns q (n, 9), errors as :func:`solve`."""
    qs, pe, re = [], [], []
    seed = np.asarray(seed, dtype=float)
    for start in range(0, len(base_from_tcp), chunk):
        q, p, r = solve(base_from_tcp[start : start + chunk], seed, iterations=iterations)
        qs.append(q)
        pe.append(p)
        re.append(r)
        seed = q[-1]
    return np.concatenate(qs), np.concatenate(pe), np.concatenate(re)
