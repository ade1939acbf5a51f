"""The collect stage's math against analytic answers: antipodal grasps on a box, the gripper's
collision boxes, the follow transform, the Panda's forward kinematics against Newton's."""

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from rose_usd.collect import motion
from rose_usd.core import se3
from rose_usd.geometry import grasps


def _box(extents):
    mesh = trimesh.creation.box(extents=extents)
    return np.asarray(mesh.vertices), np.asarray(mesh.faces)


def test_antipodal_pairs_on_a_box_are_its_opposing_faces():
    """On a 6 x 4 x 10 cm box with an 8 cm gripper, every pair joins the two x faces or the two y
    faces (the z faces are 10 cm apart), inside the friction cone, and both kinds are found."""
    vertices, faces = _box([0.06, 0.04, 0.10])
    points, normals = grasps.sample_surface(vertices, faces, 600, np.random.default_rng(0))
    pairs = grasps.antipodal_pairs(points, normals, friction=0.3, max_width_m=0.08)
    assert len(pairs) > 50
    axis = np.abs(pairs.axis)
    along_x, along_y = axis[:, 0] > np.cos(np.arctan(0.3)), axis[:, 1] > np.cos(np.arctan(0.3))
    assert np.all(along_x | along_y) and along_x.any() and along_y.any()
    np.testing.assert_allclose(np.abs(pairs.p1[along_x, 0]), 0.03, atol=1e-9)
    np.testing.assert_allclose(np.abs(pairs.p2[along_y, 1]), 0.02, atol=1e-9)
    assert np.all(pairs.width[along_x] >= 0.06 - 1e-9) and np.all(pairs.width[along_y] >= 0.04 - 1e-9)
    assert np.all(pairs.alignment >= np.cos(np.arctan(0.3)) - 1e-9)


def test_no_antipodal_pair_when_the_box_is_too_wide():
    """A 9 cm cube has no pair within an 8 cm opening."""
    vertices, faces = _box([0.09, 0.09, 0.09])
    points, normals = grasps.sample_surface(vertices, faces, 400, np.random.default_rng(1))
    assert len(grasps.antipodal_pairs(points, normals, friction=0.5, max_width_m=0.08)) == 0


def test_grasp_frames_close_along_the_pair_and_turn_about_it():
    """Frames are rotations with y along the closing line and the origin at the midpoint; the
    turns about y are evenly spread."""
    pairs = grasps.Antipodal(np.array([[0.0, -0.02, 0.05]]), np.array([[0.0, 0.02, 0.05]]), np.ones(1))
    frames, which = grasps.grasp_frames(pairs, 4)
    assert frames.shape == (4, 4, 4) and np.all(which == 0)
    for f in frames:
        np.testing.assert_allclose(f[:3, :3].T @ f[:3, :3], np.eye(3), atol=1e-12)
        assert np.linalg.det(f[:3, :3]) == pytest.approx(1.0)
        np.testing.assert_allclose(f[:3, 1], [0, 1, 0], atol=1e-12)
        np.testing.assert_allclose(f[:3, 3], [0, 0, 0.05], atol=1e-12)
    approach = frames[:, :3, 2]
    np.testing.assert_allclose(approach[0], [0, 0, -1], atol=1e-12)  # the first comes from above
    np.testing.assert_allclose(approach[2], [0, 0, 1], atol=1e-12)


def test_boxes_hit_finds_points_inside_placed_boxes():
    """A unit box at a frame turned 90 deg about z holds a point at its rotated offset only."""
    frame = se3.make_pose(Rotation.from_euler("z", 90, degrees=True).as_matrix(), [1.0, 0.0, 0.0])
    centres, halves = np.array([[0.5, 0.0, 0.0]]), np.array([[0.1, 0.1, 0.1]])
    inside, outside = np.array([[1.0, 0.5, 0.0]]), np.array([[1.5, 0.0, 0.0]])
    assert grasps.boxes_hit(frame[None], centres, halves, inside)[0]
    assert not grasps.boxes_hit(frame[None], centres, halves, outside)[0]


def test_follow_keeps_the_grasp_relative_pose():
    """T_ee(t) = T_obj(t) T_obj(tg)^-1 T_ee(tg): at the grasp it is T_ee(tg), and the object
    stays put in the tool frame at every t."""
    rng = np.random.default_rng(3)
    path = se3.make_pose(Rotation.random(10, random_state=4).as_matrix(), rng.normal(size=(10, 3)))
    obj_grasp, ee_grasp = path[0], se3.make_pose(Rotation.random(random_state=5).as_matrix(), [0.1, 0.2, 0.3])
    ee = motion.follow_poses(path, obj_grasp, ee_grasp)
    np.testing.assert_allclose(ee[0], ee_grasp, atol=1e-12)
    in_hand = np.einsum("nij,njk->nik", se3.invert(ee), path)
    np.testing.assert_allclose(in_hand, np.broadcast_to(se3.invert(ee_grasp) @ obj_grasp, in_hand.shape), atol=1e-12)


def test_follow_of_a_pure_translation_translates_the_tool():
    """An object sliding 20 cm along x moves the tool 20 cm along x without turning it."""
    path = np.stack([se3.make_pose(np.eye(3), [0.2 * s, 0.0, 0.0]) for s in np.linspace(0, 1, 5)])
    ee_grasp = se3.make_pose(Rotation.from_euler("x", 180, degrees=True).as_matrix(), [0.0, 0.0, 0.04])
    ee = motion.follow_poses(path, path[0], ee_grasp)
    np.testing.assert_allclose(ee[:, :3, :3], np.broadcast_to(ee_grasp[:3, :3], (5, 3, 3)), atol=1e-12)
    np.testing.assert_allclose(ee[:, 0, 3], np.linspace(0, 0.2, 5), atol=1e-12)


def test_panda_forward_kinematics_matches_newton():
    """The URDF chain in numpy gives Newton's body poses (eval_fk) for random joint coordinates."""
    import warp as wp

    from rose_usd.sim import panda
    from rose_usd.sim.engine import newton as load_newton

    newton = load_newton()
    chain = panda.chain()
    builder = newton.ModelBuilder()
    builder.add_urdf(str(panda.panda_urdf()), floating=False, enable_self_collisions=False, hide_visuals=True)
    model = builder.finalize(device="cpu")
    state = model.state()
    qs = np.random.default_rng(0).uniform(chain.lower, chain.upper, size=(4, 9))
    for q in qs:
        newton.eval_fk(model, wp.array(q.astype(np.float32)), model.joint_qd, state)
        body_q = state.body_q.numpy()
        mine = chain.forward(q)
        for i, label in enumerate(builder.body_label):
            link = chain.index(label.rsplit("/", 1)[-1])
            np.testing.assert_allclose(body_q[i, :3], mine[link, :3, 3], atol=1e-5)
            np.testing.assert_allclose(se3.matrix_from_quat_xyzw(body_q[i, 3:]), mine[link, :3, :3], atol=1e-5)


def test_a_missing_robot_description_is_one_line(monkeypatch):
    """Without the mani-skill wheel the error names the pip command that fixes it."""
    from rose_usd.errors import EnvironmentProblem
    from rose_usd.sim import panda

    panda._urdf_path.cache_clear()
    monkeypatch.setattr(panda, "URDF_IN_WHEEL", "mani_skill/assets/robots/panda/missing.urdf")
    try:
        with pytest.raises(EnvironmentProblem, match="pip install --no-deps"):
            panda.panda_urdf()
    finally:
        panda._urdf_path.cache_clear()


def test_flat_pads_open_as_wide_as_the_object_across_them():
    """On an 8 cm cylinder an off-centre chord inside the friction cone is shorter than 8 cm, but
    the pads must open to about the full diameter: closing_extent puts every such frame over a
    7.6 cm limit (within a point sample's resolution of 8 cm)."""
    mesh = trimesh.creation.cylinder(radius=0.04, height=0.1, sections=96)
    vertices, faces = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    points, normals = grasps.sample_surface(vertices, faces, 800, np.random.default_rng(2))
    pairs = grasps.antipodal_pairs(points, normals, friction=0.5, max_width_m=0.076)
    assert len(pairs) > 0 and pairs.width.max() <= 0.076  # chords that pass a width test on their own
    frames, _ = grasps.grasp_frames(pairs, 2)
    cloud, _ = grasps.sample_surface(vertices, faces, 4000, np.random.default_rng(3))
    extent, _ = grasps.closing_extent(frames, cloud, 0.00875, (-0.00925, 0.00925))
    horizontal = np.abs(frames[:, 2, 1]) < 0.1  # closing across the axis, not along it
    assert np.all(extent[horizontal] > 0.076)
    assert np.median(extent[horizontal]) == pytest.approx(0.08, abs=0.001)


def test_a_flat_scene_part_is_thickened_into_the_scene():
    """A convex part with no thickness (MuJoCo refuses it as a collider) becomes a 2 mm slab on
    the side away from the robot's workspace, its top surface where it was; a solid part stays."""
    from rose_usd.collect.world import thickened

    square = np.array([[0, 0, 0.7], [0.1, 0, 0.7], [0.1, 0.1, 0.7], [0, 0.1, 0.7]], float)
    tilt = np.array([[1, 0, 0], [0, np.cos(0.3), -np.sin(0.3)], [0, np.sin(0.3), np.cos(0.3)]])
    for rotate in (np.eye(3), tilt):
        v, faces = thickened(square @ rotate.T, away_from=np.array([0.05, 0.05, 1.5]) @ rotate.T)
        local = v @ rotate  # back in the square's frame
        assert local[:, 2].max() == pytest.approx(0.7, abs=1e-6) and local[:, 2].min() == pytest.approx(0.698, abs=1e-6)
        assert len(faces) == 12  # a box
    cube = np.array([[x, y, z] for x in (0, 0.1) for y in (0, 0.1) for z in (0, 0.1)], float)
    assert thickened(cube, away_from=np.zeros(3)) is None
    sliver = np.array([[0, 0, 0.7], [0.02, 0, 0.7], [0, 0.02, 0.7005], [0.02, 0.02, 0.7005]], float)
    assert thickened(sliver, away_from=np.array([0.0, 0.0, 1.5])) is not None  # 0.35 mm thick


def test_flat_convex_parts_become_slabs_mujoco_accepts():
    """A convex-mesh scene part with no thickness (CoACD leaves such slivers, a 0.4 mm triangle
    on the sample) made MuJoCo's CPU backend refuse the whole world; thickened, the world builds
    and a part with volume is left as it was."""
    import warp as wp
    from newton.solvers import SolverMuJoCo

    from rose_usd.collect.world import thicken_flat_parts
    from rose_usd.sim.engine import newton as load_newton

    newton = load_newton()
    b = newton.ModelBuilder()
    SolverMuJoCo.register_custom_attributes(b)
    slab = trimesh.creation.box((0.6, 0.6, 0.02))
    slab.apply_translation((0.0, 0.0, -0.01))
    solid = b.add_shape_convex_hull(-1, mesh=newton.Mesh(slab.vertices, slab.faces.reshape(-1)))
    tri = np.array([[0.1, 0.1, 0.0], [0.1004, 0.1, 0.0], [0.1, 0.1004, 0.0]])
    flat = b.add_shape_convex_hull(-1, mesh=newton.Mesh(tri, np.array([0, 1, 2])))
    body = b.add_body(xform=wp.transform((0.0, 0.0, 0.1), wp.quat_identity()))
    b.add_shape_box(body, hx=0.02, hy=0.02, hz=0.02)
    with pytest.raises(ValueError, match="planar mesh"):
        SolverMuJoCo(b.finalize(device="cpu"), use_mujoco_cpu=True)
    assert thicken_flat_parts(b, newton, [solid, flat], np.array([0.0, 0.0, 0.5])) == 1
    v = np.asarray(b.shape_source[flat].vertices)
    assert v[:, 2].max() == pytest.approx(0.0, abs=1e-7) and v[:, 2].min() == pytest.approx(-0.002, abs=1e-6)
    assert np.ptp(np.asarray(b.shape_source[solid].vertices)[:, 2]) == pytest.approx(0.02, abs=1e-7)
    SolverMuJoCo(b.finalize(device="cpu"), use_mujoco_cpu=True)


def test_a_follow_the_arm_keeps_up_with_is_one_tick_a_frame():
    q = np.zeros((20, 9))
    q[:, 0] = 0.01 * np.arange(20)  # 0.3 rad/s at 30 fps
    np.testing.assert_array_equal(motion.retimed(q, 30.0), np.arange(20.0))


def test_a_fast_step_is_followed_slower_under_the_speed_limit():
    from rose_usd.sim import panda

    q = np.zeros((20, 9))
    q[:, 0] = 0.01 * np.arange(20)
    q[10:, 5] += 0.3  # joint 6 turns 0.3 rad in one frame: 9 rad/s at 30 fps
    frames = motion.retimed(q, 30.0)
    assert frames[0] == 0 and frames[-1] == 19 and np.all(np.diff(frames) > 0)
    ticks_q = np.stack([np.interp(frames, np.arange(20), q[:, j]) for j in range(7)], axis=1)
    speed = np.abs(np.diff(ticks_q, axis=0)) * 30.0
    limit = motion.FOLLOW_SPEED * np.asarray(panda.ARM_MAX_VELOCITY_RAD_S)
    assert np.all(speed <= limit * (1 + 1e-9))
    # one tick a frame away from the step, and the slowdown eased in over the ramp's frames
    assert np.allclose(np.diff(frames[:5]), 1.0) and np.allclose(np.diff(frames[-5:]), 1.0)
    pace = np.diff(frames)
    slowest = int(pace.argmin())
    assert np.all(np.diff(pace[: slowest + 1]) <= 1e-12) and np.all(np.diff(pace[slowest:]) >= -1e-12)


def test_a_retimed_plan_records_the_video_frame_of_each_tick():
    plan = motion.Plan(rate_hz=30.0)
    plan.hold(np.zeros(9), 0.1, "home", 0.04, np.full((4, 4), np.nan))
    q = np.zeros((6, 9))
    q[3:, 0] = 0.5
    frames = motion.retimed(q, 30.0)
    for qq, f in zip(np.stack([np.interp(frames, np.arange(6), q[:, j]) for j in range(9)], axis=1), frames):
        plan._append(qq, np.eye(4), "follow", f)
    plan.hold(q[-1], 0.1, "release", 0.04, np.eye(4))
    video = plan.video_frames()
    assert np.all(video[:3] == 0) and np.all(video[-3:] == 5) and len(video) == len(plan) > 12
    assert np.all(np.diff(video) >= 0)


def test_poses_at_fractional_frames_interpolate_position_and_turn():
    a = np.eye(4)
    b = se3.make_pose(se3.rotation_about([0, 0, 1], np.radians(90)), [0.2, 0, 0])
    mid = motion.poses_at(np.stack([a, b]), np.array([0.0, 0.5, 1.0]))
    np.testing.assert_allclose(mid[1, :3, 3], [0.1, 0, 0], atol=1e-12)
    assert abs(se3.rotation_angle_deg(mid[1, :3, :3]) - 45.0) < 1e-6
    np.testing.assert_allclose(mid[2], b, atol=1e-12)


def test_grasps_whose_arm_meets_the_scene_on_the_path_rank_last():
    from rose_usd.collect import grasping

    down = np.diag([1.0, -1.0, -1.0])
    turned = se3.rotation_about([0, 0, 1], np.radians(90)) @ down
    grasps_ = grasping.Candidates(
        object_from_tcp=np.stack([se3.make_pose(down, [0, 0, 0.02]), se3.make_pose(turned, [0, 0, 0.02])]),
        width_m=np.array([0.05, 0.05]),
        opening_m=np.array([0.08, 0.08]),
        com_distance_m=np.array([0.0, 0.01]),  # the first is the better by the prior
        depth_m=np.zeros(2),
        approach_up=np.array([-1.0, -1.0]),
        alignment=np.array([1.0, 1.0]),
        sampled_pairs=2,
    )
    path = np.repeat(se3.make_pose(np.eye(3), [0.5, 0.0, 0.1])[None], 12, axis=0)
    path[:, 0, 3] += np.linspace(0.0, 0.05, 12)
    plain = grasping.rank(np.eye(4), path, grasps_, 1, 0.01)
    np.testing.assert_array_equal(plain.object_from_tcp[0], grasps_.object_from_tcp[0])
    # the two grasps' wrists (joint 7) differ by a quarter turn: call the first one's arm blocked
    q_first, q_second = (_wrist(path[0] @ grasps_.object_from_tcp[k]) for k in range(2))
    cut, sign = 0.5 * (q_first + q_second), np.sign(q_second - q_first)
    blocked = grasping.rank(np.eye(4), path, grasps_, 1, 0.01, clearance=lambda q: sign * (q[..., 6] - cut))
    np.testing.assert_array_equal(blocked.object_from_tcp[0], grasps_.object_from_tcp[1])


def _wrist(tcp: np.ndarray) -> float:
    """Joint 7 of the IK solution for a tool pose, the base at the origin."""
    from rose_usd.collect import ik
    from rose_usd.sim import panda

    q, _, _ = ik.solve(tcp[None], panda.HOME_Q, n_seeds=8, iterations=80)
    return float(q[0, 6])


def _lying_pen_candidates(radius: float, clearance_m: float = 0.015, neighbour_m: float | None = None):
    """Grasp candidates of a pen (a cylinder ``radius`` thick, 14 cm long, along x) lying on a table
    at z = 0 (points 4 mm apart), the object frame the world's; with ``neighbour_m``, a second pen
    lies parallel to it that far away (centre to centre)."""
    from rose_usd.collect import grasping

    def pen_at(y: float) -> trimesh.Trimesh:
        pen = trimesh.creation.cylinder(radius=radius, height=0.14, sections=48)
        pen.apply_transform(se3.make_pose(se3.rotation_about([0, 1, 0], np.pi / 2), [0.5, y, radius]))
        return pen

    pen = pen_at(0.0)
    g = np.arange(-0.2, 0.2, 0.004)
    scene = np.stack(np.meshgrid(0.5 + g, g, [0.0]), axis=-1).reshape(-1, 3)
    if neighbour_m is not None:
        scene = np.concatenate([scene, pen_at(neighbour_m).sample(3000, seed=1)])
    path = np.repeat(np.eye(4)[None], 6, axis=0)
    path[3:, 2, 3] = 0.05  # lifted 5 cm half way
    return grasping.candidates(
        np.asarray(pen.vertices),
        np.asarray(pen.faces),
        np.asarray(pen.center_mass),
        path,
        scene,
        friction=0.5,
        max_width_m=0.076,
        clearance_m=clearance_m,
        surface_points=300,
        approach_turns=12,
        lift_m=0.01,
        rng=np.random.default_rng(0),
    )


def test_a_thin_pen_lying_on_the_table_is_held_near_the_pads_tips():
    """An 11 mm pen: held at the pads' centre, their tips (9.25 mm past it) would be 4 mm into the
    table; the grasps found hold the chord nearer the tips, close level and come straight down,
    every fingertip above the table, the pen's axis between the pads, the fingers pre-shaped to its
    width plus 1.5 cm a side (past its farther side)."""
    from rose_usd.collect import grasping
    from rose_usd.sim import panda

    cands = _lying_pen_candidates(0.0055)
    assert len(cands) > 0
    assert set(np.round(cands.depth_m, 4)) <= set(grasping.GRASP_DEPTHS_M) - {0.0}
    # evenly about the tcp, 1.5 cm past the pen's farther side: at least its width plus 3 cm
    assert np.all(cands.opening_m >= cands.width_m + 0.03 - 1e-9) and np.all(cands.opening_m < 0.06)
    assert np.all((cands.width_m > 0.010) & (cands.width_m < 0.02))  # flat pads: the pen's extent across them
    assert np.all(cands.approach_up < -0.99)
    for frame, opening in zip(cands.object_from_tcp, cands.opening_m, strict=True):
        assert abs(frame[2, 1]) < np.sin(np.radians(2.0))  # closing level
        for side in (1.0, -1.0):  # the finger box's lowest corner, at this opening
            centre, half = panda.finger_box(side)
            corners = centre + half * np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).reshape(3, -1).T
            corners[:, 1] += side * opening / 2
            assert se3.transform_points(frame, corners)[:, 2].min() > 0.0
        axis_in_tcp = se3.transform_points(se3.invert(frame), np.array([[0.5, 0.0, 0.0055]]))[0]
        assert panda.PAD_Z[0] < axis_in_tcp[2] < panda.PAD_Z[1]


def test_a_pen_beside_another_is_grasped_only_with_the_fingers_pre_shaped():
    """A second pen 6 cm away: fingers opened all the way (8 cm apart, each 2.6 cm thick) reach
    into it from every grasp across the pen; opened to the pen's width plus 1.5 cm a side, they do not."""
    from rose_usd.collect import grasping

    assert len(_lying_pen_candidates(0.0055, neighbour_m=0.06)) > 0
    with pytest.raises(grasping.NoGrasp, match="into the scene or the object"):
        _lying_pen_candidates(0.0055, clearance_m=0.04, neighbour_m=0.06)


def test_the_smallest_clearance_still_leaves_grasps():
    """At collect.grasp_clearance_m's lower limit (5 mm) the pads open 5 mm past the object's
    farther side, centred on it or not, and grasps remain (at 0 the fingers would touch it)."""
    from rose_usd.collect.config import CollectConfig
    from rose_usd.errors import ConfigError
    from rose_usd.stage_config import build_config

    with pytest.raises(ConfigError, match="grasp_clearance_m"):
        build_config("collect", CollectConfig, {"grasp_clearance_m": 0.0}, source="--set")
    assert len(_lying_pen_candidates(0.0055, clearance_m=0.005)) > 0


def test_a_thick_object_is_held_at_the_pads_centre_where_it_can_be():
    """A 4 cm cylinder lying on the table: grasps at the pads' centre exist; the pre-shape opens
    the fingers to 4 + 3 cm, at most 8; of two grasps alike but for the depth, the centred ranks first."""
    from rose_usd.collect import grasping

    cands = _lying_pen_candidates(0.02)
    assert np.any(cands.depth_m == 0.0)
    assert np.all(cands.opening_m >= np.minimum(0.08, cands.width_m + 0.03) - 1e-9)
    assert np.all(cands.opening_m <= 0.08)
    two = cands.take(np.array([0, 0]))
    two = grasping.Candidates(**{**two.__dict__, "depth_m": np.array([0.007, 0.0])})
    assert list(two.prior_order()) == [1, 0]


def test_the_plan_opens_the_fingers_to_the_pre_shape_only():
    from rose_usd.sim import panda

    grasp = se3.make_pose(np.diag([1.0, -1.0, -1.0]), [0.5, 0.0, 0.1])
    route = _straight_route
    plan = motion.approach_plan(np.eye(4), grasp, 30.0, 0.5, route, opening_m=0.03)
    fingers = np.array(plan.q)[:, 7]
    assert fingers.max() == pytest.approx(0.015) and fingers[-1] == 0.0
    motion.carry_plan(plan, np.eye(4), np.repeat(grasp[None], 4, axis=0), 0.01)
    release = np.array(plan.q)[plan.phase_ticks("release"), 7]
    assert release[-1] == pytest.approx(0.015)
    assert motion.approach_plan(np.eye(4), grasp, 30.0, 0.5, route).opening_m == panda.MAX_OPENING_M


def _straight_route(q_from: np.ndarray, q_to: np.ndarray):
    from rose_usd.collect import planning

    return planning.Route(np.stack([q_from[:7], q_to[:7]]), "straight", np.inf)


def test_levelled_pairs_close_level_where_they_stay_in_the_friction_cone():
    """A chord tilted 10 deg whose contacts are 5 deg off their normals turns level (15 deg, inside
    the 26.6 deg cone of friction 0.5), width and midpoint kept; one tilted 25 deg (30) is dropped."""

    def pair(tilt_deg: float) -> np.ndarray:
        return 0.01 * np.array([np.cos(np.radians(tilt_deg)), 0.0, np.sin(np.radians(tilt_deg))])

    p1 = np.array([[0.1, 0.2, 0.05], [0.0, 0.0, 0.05], [0.0, 0.0, 0.05]])
    p2 = p1 + np.stack([pair(10.0), pair(25.0), pair(0.0)])
    pairs = grasps.Antipodal(p1, p2, np.full(3, np.cos(np.radians(5.0))))
    flat = grasps.levelled(pairs, np.array([0.0, 0.0, 1.0]), friction=0.5)
    assert len(flat) == 1  # the level one needs no turn, the 25 deg one leaves the cone
    np.testing.assert_allclose(flat.axis[0], [1.0, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(flat.center[0], pairs.center[0], atol=1e-12)
    assert flat.width[0] == pytest.approx(0.01)
    assert flat.alignment[0] == pytest.approx(np.cos(np.radians(15.0)))


def test_the_first_approach_of_a_level_pair_is_straight_down_the_given_way():
    """Frames for a level closing axis: the first approach is ``down`` exactly, whatever the
    object frame's own z (here the object lies turned 90 deg about x: the world's down is its +y)."""
    pairs = grasps.Antipodal(np.array([[0.0, 0.0, 0.0]]), np.array([[0.02, 0.0, 0.0]]), np.ones(1))
    down = np.array([0.0, 1.0, 0.0])
    frames, _ = grasps.grasp_frames(pairs, 12, down=down)
    np.testing.assert_allclose(frames[0, :3, 2], down, atol=1e-12)
    default, _ = grasps.grasp_frames(pairs, 12)
    np.testing.assert_allclose(default[0, :3, 2], [0.0, 0.0, -1.0], atol=1e-12)
