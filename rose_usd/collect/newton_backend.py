"""The newton backend: grasp-and-follow rollouts of a Franka Panda in Newton (SolverMuJoCo on
MuJoCo's C backend, one world, reused across rollouts), then the robot layer and the dataset.

Inputs that cannot give a demonstration (no object with a path, an object without a collision
mesh, one too large for the gripper, a path out of reach) write a layer whose status and
message say so, and a warning; they are not errors of the pipeline.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import NamedTuple

import numpy as np

from rose_usd.collect import batch, grasping, motion, planning
from rose_usd.collect.author import Outcome, author_robot
from rose_usd.collect.config import CollectConfig, SimDevice
from rose_usd.collect.dataset import write_dataset
from rose_usd.collect.rollout import Perturbation, Rollout, Simulator, run_rollout
from rose_usd.collect.world import World, build_world, crop_to_box
from rose_usd.core import se3
from rose_usd.errors import ConfigError
from rose_usd.geometry.grasps import sample_surface
from rose_usd.layers import objects as object_layer
from rose_usd.layers.gate import read_gate
from rose_usd.layers.scene import scene_collider
from rose_usd.layers.trajectory import object_poses
from rose_usd.progress import progress, say
from rose_usd.sim.resting import min_run_frames, resting_frames, resting_runs
from rose_usd.stage_api import StageContext
from rose_usd.usd.geom import MeshData


def _pick_objects(ctx: StageContext, cfg: CollectConfig) -> list[tuple[str, np.ndarray]]:
    """The objects the robot may move, with their paths (N, 4, 4), in the order to try them: the
    configured one alone, else every object, the one whose path is longest first."""
    names = object_layer.object_paths(ctx.stage)
    n = ctx.time_info.n_frames
    if cfg.object_name:
        if cfg.object_name not in names:
            raise ConfigError(
                f"collect.object_name = {cfg.object_name!r} is not an object of the stage",
                hint=f"objects: {', '.join(names) or 'none'}",
            )
        return [(cfg.object_name, object_poses(ctx.stage, cfg.object_name, n))]
    paths = [(name, object_poses(ctx.stage, name, n)) for name in names]
    length = {name: float(np.linalg.norm(np.diff(p[:, :3, 3], axis=0), axis=1).sum()) for name, p in paths}
    return sorted(paths, key=lambda item: -length[item[0]])


def _planned(ctx: StageContext, cfg: CollectConfig, rng, clearance_for):
    """The first object of ``_pick_objects`` a grasp and a base are found for: (name, path, target,
    outcome, (candidates, ranked grasps, other bases)); or None, the first object's outcome (with
    the others' reasons) finished into the layer. A warning names the objects passed over."""
    refusals: list[Outcome] = []
    for name, path in _pick_objects(ctx, cfg):
        refused = _unmovable(ctx, name)
        if refused is None:
            target = _target(ctx, name, path, rng)
            outcome = Outcome("ok", object_name=name)
            try:
                plan = _grasps_and_base(cfg, target, path, outcome, rng, clearance_for(name))
            except grasping.NoGrasp as why:  # the outcome keeps what was found (the base tried)
                outcome.status = "unreachable" if "reach" in str(why) else "no-grasp"
                outcome.message, refused = str(why), outcome
            else:
                if refusals:
                    passed = "; ".join(f"{r.object_name!r} ({r.message})" for r in refusals)
                    ctx.warn(f"the robot moves {name!r}, passing over {passed}")
                return name, path, target, outcome, plan
        refusals.append(refused)
    if not refusals:
        _finish(ctx, Outcome("no-object", "the stage has no object to move"))
        return None
    first = refusals[0]
    if len(refusals) > 1:
        others = "; ".join(f"{r.object_name!r}: {r.message}" for r in refusals[1:])
        first.message = f"{first.message} (nor any other object: {others})"
    _finish(ctx, first)
    return None


def _unmovable(ctx: StageContext, name: str) -> Outcome | None:
    """Why no robot can move the object (status no-collider or not-resting), or None."""
    if object_layer.collision_approximation(ctx.stage, name) is None:
        return Outcome("no-collider", f"object {name!r} has no collision mesh", object_name=name)
    if not _rests_somewhere(ctx, name):
        why = (
            f"object {name!r} rests in no frame of the video (held or moving in every one):"
            " there is nowhere for the robot to pick it up from"
        )
        return Outcome("not-resting", why, object_name=name)
    return None


def _rests_somewhere(ctx: StageContext, name: str) -> bool:
    """Whether the object rests in the video (``sim.resting``: still, untouched or still from the
    start) for at least the run the gate's rest check counts."""
    n = ctx.time_info.n_frames
    frames = resting_frames(ctx.stage, {name: object_layer.object_paths(ctx.stage)[name]}, n)[name]
    return bool(resting_runs(frames, min_run_frames(ctx.time_info.fps)))


def _surface_points(vertices: np.ndarray, faces: np.ndarray, spacing_m: float, rng) -> np.ndarray:
    """Points on a mesh about ``spacing_m`` apart (between 500 and 40000 of them)."""
    tri = vertices[faces]
    area = float(np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1).sum() / 2)
    points, _ = sample_surface(vertices, faces, int(np.clip(area / spacing_m**2, 500, 40000)), rng)
    return points


def _scene_points(stage, lo: np.ndarray, hi: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Points on the scene collider inside the box [lo, hi], about 5 mm apart."""
    collider = scene_collider(stage)
    if collider is None:
        return np.zeros((0, 3))
    cut = crop_to_box(collider[0], collider[1], lo, hi)
    if cut is None:
        return np.zeros((0, 3))
    return _surface_points(cut[0], cut[1], 0.005, rng)


def _perturbations(cfg: CollectConfig, prior: object_layer.PhysicsPrior, mass_kg: float, rng) -> list[Perturbation]:
    """The first as reconstructed, the others uniformly within the noise limits and one sigma of the prior."""
    out = [Perturbation(np.zeros(3), 0.0, mass_kg, prior.friction)]
    for _ in range(max(0, cfg.perturbations - 1)):
        angle, radius = rng.uniform(0, 2 * np.pi), cfg.pose_noise_m * np.sqrt(rng.uniform())
        out.append(
            Perturbation(
                offset_m=np.array([radius * np.cos(angle), radius * np.sin(angle), 0.0]),
                yaw_deg=float(rng.uniform(-cfg.pose_noise_deg, cfg.pose_noise_deg)),
                mass_kg=float(max(0.3 * mass_kg, mass_kg + rng.uniform(-1, 1) * prior.mass_sigma_kg)),
                friction=float(np.clip(prior.friction + rng.uniform(-1, 1) * prior.friction_sigma, 0.05, 1.5)),
            )
        )
    return out


class _Target(NamedTuple):
    """The object to move, in its own frame, and what stands around it."""

    visual: MeshData
    """Its visual mesh in the world at the default pose."""
    vertices: np.ndarray
    """(V, 3) the visual mesh's vertices in the object frame [m]."""
    prior: object_layer.PhysicsPrior
    support_z: float
    """Height [m] of the support the robot stands on."""
    radius: float
    """Largest distance [m] of a vertex from the vertices' mean."""
    scene_points: np.ndarray
    """(P, 3) points [m] on the scene collider near the path and on the other objects."""


def _target(ctx: StageContext, name: str, path: np.ndarray, rng: np.random.Generator) -> _Target:
    """The object ``name`` with its path (N, 4, 4): its mesh and prior, the support and the obstacles."""
    default = object_layer.default_pose(ctx.stage, name)
    visual = object_layer.visual_mesh(ctx.stage, name)
    object_vertices = se3.transform_points(se3.invert(default), visual.vertices)
    prior = object_layer.physics_prior(ctx.stage, name)
    others = [object_layer.visual_mesh(ctx.stage, o) for o in object_layer.object_paths(ctx.stage) if o != name]
    # the robot stands on the support under the lowest object (a stacked object's bottom is on another)
    support_z = float(min(m.vertices[:, 2].min() for m in [visual, *others]))
    radius = float(np.linalg.norm(object_vertices - object_vertices.mean(axis=0), axis=1).max())
    positions = path[:, :3, 3]
    near_lo = positions.min(axis=0) - radius - 0.15
    near_hi = positions.max(axis=0) + radius + 0.15
    scene_points = _scene_points(ctx.stage, near_lo, near_hi, rng)
    for other in others:  # the other objects, where they stand at frame 0, are obstacles too
        scene_points = np.concatenate([scene_points, _surface_points(other.vertices, other.faces, 0.004, rng)])
    return _Target(visual, object_vertices, prior, support_z, radius, scene_points)


def _grasps_and_base(
    cfg: CollectConfig,
    target: _Target,
    path: np.ndarray,
    outcome: Outcome,
    rng: np.random.Generator,
    clearance_at: Callable[[np.ndarray], Callable[[np.ndarray], np.ndarray]],
) -> tuple[grasping.Candidates, grasping.Candidates, np.ndarray]:
    """The grasp candidates, the ranked few to roll out and the other base poses to try, best
    first (none when rose.toml places the base); the base pose goes into ``outcome``.
    ``clearance_at(base)``: the arm's clearance from the scene with its base there, for ``grasping.rank``.

    Raises:
        grasping.NoGrasp: no grasp fits, is free of the scene or reaches the path.
    """
    cands = grasping.candidates(
        target.vertices,
        target.visual.faces,
        target.prior.center_of_mass_m,
        path,
        target.scene_points,
        friction=cfg.grasp_friction,
        max_width_m=cfg.max_width_m,
        clearance_m=cfg.grasp_clearance_m,
        surface_points=cfg.surface_points,
        approach_turns=cfg.approach_turns,
        lift_m=cfg.lift_m,
        rng=rng,
    )
    say(f"collect: {cands.sampled_pairs} antipodal pairs, {len(cands)} collision-free grasp frames")
    if cfg.base:
        x, y, *yaw = cfg.base
        base = se3.make_pose(
            se3.rotation_about([0.0, 0.0, 1.0], np.radians(yaw[0] if yaw else 0.0)), [x, y, target.support_z]
        )
        outcome.base_source = "user"
        others = np.zeros((0, 4, 4))
    else:
        bases = grasping.place_bases(path, cands, target.support_z, target.scene_points)
        base, others = bases[0], bases[1:]
    outcome.base_pose = base
    ranked = grasping.rank(base, path, cands, cfg.grasps, cfg.lift_m, clearance=clearance_at(base))
    return cands, ranked, others


def _world(
    ctx: StageContext,
    name: str,
    target: _Target,
    path: np.ndarray,
    base_pose: np.ndarray,
    *,
    worlds: int = 1,
    device: str = "cpu",
) -> World:
    """The simulated world: the stage with the scene cut around the path (N, 4, 4) and the base
    (4, 4), and the robot; ``worlds`` copies of it on ``device``."""
    cfg: CollectConfig = ctx.config
    positions, radius, support_z = path[:, :3, 3], target.radius, target.support_z
    base_xyz, margin = base_pose[:3, 3], cfg.newton.crop_margin_m
    lo = np.minimum(positions.min(axis=0) - radius, base_xyz) - margin
    hi = np.maximum(positions.max(axis=0) + radius, base_xyz) + margin
    lo[2], hi[2] = support_z - 0.1, max(hi[2], support_z + 1.0)
    object_path = object_layer.object_paths(ctx.stage)[name]
    return build_world(ctx.stage, object_path, base_pose, (lo, hi), cfg.newton, worlds=worlds, device=device)


def _arm_checker(
    ctx: StageContext, base_pose: np.ndarray, cfg: CollectConfig, *, held: str | None = None
) -> planning.ArmChecker:
    """The arm's clearance from the scene collider and every object (but ``held``) where it stands at frame 0."""
    obstacles = [object_layer.visual_mesh(ctx.stage, o) for o in object_layer.object_paths(ctx.stage) if o != held]
    meshes = [(m.vertices, m.faces) for m in obstacles]
    collider = scene_collider(ctx.stage)
    if collider is not None:
        meshes.append(collider)
    return planning.ArmChecker(base_pose, meshes, clearance_m=cfg.approach_clearance_m)


def _roll_out(
    sim: Simulator,
    ranked: grasping.Candidates,
    perturbations: list[Perturbation],
    path: np.ndarray,
    base_pose: np.ndarray,
    rate: float,
    cfg: CollectConfig,
    checker: planning.ArmChecker,
) -> list[Rollout]:
    """One rollout per ranked grasp and perturbation, each grasp's approach planned once (around
    what ``checker`` sees); ``rate`` [Hz]."""
    jobs = [(g, p) for g in range(len(ranked)) for p in perturbations]
    rollouts: list[Rollout] = []
    plans: dict[int, motion.Plan] = {}
    for g, pert in progress(jobs, "collect rollouts", total=len(jobs), unit="rollout"):
        if g not in plans:
            grasp_tcp = path[0] @ ranked.object_from_tcp[g]
            opening = ranked.opening_m[g]
            plans[g] = motion.approach_plan(base_pose, grasp_tcp, rate, cfg.approach_s, checker.route, opening)
        rollouts.append(run_rollout(sim, plans[g], path, pert, g, cfg))
    return rollouts


def _roll_out_at(
    ctx: StageContext,
    name: str,
    target: _Target,
    path: np.ndarray,
    base_pose: np.ndarray,
    ranked: grasping.Candidates,
    rng: np.random.Generator,
    device: str,
    batched: bool,
) -> tuple[World, list[Rollout], float, planning.ArmChecker]:
    """Every (ranked grasp, perturbation) rollout with the robot at ``base_pose``: one world on the
    CPU, one after another, or (``batched``) every rollout its own world on ``device``; (world,
    rollouts, build seconds, the approach's checker)."""
    cfg: CollectConfig = ctx.config
    rate = float(ctx.time_info.fps)
    checker = _arm_checker(ctx, base_pose, cfg)
    t0 = time.perf_counter()
    if not batched:
        # the world: the stage, the scene cut around the path and the base, and the robot
        world = _world(ctx, name, target, path, base_pose)
        sim = Simulator(world, cfg.newton.dt_s, cfg.newton.iterations)
        t_build = time.perf_counter() - t0
        perturbations = _perturbations(cfg, target.prior, world.object_mass_kg, rng)
        rollouts = _roll_out(sim, ranked, perturbations, path, base_pose, rate, cfg, checker)
        return world, rollouts, t_build, checker
    perturbations = _perturbations(cfg, target.prior, target.prior.mass_kg, rng)
    jobs = [(g, p) for g in range(len(ranked)) for p in perturbations]
    world, rollouts, t_build = _roll_out_batched(ctx, name, target, path, base_pose, ranked, jobs, device, checker)
    return world, rollouts, t_build, checker


def _judge_all(ctx: StageContext, outcome: Outcome, name: str, path: np.ndarray) -> list[int]:
    """Pick the best rollout of ``outcome`` and write the dataset of the successful ones (or say
    why none succeeded); their indices."""
    cfg: CollectConfig = ctx.config
    rollouts = outcome.rollouts
    successes = [i for i, r in enumerate(rollouts) if r.success]
    reached = [i for i, r in enumerate(rollouts) if r.follow_start >= 0]
    pool = successes or reached
    outcome.best = min(pool, key=lambda i: rollouts[i].mean_error_m) if pool else -1
    if not successes:
        outcome.status = "no-success"
        reasons = sorted({r.reason for r in rollouts})
        outcome.message = f"no rollout succeeded: {reasons[0]}" + (
            f" (+{len(reasons) - 1} other reasons)" if len(reasons) > 1 else ""
        )
    else:
        info = write_dataset(ctx, [rollouts[i] for i in successes], name, path, outcome.base_pose, cfg)
        outcome.dataset_info = info
    return successes


def run(ctx: StageContext) -> None:
    """Collect: grasp candidates, base, world, rollouts, then the robot layer and the dataset."""
    cfg: CollectConfig = ctx.config
    t_start = time.perf_counter()
    rng = np.random.default_rng(cfg.seed)

    def clearance_for(name: str):
        """The arm's clearance from the scene and the objects but ``name``, with its base at a point."""
        return lambda base: _arm_checker(ctx, base, cfg, held=name).clearance

    if _gate_refuses(ctx, cfg):
        return
    planned = _planned(ctx, cfg, rng, clearance_for)
    if planned is None:
        return
    name, path, target, outcome, (cands, ranked, other_bases) = planned
    clearance_at = clearance_for(name)
    t_plan = time.perf_counter() - t_start

    device, batched = _device(cfg)
    world, rollouts, t_build, checker = _roll_out_at(
        ctx, name, target, path, outcome.base_pose, ranked, rng, device, batched
    )
    bases_tried, earlier = 1, 0
    for base in other_bases:
        if any(r.success for r in rollouts) or bases_tried >= cfg.base_tries:
            break
        try:  # every rollout failed: the next base, where the grasps reach the path from there too
            ranked_here = grasping.rank(base, path, cands, cfg.grasps, cfg.lift_m, clearance=clearance_at(base))
        except grasping.NoGrasp:
            continue
        bases_tried += 1
        x, y = outcome.base_pose[:2, 3]
        say(f"collect: no rollout succeeded from the base at ({x:.3f}, {y:.3f}) m; trying the next")
        outcome.base_pose, ranked, earlier = base, ranked_here, earlier + len(rollouts)
        world, rollouts, t_build, checker = _roll_out_at(ctx, name, target, path, base, ranked, rng, device, batched)
    outcome.rollouts = rollouts
    successes = _judge_all(ctx, outcome, name, path)
    if not successes and earlier:
        outcome.message += (
            f"; these are the {len(rollouts)} rollouts from the last of {bases_tried} robot bases tried,"
            f" the {earlier} from the others failed too"
        )
    if batched and outcome.best >= 0:
        rollouts[outcome.best].links = batch.link_poses(rollouts[outcome.best], outcome.base_pose)
    _finish(ctx, outcome)
    wall = [r.wall_s for r in rollouts]
    ctx.record(
        object=name,
        grasp_pairs=cands.sampled_pairs,
        grasp_frames=len(cands),
        grasps_rolled_out=len(ranked),
        scene_parts=world.scene_parts,
        plan_s=round(t_plan, 2),
        build_s=round(t_build, 2),
        build_timings={k: round(v, 2) for k, v in world.timings.items()},
        rollout_wall_s=[round(v, 2) for v in wall],
        rollout_sim_s=[round(r.sim_s, 2) for r in rollouts],
        rollouts_per_minute=round(60.0 * len(rollouts) / max(sum(wall), 1e-9), 2),
        successes=len(successes),
        rollout_success=[bool(r.success) for r in rollouts],
        rollout_mean_error_m=[_rounded(r.mean_error_m) for r in rollouts],
        rollout_final_error_m=[_rounded(r.final_error_m) for r in rollouts],
        rollout_drift_m=[_rounded(r.drift_m) for r in rollouts],
        rollout_approach=[r.approach for r in rollouts],
        # ticks of each follow, against the video's frames: more where the arm followed slower
        rollout_follow_ticks=[int(np.count_nonzero(np.asarray(r.phase) == "follow")) for r in rollouts],
        video_frames=int(ctx.time_info.n_frames),
        approach_checks=checker.checks,
        bases_tried=bases_tried,
        rollouts_at_other_bases=earlier,
        device=device,
        worlds=world.worlds,
    )


def _gate_refuses(ctx: StageContext, cfg: CollectConfig) -> bool:
    """Whether the gate failed the reconstruction (and collect is not told to go on): the layer
    then says so (status gate-failed), with what failed."""
    gate = read_gate(ctx.stage)
    if gate is None or gate.passed or cfg.after_failed_gate:
        return False
    why = "; ".join(gate.failures()) or "see report/gate.json"
    message = (
        f"the gate failed ({why}): no robot data from a reconstruction it rejects"
        " (set collect.after_failed_gate = true to collect anyway)"
    )
    _finish(ctx, Outcome("gate-failed", message))
    return True


def _device(cfg: CollectConfig) -> tuple[str, bool]:
    """The Warp device the rollouts run on, and whether they run batched (many worlds on mujoco_warp):
    ("cpu", False) for MuJoCo's C backend, ("cuda:0", True) on a GPU."""
    choice = cfg.newton.device
    if choice is SimDevice.CPU or (choice is SimDevice.AUTO and not batch.cuda_available()):
        return "cpu", False
    if not batch.cuda_available():
        raise ConfigError(
            "collect.newton.device = cuda, but Warp sees no CUDA device", hint="use auto or cpu on this machine"
        )
    return "cuda:0", True


def _roll_out_batched(
    ctx: StageContext,
    name: str,
    target: _Target,
    path: np.ndarray,
    base_pose: np.ndarray,
    ranked: grasping.Candidates,
    jobs: list[tuple[int, Perturbation]],
    device: str,
    checker: planning.ArmChecker,
) -> tuple[World, list[Rollout], float]:
    """Every (grasp, perturbation) rollout of ``jobs`` as its own world of one model on ``device``,
    in batches of at most ``collect.newton.max_worlds``; (world, rollouts, build seconds)."""
    cfg: CollectConfig = ctx.config
    rate = float(ctx.time_info.fps)
    size = min(len(jobs), cfg.newton.max_worlds)
    t0 = time.perf_counter()
    world = _world(ctx, name, target, path, base_pose, worlds=size, device=device)
    sim = batch.BatchSimulator(world, cfg.newton.dt_s, cfg.newton.iterations, cfg.newton.contacts_per_world)
    t_build = time.perf_counter() - t0
    grasp_tcp = [path[0] @ ranked.object_from_tcp[g] for g in range(len(ranked))]
    plans = [
        batch.full_plan(base_pose, tcp, path, rate, cfg, checker.route, opening)
        for tcp, opening in zip(grasp_tcp, ranked.opening_m, strict=True)
    ]
    plans = [p.delayed(max(len(q) for q in plans)) for p in plans]  # one length for every world
    rollouts: list[Rollout] = []
    for start in progress(range(0, len(jobs), size), "collect batches", total=-(-len(jobs) // size), unit="batch"):
        chunk = jobs[start : start + size]
        chunk = chunk + [chunk[-1]] * (size - len(chunk))  # a last batch filled up; the copies are dropped
        done = batch.run_batch(sim, plans, [g for g, _ in chunk], [p for _, p in chunk], path, cfg)
        rollouts += done[: len(jobs) - start]
    if sim.most_contacts >= cfg.newton.contacts_per_world * size:
        ctx.warn(
            f"collect: mujoco_warp used all {cfg.newton.contacts_per_world} contact slots per world and dropped "
            "contacts; raise collect.newton.contacts_per_world"
        )
    return world, rollouts, t_build


def _rounded(value: float) -> float | None:
    """A rollout's error [m] to 0.1 mm for the provenance record, None where it is not finite."""
    return round(float(value), 4) if np.isfinite(value) else None


def _finish(ctx: StageContext, outcome: Outcome) -> None:
    author_robot(ctx, outcome)
    rollouts = outcome.rollouts
    ctx.record(status=outcome.status, rollouts=len(rollouts), successes=sum(r.success for r in rollouts))
    if outcome.status == "ok":
        say(
            f"collect: {sum(r.success for r in rollouts)}/{len(rollouts)} rollouts succeeded "
            f"(best mean path error {100 * rollouts[outcome.best].mean_error_m:.1f} cm)"
        )
    else:
        ctx.warn(outcome.message)
