"""The approach's route: the arm's clearance from obstacles and OMPL's way around them."""

import numpy as np
import trimesh

from rose_usd.collect import motion, planning
from rose_usd.sim import panda


def _box(centre, extents) -> tuple[np.ndarray, np.ndarray]:
    box = trimesh.creation.box(extents=extents)
    box.apply_translation(centre)
    return np.asarray(box.vertices), np.asarray(box.faces)


def test_clearance_over_a_floor_is_the_arms_lowest_point():
    """Over a wide slab whose top is at z = -0.2 (the base link excluded), the arm's clearance is the
    height of its lowest point above the slab; a slab raised into the hand gives a negative one."""
    base = np.eye(4)
    base[:3, 3] = [0.1, -0.2, 0.0]
    floor = _box([0.0, 0.0, -0.7], [4.0, 4.0, 1.0])
    checker = planning.ArmChecker(base, [floor])
    qs = np.stack([panda.HOME_Q, panda.HOME_Q + np.r_[0.4, 0.3, -0.2, 0.3, 0.5, -0.4, 0.2, 0.0, 0.0]])
    lowest = checker.world_points(qs)[..., 2].min(axis=-1)
    np.testing.assert_allclose(checker.clearance(qs, exact_m=1.0), lowest + 0.2, atol=1e-4)
    # farther than exact_m (5 cm by default) from everything, a lower bound no smaller than that
    bound = checker.clearance(qs)
    assert np.all((bound >= 0.05) & (bound <= lowest + 0.2 + 1e-4))
    tcp_z = (base @ panda.chain().tcp(panda.HOME_Q))[2, 3]
    raised = planning.ArmChecker(base, [_box([0.0, 0.0, tcp_z + 0.02 - 0.5], [4.0, 4.0, 1.0])])
    assert raised.clearance(panda.HOME_Q) < -0.01
    # seven joint coordinates are the arm's with the fingers open
    assert checker.clearance(panda.HOME_Q[:7]) == checker.clearance(panda.HOME_Q)


def test_a_clear_straight_line_is_kept():
    checker = planning.ArmChecker(np.eye(4), [_box([0.0, 0.0, -0.5], [4.0, 4.0, 1.0])])
    goal = panda.HOME_Q.copy()
    goal[0] += 1.0
    route = checker.route(panda.HOME_Q, goal)
    assert route.how == "straight" and route.clearance_m >= checker.clearance_m
    np.testing.assert_array_equal(route.waypoints, np.stack([panda.HOME_Q[:7], goal[:7]]))


def test_a_pillar_in_the_way_is_gone_around():
    """Turning joint 1 by 1.5 rad sweeps the hand through a pillar; RRTConnect finds a route whose
    every segment keeps the clearance, from the start to the goal exactly."""
    angle = 0.75
    pillar = _box([0.31 * np.cos(angle), 0.31 * np.sin(angle), 0.3], [0.1, 0.1, 0.6])
    checker = planning.ArmChecker(np.eye(4), [pillar])
    goal = panda.HOME_Q.copy()
    goal[0] += 1.5
    assert checker.line_clearance(panda.HOME_Q, goal, 0.02) < 0
    route = checker.route(panda.HOME_Q, goal, time_s=5.0)
    assert route.how == "planned", route
    assert len(route.waypoints) >= 3
    np.testing.assert_allclose(route.waypoints[0], panda.HOME_Q[:7])
    np.testing.assert_allclose(route.waypoints[-1], goal[:7])
    for a, b in zip(route.waypoints[:-1], route.waypoints[1:], strict=True):
        assert checker.line_clearance(a, b, 0.01) >= checker.clearance_m * 0.9
    chain = panda.chain()
    assert np.all(route.waypoints >= chain.lower[:7] - 1e-9) and np.all(route.waypoints <= chain.upper[:7] + 1e-9)


def test_an_end_inside_an_obstacle_is_reported_not_planned():
    tcp = panda.chain().tcp(panda.HOME_Q)[:3, 3]
    checker = planning.ArmChecker(np.eye(4), [_box(tcp, [0.1, 0.1, 0.1])])
    goal = panda.HOME_Q.copy()
    goal[0] += 1.0
    assert checker.route(panda.HOME_Q, goal).how == "start-blocked"
    assert checker.route(goal, panda.HOME_Q).how == "goal-blocked"


def test_joint_path_passes_every_waypoint_in_order_and_ends_at_the_last():
    plan = motion.Plan(rate_hz=30.0)
    waypoints = np.array(
        [np.zeros(7), np.r_[1.0, np.zeros(6)], np.r_[1.0, 0.5, np.zeros(5)], np.r_[0.0, 0.5, np.zeros(5)]]
    )
    plan.joint_path(waypoints, 2.0, "approach", 0.04)
    q = np.asarray(plan.q)
    assert q.shape == (60, 9) and np.all(q[:, 7:] == 0.04) and set(plan.phase) == {"approach"}
    np.testing.assert_allclose(q[-1, :7], waypoints[-1], atol=1e-12)
    # on the segments, in order: joint 1 rises to 1, then joint 2 to 0.5, then joint 1 falls to 0
    assert np.all(q[:, 2:7] == 0)
    segment = np.where(q[:, 1] == 0, 0, np.where(q[:, 1] < 0.5, 1, 2))
    assert np.all(np.diff(segment) >= 0) and set(segment) == {0, 1, 2}
    assert np.all(q[segment == 1, 0] == 1.0)
    assert np.all(np.diff(q[segment == 0, 0]) > 0) and np.all(np.diff(q[segment == 2, 0]) < 0)
    # eased in and out: the first and last steps are the smallest
    steps = np.abs(np.diff(q[:, :7], axis=0)).max(axis=1)
    assert steps[0] < steps.max() / 5 and steps[-1] < steps.max() / 5


def test_a_delayed_plan_holds_its_first_tick_in_front():
    plan = motion.Plan(rate_hz=30.0)
    plan.joint_path(np.stack([panda.HOME_Q, panda.HOME_Q + 0.1]), 0.5, "approach", 0.04)
    longer = plan.delayed(len(plan) + 7)
    assert len(longer) == len(plan) + 7 and longer.phase[:7] == ["home"] * 7
    assert all(np.array_equal(q, plan.q[0]) for q in longer.q[:8]) and longer.q[7:] == plan.q
    assert len(plan.delayed(3)) == len(plan)
