"""Grasps and the robot base, without learned weights.

1. Antipodal pairs on the object's visual mesh (``rose_usd.geometry.grasps``), and the same
   pairs closing level where that keeps them antipodal, each turned into tool frames at several
   approach directions, the first the nearest straight down.
2. Rejected where the gripper (hand and fingers as boxes, the fingers pre-shaped: opened evenly
   about the grasp to a clearance past the object's farther side between the pads) holds a point
   of the scene collider or of the object: at the grasp, on the way in from the pre-grasp, and,
   carried with the object, along its path. A grasp that fails with the chord between the pads'
   centres is tried with the chord nearer the pads' tips (``GRASP_DEPTHS_M``): an object thinner
   than the pads are long, lying on the support, is only held that way.
3. The base: candidates on the support's height on rings around the path, facing it; each
   scored by how much of the path the best few grasps reach (batched IK), unless rose.toml fixes it.
4. Ranking: reachable along the whole path (batched IK) first, then the grasp centre's distance
   to the centre of mass and how far the approach is from straight down.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from rose_usd.collect import ik, motion
from rose_usd.core import se3
from rose_usd.geometry import grasps as antipodal
from rose_usd.sim import panda

REACH_POS_M = 0.005
"""IK position error under which a pose counts as reached [m]."""
REACH_ROT_DEG = 3.0
GRASP_DEPTHS_M = (0.0, 0.004, 0.007)
"""Where the chord may sit along the approach, from the tcp (the pads' centre) toward their tips,
tried in this order [m]: the fingers reach 9.5 mm past the tcp, so a pen 11 mm thick held at its
middle puts the fingertips 4 mm into the desk it lies on; at 7 mm they stay 3 mm above it."""


class NoGrasp(Exception):
    """No grasp survived; the message says why (one line)."""


@dataclass(frozen=True)
class Candidates:
    """Grasp candidates in the object frame."""

    object_from_tcp: np.ndarray
    """(G, 4, 4)."""
    width_m: np.ndarray
    """(G,) how far the pads must open: the object's extent across them [m]."""
    opening_m: np.ndarray
    """(G,) how far the pads open before they close (the pre-shape), evenly about the tcp: the
    clearance past the object's farther side on each side, at most the Panda's 8 cm [m]."""
    com_distance_m: np.ndarray
    """(G,) from the grasp centre to the centre of mass [m]."""
    depth_m: np.ndarray
    """(G,) where the chord sits from the tcp toward the pads' tips (one of ``GRASP_DEPTHS_M``) [m]."""
    approach_up: np.ndarray
    """(G,) world z of the approach direction at frame 0 (-1 straight down)."""
    alignment: np.ndarray
    """(G,) the antipodal pair's alignment (see ``Antipodal.alignment``)."""
    sampled_pairs: int
    """Antipodal pairs found before any was rejected."""

    def __len__(self) -> int:
        return len(self.object_from_tcp)

    def take(self, index: np.ndarray) -> "Candidates":
        return Candidates(
            self.object_from_tcp[index],
            self.width_m[index],
            self.opening_m[index],
            self.com_distance_m[index],
            self.depth_m[index],
            self.approach_up[index],
            self.alignment[index],
            self.sampled_pairs,
        )

    def prior_order(self) -> np.ndarray:
        """Candidates by centre-of-mass distance plus the chord's depth toward the pads' tips, 5 cm
        per unit of approach away from straight down and 1 cm per degree of the closing line away
        from the surface normals."""
        misalign_deg = np.degrees(np.arccos(np.clip(self.alignment, -1.0, 1.0)))
        score = self.com_distance_m + self.depth_m + 0.05 * (1.0 + self.approach_up) + 0.01 * misalign_deg
        return np.argsort(score, kind="stable")


def _along_path(path: np.ndarray, count: int) -> np.ndarray:
    return path[np.unique(np.linspace(0, len(path) - 1, count).round().astype(int))]


def _antipodal_pairs(
    object_vertices: np.ndarray,
    object_faces: np.ndarray,
    *,
    friction: float,
    max_width_m: float,
    surface_points: int,
    max_pairs: int,
    rng: np.random.Generator,
) -> tuple[antipodal.Antipodal, int]:
    """Antipodal pairs on the mesh that fit the gripper, at most ``max_pairs`` of them, and how many were found."""
    points, normals = antipodal.sample_surface(object_vertices, object_faces, surface_points, rng)
    pairs = antipodal.antipodal_pairs(points, normals, friction=friction, max_width_m=max_width_m)
    if len(pairs) == 0:
        wide = antipodal.antipodal_pairs(points, normals, friction=friction, max_width_m=10.0)
        if not len(wide):
            raise NoGrasp(
                f"no two of the {len(points)} points sampled on the object's surface face each other within"
                f" the friction cone (friction {friction:g}): nothing for two fingers to squeeze"
            )
        raise NoGrasp(
            f"the object is too large for the gripper: its narrowest antipodal grasp is"
            f" {100 * wide.width.min():.1f} cm, the Panda takes at most {100 * max_width_m:.1f} cm"
        )
    found = len(pairs)
    if len(pairs) > max_pairs:  # the best aligned, and a random share of the rest
        best = np.argsort(-pairs.alignment, kind="stable")[: max_pairs // 2]
        rest = np.setdiff1d(np.arange(len(pairs)), best)
        keep = np.concatenate([best, rng.choice(rest, max_pairs - len(best), replace=False)])
        pairs = antipodal.Antipodal(pairs.p1[keep], pairs.p2[keep], pairs.alignment[keep])
    return pairs, found


def _frames_from_above(
    pairs: antipodal.Antipodal, approach_turns: int, start_pose: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Tool frames (G, 4, 4) of the pairs whose approach is not from below at ``start_pose`` (4, 4),
    their pair indices (G,) and the approach's world z (G,); the first approach of each pair is
    the one nearest straight down."""
    frames, which = antipodal.grasp_frames(pairs, approach_turns, down=-start_pose[2, :3])
    world0 = np.einsum("ij,gjk->gik", start_pose, frames)
    approach_up = world0[:, 2, 2]
    frames, which, approach_up = frames[approach_up < 0.3], which[approach_up < 0.3], approach_up[approach_up < 0.3]
    if len(frames) == 0:
        raise NoGrasp("every antipodal grasp of the object must come from below the support")
    return frames, which, approach_up


def _gripper_hit(frames: np.ndarray, opening_m: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(G,) whether the hand or a finger, the pads ``opening_m`` (G,) apart, holds one of the
    points (P, 3) at each tool frame (G, 4, 4) [m]."""
    hit = antipodal.boxes_hit(frames, panda.HAND_BOX[0][None], panda.HAND_BOX[1][None], points)
    for side in (1.0, -1.0):
        at_pad = frames.copy()
        at_pad[:, :3, 3] += (side * opening_m / 2)[:, None] * frames[:, :3, 1]
        centre, half = panda.finger_box(side)
        hit |= antipodal.boxes_hit(at_pad, centre[None], half[None], points)
    return hit


def _collision_free(
    frames: np.ndarray,
    opening_m: np.ndarray,
    object_cloud: np.ndarray,
    scene_points: np.ndarray,
    path: np.ndarray,
    lift_m: float,
) -> np.ndarray:
    """(G,) whether the gripper, pre-shaped to ``opening_m`` (G,), at each tool frame (G, 4, 4)
    stays clear of the object's points and of the scene points [m] at the grasp, on the way in and
    along the lifted path (N, 4, 4)."""
    hit = _gripper_hit(frames, opening_m, object_cloud)
    # on the way in: the hand and fingers backed off along the approach
    for back in (0.03, 0.06, motion.PREGRASP_M):
        hit |= _gripper_hit(motion.backed_off(frames, back), opening_m, object_cloud)
    free = ~hit
    if len(scene_points):
        # the scene at the grasp and on the way in (world frame at frame 0), and along the path
        local_scene = se3.transform_points(se3.invert(path[0]), scene_points)
        for back in (0.0, 0.05, motion.PREGRASP_M):
            idx = np.flatnonzero(free)
            shifted = motion.backed_off(frames[idx], back)
            free[idx[_gripper_hit(shifted, opening_m[idx], local_scene)]] = False
        for pose in _along_path(motion.lifted(path, lift_m), 8)[1:]:
            idx = np.flatnonzero(free)
            if len(idx) == 0:
                break
            moved = np.einsum("ij,gjk->gik", pose, frames[idx])
            free[idx[_gripper_hit(moved, opening_m[idx], scene_points)]] = False
    return free


def _free_at_depths(
    frames: np.ndarray,
    object_cloud: np.ndarray,
    scene_points: np.ndarray,
    path: np.ndarray,
    *,
    max_width_m: float,
    clearance_m: float,
    lift_m: float,
) -> tuple[np.ndarray, ...]:
    """Each tool frame (G, 4, 4) moved back along its approach by the first of ``GRASP_DEPTHS_M``
    at which the object fits between the pads and the pre-shaped gripper is free: the indices of
    those free at some depth (K,), their moved frames (K, 4, 4), and the depth, the pads' width and
    their opening there (K,) [m].

    Raises:
        NoGrasp: the object is too wide across the pads at every frame.
    """
    index, moved, depths, widths, openings = [], [], [], [], []
    todo, narrowest = np.arange(len(frames)), np.inf
    for depth in GRASP_DEPTHS_M:
        shifted = motion.backed_off(frames[todo], depth)
        # flat pads open as wide as the object is across them, which may exceed the pair's chord
        width, far = antipodal.closing_extent(shifted, object_cloud, panda.PAD_HALF_X, panda.PAD_Z)
        narrowest = min(narrowest, float(width[width > 0].min(initial=np.inf)))
        # the pads open evenly about the tcp: past the object's farther side by the clearance
        opening = np.minimum(panda.MAX_OPENING_M, 2 * (far + clearance_m))
        free = (width > 0) & (width <= max_width_m)
        free[free] = _collision_free(shifted[free], opening[free], object_cloud, scene_points, path, lift_m)
        index.append(todo[free])
        moved.append(shifted[free])
        depths.append(np.full(int(free.sum()), depth))
        widths.append(width[free])
        openings.append(opening[free])
        todo = todo[~free]
        if not len(todo):
            break
    if np.isfinite(narrowest) and narrowest > max_width_m:
        raise NoGrasp(
            f"the object is too large for the gripper: across the finger pads it is at least "
            f"{100 * narrowest:.1f} cm wide, the Panda takes at most {100 * max_width_m:.1f} cm"
        )
    return tuple(np.concatenate(part) for part in (index, moved, depths, widths, openings))


def candidates(
    object_vertices: np.ndarray,
    object_faces: np.ndarray,
    center_of_mass: np.ndarray,
    path: np.ndarray,
    scene_points: np.ndarray,
    *,
    friction: float,
    max_width_m: float,
    clearance_m: float,
    surface_points: int,
    approach_turns: int,
    lift_m: float,
    rng: np.random.Generator,
    max_pairs: int = 150,
) -> Candidates:
    """Collision-free antipodal grasps of the object.

    Args:
        object_vertices, object_faces: the visual mesh in the object frame [m].
        center_of_mass: (3,) in the object frame [m].
        path: (N, 4, 4) the object's world poses; path[0] is where it is grasped.
        scene_points: (P, 3) points on the scene collider near the path [m].
        clearance_m: the pre-shaped pads open this much wider than the object on each side [m].

    Raises:
        NoGrasp: none fits the gripper or none is free of the scene and the object.
    """
    pairs, found = _antipodal_pairs(
        object_vertices,
        object_faces,
        friction=friction,
        max_width_m=max_width_m,
        surface_points=surface_points,
        max_pairs=max_pairs,
        rng=rng,
    )
    flat = antipodal.levelled(pairs, path[0][2, :3], friction)  # up in the object frame at the grasp
    pairs = antipodal.Antipodal(
        *(
            np.concatenate([a, b])
            for a, b in zip((pairs.p1, pairs.p2, pairs.alignment), (flat.p1, flat.p2, flat.alignment))
        )
    )
    frames, which, approach_up = _frames_from_above(pairs, approach_turns, path[0])
    object_cloud, _ = antipodal.sample_surface(object_vertices, object_faces, 1500, rng)
    free, frames, depth, width, opening = _free_at_depths(
        frames, object_cloud, scene_points, path, max_width_m=max_width_m, clearance_m=clearance_m, lift_m=lift_m
    )
    if not len(free):
        raise NoGrasp(f"all {found} antipodal grasps of the object would put the gripper into the scene or the object")
    which, approach_up = which[free], approach_up[free]
    return Candidates(
        object_from_tcp=frames,
        width_m=width,
        opening_m=opening,
        com_distance_m=np.linalg.norm(pairs.center[which] - np.asarray(center_of_mass, dtype=float), axis=1),
        depth_m=depth,
        approach_up=approach_up,
        alignment=pairs.alignment[which],
        sampled_pairs=found,
    )


def reach_cost(base_poses: np.ndarray, path: np.ndarray, object_from_tcp: np.ndarray, samples: int, seeds: int):
    """IK along the path for each grasp from each base, in one batch: (B, G) fraction of the
    sampled path poses reached and (B, G) worst position error [m]. The pre-grasp pose is one of
    the samples."""
    base_poses = np.asarray(base_poses, dtype=float).reshape(-1, 4, 4)
    poses = _along_path(path, samples)
    world = np.einsum("sij,gjk->gsik", poses, object_from_tcp)  # (G, S, 4, 4)
    pre = motion.backed_off(np.einsum("ij,gjk->gik", path[0], object_from_tcp), motion.PREGRASP_M)
    world = np.concatenate([world, pre[:, None]], axis=1)
    base_tcp = np.einsum("bij,gsjk->bgsik", se3.invert(base_poses), world)
    shape = base_tcp.shape[:3]
    _, pos_err, rot_err = ik.solve(base_tcp.reshape(-1, 4, 4), panda.HOME_Q, n_seeds=seeds, iterations=60)
    ok = ((pos_err < REACH_POS_M) & (rot_err < REACH_ROT_DEG)).reshape(shape)
    return ok.mean(axis=2), pos_err.reshape(shape).max(axis=2)


def base_candidates(path: np.ndarray, support_z: float, scene_points: np.ndarray) -> np.ndarray:
    """Base poses (B, 4, 4) on rings around the path's centre, facing it, on the support's
    height; candidates with scene above the support within 12 cm of the base are dropped."""
    centre = path[:, :2, 3].mean(axis=0)
    out = []
    for radius in (0.45, 0.55, 0.65):
        for angle in np.radians(np.arange(0, 360, 30)):
            xy = centre + radius * np.array([np.cos(angle), np.sin(angle)])
            if len(scene_points):
                near = np.linalg.norm(scene_points[:, :2] - xy, axis=1) < 0.12
                if np.any(scene_points[near, 2] > support_z + 0.01):
                    continue
            yaw = np.arctan2(*(centre - xy)[::-1])
            out.append(se3.make_pose(se3.rotation_about([0.0, 0.0, 1.0], yaw), [xy[0], xy[1], support_z]))
    return np.array(out)


def place_bases(path: np.ndarray, cands: Candidates, support_z: float, scene_points: np.ndarray) -> np.ndarray:
    """The base poses (B, 4, 4), best first: from the first the best few grasps reach most of the path."""
    bases = base_candidates(path, support_z, scene_points)
    if len(bases) == 0:
        raise NoGrasp("no place for the robot base: the scene stands above the support all around the path")
    top = cands.take(cands.prior_order()[:8])
    reached, worst = reach_cost(bases, path, top.object_from_tcp, samples=6, seeds=1)
    score = reached - 0.01 * worst  # (B, G)
    best = np.argmax(score, axis=1)
    rows = np.arange(len(bases))
    order = np.lexsort((worst[rows, best], -reached[rows, best]))
    return bases[order]


def chained_reach(
    base_pose: np.ndarray,
    path: np.ndarray,
    object_from_tcp: np.ndarray,
    lift_m: float,
    chunk: int = 8,
    clearance: Callable[[np.ndarray], np.ndarray] | None = None,
):
    """IK along the whole path as the arm would follow it, each chunk of poses seeded with the
    previous chunk's solution (one batch per chunk for all grasps): a wrist that runs into its
    limit half way through a turn fails here though every pose alone is reachable. Returns (G,)
    worst position error [m], (G,) worst rotation error [deg] and (G,) the arm's smallest
    ``clearance`` [m] (of joint coordinates (..., 9): ``planning.ArmChecker.clearance``) at every
    other pose of the path (inf without one): an arm whose forearm goes through the table as it
    sets the object down there reaches every pose, and the table stops it in the simulation."""
    g = len(object_from_tcp)
    base_inv = se3.invert(base_pose)
    pre = motion.backed_off(np.einsum("ij,gjk->gik", path[0], object_from_tcp), motion.PREGRASP_M)
    q, pos_err, rot_err = ik.solve(np.einsum("ij,gjk->gik", base_inv, pre), panda.HOME_Q, n_seeds=8, iterations=80)
    poses = np.einsum("nij,gjk->gnik", motion.lifted(path, lift_m), object_from_tcp)  # (G, N, 4, 4)
    poses = np.concatenate([np.einsum("ij,gjk->gik", path[0], object_from_tcp)[:, None], poses], axis=1)
    worst_pos, worst_rot, least = pos_err.copy(), rot_err.copy(), np.full(g, np.inf)
    for start in range(0, poses.shape[1], chunk):
        part = poses[:, start : start + chunk]
        n = part.shape[1]
        targets = np.einsum("ij,gnjk->gnik", base_inv, part).reshape(-1, 4, 4)
        q_all, p, r = ik.solve(targets, np.repeat(q, n, axis=0), iterations=40)
        worst_pos = np.maximum(worst_pos, p.reshape(g, n).max(axis=1))
        worst_rot = np.maximum(worst_rot, r.reshape(g, n).max(axis=1))
        q_all = q_all.reshape(g, n, -1)
        if clearance is not None and start > 0:  # the first chunk holds the grasp: fingertips on the support
            least = np.minimum(least, clearance(q_all[:, ::2]).min(axis=1))
        q = q_all[:, -1]
    return worst_pos, worst_rot, least


def rank(
    base_pose: np.ndarray,
    path: np.ndarray,
    cands: Candidates,
    count: int,
    lift_m: float,
    pool: int = 48,
    clearance: Callable[[np.ndarray], np.ndarray] | None = None,
) -> Candidates:
    """The ``count`` best grasps of those that reach every sampled pose of the path (independent IK
    with several seeds): first those that reach the whole path as the arm follows it (chained IK)
    with the arm clear of the scene (``clearance``, as for :func:`chained_reach`), then those that
    reach it, then the rest, each group in :meth:`Candidates.prior_order`. The chained IK runs on
    3 x ``count`` grasps at a time, in that order, until ``count`` are followed and clear."""
    top = cands.take(cands.prior_order()[:pool])
    reached, worst = reach_cost(base_pose, path, top.object_from_tcp, samples=10, seeds=4)
    reached, worst = reached[0], worst[0]
    order = np.lexsort((np.arange(len(top)), -reached))  # stable: prior order within equal reach
    if reached[order[0]] < 1.0:
        raise NoGrasp(
            f"the path is out of the robot's reach: the best grasp reaches {100 * reached[order[0]]:.0f} % "
            f"of it (worst IK error {100 * worst[order[0]]:.1f} cm)"
        )
    full = top.take(order[reached[order] >= 1.0])
    # chained IK in batches of 3 x count, in order, until count grasps are followed and clear
    followed, clear = np.zeros(len(full), bool), np.zeros(len(full), bool)
    for start in range(0, len(full), 3 * count):
        part = full.take(np.arange(start, min(start + 3 * count, len(full))))
        pos_err, rot_err, least = chained_reach(base_pose, path, part.object_from_tcp, lift_m, clearance=clearance)
        ok = (pos_err < REACH_POS_M) & (rot_err < REACH_ROT_DEG)
        followed[start : start + len(part)], clear[start : start + len(part)] = ok, ok & (least >= 0.0)
        if clear.sum() >= count:
            break
    checked = np.arange(start + len(part))
    return full.take(checked[np.lexsort((checked, ~followed[checked], ~clear[checked]))][:count])
