"""The simulated world of a rollout: the composed stage loaded with Newton's ``add_usd`` (the
scene's static collider, the object as a free body with its mass prior and convex parts), the
Panda added beside it with ``add_urdf``, and the MuJoCo contact settings that hold an object.

Contact settings, and why (measured on this CPU, ``docs/architecture.md`` amendment 28):

- MuJoCo's own collision detection (the only kind its C backend has) treats a mesh geom as its
  convex hull, so the room-sized scene collider would be one convex blob around everything. It
  is cut to a box around the object's path and the robot base (a boolean intersection, so it
  stays closed) and split into convex parts by CoACD, cached (``core.cache``).
  A part thinner than 1 mm (CoACD leaves such slivers) becomes a 2 mm slab into the scene: MuJoCo's
  CPU backend refuses a flat one.
- Finger pads and object: ``condim`` 6 (torsional and rolling friction), a stiff raw ``solref``
  (time constant 4 ms instead of MuJoCo's 20 ms) and a hard ``solimp``: the soft default let a
  held object slip 3-5x more. Pads have friction 1 (rubber); MuJoCo takes the larger of two
  geoms' friction, so the scene gets the object's prior friction, and object-scene contacts
  keep the prior while pad-object contacts use the pads'.
- An elliptic friction cone with ``impratio`` 100, and multi-point CCD (one contact point per
  face pair let a box sink 4.7 mm). MuJoCo's friction is soft, and under the pyramidal cone
  (impratio 10) cans and mugs gripped beside their axis (the only grasps narrower than the 7.6 cm
  opening) crept and turned 90-120 deg in the hand, and fell out. On the default suite's oracle
  reconstructions (3 grasps x 2 rollouts, the nine cases with a grasp) 24 of 54 rollouts
  succeeded with it, 46 with the elliptic cone at impratio 10, 49 at 100. MuJoCo's noslip
  iterations and pads split into 2 x 2 tiles changed no outcome.
- ``rigid_gap`` 1 cm instead of 10 cm: MuJoCo would otherwise list every pair within 10 cm.
- Arm drives: PD gains per joint, MuJoCo gravity compensation on every link, and velocity
  feed-forward (PD lag fell from 5.5 mm to 0.24 mm).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from pxr import Usd

from rose_usd.collect.config import NewtonConfig
from rose_usd.core import se3
from rose_usd.errors import StageError
from rose_usd.sim import panda

SOLIMP_HARD = (0.95, 0.99, 0.001, 0.5, 2.0)
MU_TORSIONAL_M = 0.01
MU_ROLLING_M = 0.0001
RIGID_GAP_M = 0.01


@dataclass
class World:
    """A finalized Newton model with the indices a rollout needs."""

    model: object
    object_body: int
    object_shapes: list[int]
    scene_shapes: list[int]
    robot_q0: int
    """First joint coordinate of the robot (the object's free joint comes first)."""
    robot_d0: int
    """First joint DOF of the robot."""
    robot_bodies: dict[str, int]
    """Panda link name -> body index."""
    pad_shapes: list[int]
    robot_shapes: list[int]
    object_q0: int
    """First coordinate of the object's free joint (position, then quaternion xyzw)."""
    base_pose: np.ndarray
    object_mass_kg: float
    object_friction: float
    scene_parts: int
    timings: dict[str, float] = field(default_factory=dict)
    worlds: int = 1
    """Copies of the world in the model (the indices above are the first's)."""
    coords_per_world: int = 0
    dofs_per_world: int = 0
    bodies_per_world: int = 0


def _set_attr(builder, key: str, index: int, value) -> None:
    attr = builder.custom_attributes[key]
    if attr.values is None:
        attr.values = {}
    attr.values[index] = value


def _grip_contacts(builder, shapes: list[int], cfg: NewtonConfig, mu: float) -> None:
    import warp as wp

    for s in shapes:
        builder.shape_material_mu[s] = mu
        builder.shape_material_mu_torsional[s] = MU_TORSIONAL_M
        builder.shape_material_mu_rolling[s] = MU_ROLLING_M
        _set_attr(builder, "mujoco:condim", s, int(cfg.condim))
        _set_attr(builder, "mujoco:solref", s, wp.vec2(float(cfg.contact_timeconst_s), 1.0))
        _set_attr(builder, "mujoco:solref_mode", s, 1)  # raw: not recomputed from ke/kd
        _set_attr(builder, "mujoco:geom_solimp", s, SOLIMP_HARD)


def crop_to_box(vertices: np.ndarray, faces: np.ndarray, lo: np.ndarray, hi: np.ndarray):
    """The closed mesh cut to the axis-aligned box [lo, hi] (a boolean intersection, so a closed
    collider stays closed); None when nothing is left."""
    import manifold3d

    mesh = manifold3d.Mesh(
        vert_properties=np.asarray(vertices, np.float32), tri_verts=np.asarray(faces, np.uint32).reshape(-1, 3)
    )
    solid = manifold3d.Manifold(mesh)
    if solid.status() != manifold3d.Error.NoError or solid.is_empty():
        return None
    box = manifold3d.Manifold.cube(tuple(float(v) for v in hi - lo)).translate(tuple(float(v) for v in lo))
    cut = (solid ^ box).to_mesh()
    v, f = np.asarray(cut.vert_properties)[:, :3], np.asarray(cut.tri_verts)
    return (v, f) if len(f) else None


class _Robot(NamedTuple):
    """Where the Panda landed in the model builder."""

    q0: int
    """First joint coordinate."""
    d0: int
    """First joint DOF."""
    bodies: dict[str, int]
    """Link name -> body index."""
    shapes: list[int]
    pads: list[int]
    """The two finger pads' shapes."""


def _add_stage(b, stage: Usd.Stage, object_path: str) -> int:
    """Load the stage into the builder ``b`` (no visual shapes); the object's body index."""
    result = b.add_usd(stage, load_visual_shapes=False, load_static_visual_shapes=False, verbose=False)
    body_of = {str(k): int(v) for k, v in dict(result.get("path_body_map", {})).items()}
    if object_path not in body_of:
        raise StageError(
            f"Newton built no body for {object_path}",
            path=stage.GetRootLayer().identifier,
            hint="check RigidBodyAPI on the object prim (re-run the object stage)",
        )
    return body_of[object_path]


def _scene_collider(b, newton, workspace: tuple[np.ndarray, np.ndarray], cfg: NewtonConfig) -> list[int]:
    """Cut the builder's static meshes to the workspace box (lo, hi) [m] and split them into convex
    parts (MuJoCo sees a mesh as its hull); the scene's shape indices."""

    statics = [s for s in range(b.shape_count) if b.shape_body[s] == -1 and b.shape_type[s] == newton.GeoType.MESH]
    lo, hi = workspace
    for s in statics:
        cut = crop_to_box(_shape_vertices(b, s), np.asarray(b.shape_source[s].indices).reshape(-1, 3), lo, hi)
        if cut is None:  # nothing of it near the robot: leave a tiny far-away sliver out of the way
            b.shape_flags[s] = 0
            continue
        _set_world_mesh(b, newton, s, *cut)
    statics = [s for s in statics if b.shape_flags[s]]
    n_before = b.shape_count
    if statics:
        b.approximate_meshes(
            "coacd",
            shape_indices=statics,
            raise_on_failure=False,
            threshold=cfg.coacd_threshold,
        )
    parts = statics + list(range(n_before, b.shape_count))
    thicken_flat_parts(b, newton, parts, 0.5 * (np.asarray(lo, dtype=float) + np.asarray(hi, dtype=float)))
    return parts


def thicken_flat_parts(b, newton, shapes: list[int], away_from: np.ndarray) -> int:
    """Replace each flat mesh or convex-mesh shape among ``shapes`` (CoACD's parts are convex
    meshes) by a slab (``thickened``) on the side away from ``away_from``; how many were."""
    count = 0
    for s in shapes:
        if b.shape_flags[s] and b.shape_type[s] in (newton.GeoType.MESH, newton.GeoType.CONVEX_MESH):
            thick = thickened(_shape_vertices(b, s), away_from)
            if thick is not None:
                _set_world_mesh(b, newton, s, *thick)
                count += 1
    return count


def _shape_vertices(b, s: int) -> np.ndarray:
    """Mesh shape ``s``'s vertices in the world (its scale and transform applied)."""
    xf = np.asarray(b.shape_transform[s], dtype=float)
    v = np.asarray(b.shape_source[s].vertices, dtype=float) * np.asarray(b.shape_scale[s], dtype=float)
    return v @ se3.matrix_from_quat_xyzw(xf[3:]).T + xf[:3]


def _set_world_mesh(b, newton, s: int, vertices: np.ndarray, faces: np.ndarray) -> None:
    """Make shape ``s`` the mesh (vertices in the world, faces (F, 3)) with no transform of its own."""
    import warp as wp

    b.shape_source[s] = newton.Mesh(vertices, np.asarray(faces).reshape(-1), compute_inertia=False)
    b.shape_transform[s] = wp.transform_identity()
    b.shape_scale[s] = (1.0, 1.0, 1.0)


def thickened(vertices: np.ndarray, away_from: np.ndarray, *, flat_m: float = 0.001, thickness_m: float = 0.002):
    """A flat convex part (thinner than ``flat_m`` across its plane: a sliver a convex
    decomposition left) as the hull of itself and its copy moved ``thickness_m`` along its normal,
    away from ``away_from`` (into the scene, its surface unchanged); (vertices, faces) or None when
    the part is not flat. MuJoCo's contacts refuse a planar mesh collider (Newton raises), and
    collide badly with one a few micrometres thick."""
    import trimesh

    v = np.asarray(vertices, dtype=float)
    if len(v) < 3:
        return None
    centred = v - v.mean(axis=0)
    normal = np.linalg.svd(centred, full_matrices=False)[2][-1]
    if np.ptp(centred @ normal) >= flat_m:
        return None
    if float(np.dot(v.mean(axis=0) - np.asarray(away_from, dtype=float), normal)) < 0:
        normal = -normal
    hull = trimesh.convex.convex_hull(np.concatenate([v, v + thickness_m * normal]))
    return np.asarray(hull.vertices, dtype=np.float32), np.asarray(hull.faces, dtype=np.int32)


def _add_panda(b, newton, base_pose: np.ndarray, cfg: NewtonConfig) -> _Robot:
    """Add the Panda at ``base_pose`` (4, 4) to the builder: home pose, drives, gravity compensation
    and gripping finger pads."""
    import warp as wp

    b0, s0, q0, d0 = b.body_count, b.shape_count, b.joint_coord_count, b.joint_dof_count
    base = wp.transform(base_pose[:3, 3].tolist(), se3.quat_xyzw_from_matrix(base_pose[:3, :3]).tolist())
    b.add_urdf(str(panda.panda_urdf()), xform=base, floating=False, enable_self_collisions=False, hide_visuals=True)
    n = len(panda.JOINTS)
    if b.joint_coord_count - q0 != n:
        raise StageError(f"the Panda's URDF gave {b.joint_coord_count - q0} joint coordinates, not {n}")
    b.joint_q[q0 : q0 + n] = panda.HOME_Q.tolist()
    b.joint_target_q[q0 : q0 + n] = panda.HOME_Q.tolist()
    b.joint_target_ke[d0 : d0 + n] = list(panda.ARM_KE) + [panda.FINGER_KE] * 2
    b.joint_target_kd[d0 : d0 + n] = list(panda.ARM_KD) + [panda.FINGER_KD] * 2
    b.joint_effort_limit[d0 : d0 + n] = list(panda.ARM_EFFORT_N_M) + [float(cfg.grip_force_n)] * 2
    b.joint_armature[d0 : d0 + n] = list(panda.ARM_ARMATURE) + [panda.FINGER_ARMATURE] * 2
    b.joint_target_mode[d0 : d0 + 7] = [int(newton.JointTargetMode.POSITION_VELOCITY)] * 7
    for d in range(d0, d0 + 7):
        _set_attr(b, "mujoco:jnt_actgravcomp", d, True)
    for body in range(b0 + 1, b.body_count):
        _set_attr(b, "mujoco:gravcomp", body, 1.0)
    bodies = {b.body_label[i].rsplit("/", 1)[-1]: i for i in range(b0, b.body_count)}
    fingers = {bodies[name] for name in panda.FINGER_LINKS}
    robot_shapes = list(range(s0, b.shape_count))
    pads = [
        s
        for s in robot_shapes
        if b.shape_body[s] in fingers
        and b.shape_type[s] == newton.GeoType.BOX
        and abs(float(b.shape_transform[s][2]) - 0.04525) < 1e-4  # the rubber tip box, 45.25 mm along the finger
    ]
    if len(pads) != 2:
        raise StageError(f"found {len(pads)} finger pads in the Panda's URDF, not 2")
    _grip_contacts(b, pads, cfg, float(cfg.pad_friction))
    return _Robot(q0, d0, bodies, robot_shapes, pads)


def _replicated(b, newton, worlds: int):
    """The builder ``b`` as ``worlds`` separate worlds of one builder (``b`` itself for one)."""
    if worlds <= 1:
        return b
    from newton.solvers import SolverMuJoCo

    many = newton.ModelBuilder()
    SolverMuJoCo.register_custom_attributes(many)
    many.rigid_gap = RIGID_GAP_M
    many.replicate(b, worlds)
    return many


def build_world(
    stage: Usd.Stage,
    object_path: str,
    base_pose: np.ndarray,
    workspace: tuple[np.ndarray, np.ndarray],
    cfg: NewtonConfig,
    *,
    worlds: int = 1,
    device: str = "cpu",
) -> World:
    """Load the stage and the Panda into one Newton model.

    Args:
        stage: the composed stage (scene collider, objects, at their default poses).
        object_path: prim path of the object the robot moves.
        base_pose: world pose of the robot base (4, 4).
        workspace: (lo, hi) corners [m] of the box the scene collider is cut to.
        worlds: copies of the world in the model (each its own MuJoCo world, for many rollouts
            stepped at once on a GPU).
        device: Warp device of the model ("cpu", "cuda:0").
    """
    import time

    from newton.solvers import SolverMuJoCo

    from rose_usd.sim.engine import newton as load_newton

    newton = load_newton()
    timings = {}
    t0 = time.perf_counter()
    b = newton.ModelBuilder()
    SolverMuJoCo.register_custom_attributes(b)
    b.rigid_gap = RIGID_GAP_M
    obj = _add_stage(b, stage, object_path)
    object_shapes = [s for s in range(b.shape_count) if b.shape_body[s] == obj]
    timings["load_s"] = time.perf_counter() - t0

    # the scene collider: cut to the workspace, then convex parts (MuJoCo sees a mesh as its hull)
    t0 = time.perf_counter()
    scene_shapes = _scene_collider(b, newton, workspace, cfg)
    timings["scene_decomposition_s"] = time.perf_counter() - t0

    friction = float(b.shape_material_mu[object_shapes[0]]) if object_shapes else 0.5
    _grip_contacts(b, object_shapes, cfg, friction)
    for s in scene_shapes:
        b.shape_material_mu[s] = friction

    robot = _add_panda(b, newton, base_pose, cfg)
    j = b.joint_child.index(obj)
    object_q0 = int(b.joint_q_start[j])
    mass = float(b.body_mass[obj])
    per_world = (b.joint_coord_count, b.joint_dof_count, b.body_count)
    model = _replicated(b, newton, worlds).finalize(device=device)
    return World(
        model=model,
        object_body=obj,
        object_shapes=object_shapes,
        scene_shapes=scene_shapes,
        robot_q0=robot.q0,
        robot_d0=robot.d0,
        robot_bodies=robot.bodies,
        pad_shapes=robot.pads,
        robot_shapes=robot.shapes,
        object_q0=object_q0,
        base_pose=np.asarray(base_pose, dtype=float),
        object_mass_kg=mass,
        object_friction=friction,
        scene_parts=len(scene_shapes),
        timings=timings,
        worlds=worlds,
        coords_per_world=per_world[0],
        dofs_per_world=per_world[1],
        bodies_per_world=per_world[2],
    )
