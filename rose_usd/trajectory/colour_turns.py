"""A textured object's print kept where the video shows it along the whole trajectory.

Silhouettes and depth cannot tell a cube's 24 orientations apart (``geometry.symmetry``): the
object stage picks frame 0's by colour, but a track can still come out of a turn a quarter turn
off, or jump to another of them when it is found again. Every ``stride``-th frame scores each
symmetry by how well the texture under it matches the frame inside the object's mask; a Viterbi
path through the symmetries then keeps frame 0's and pays for each change by the turn it adds to
the object's motion between two frames (``turn_cost`` per radian): where the track jumped a
quarter turn the path turns it back for free, and where it drifted it changes only on the
colours' evidence over several frames.
"""

from __future__ import annotations

import numpy as np

from rose_usd.core import se3
from rose_usd.geometry.symmetry import coloured_samples, shape_symmetries, symmetric_look, symmetry_scores
from rose_usd.io.images import read_rgb
from rose_usd.layers.objects import default_pose, visual_mesh


def symmetry_path(poses: np.ndarray, symmetries: np.ndarray, scores: np.ndarray, turn_cost: float) -> np.ndarray:
    """The symmetry (index into ``symmetries``) to apply to each of ``poses`` (N, 4, 4): identity at
    frame 0, then the path that maximizes the summed ``scores`` (N, K; 0 where a frame was not
    scored) less ``turn_cost`` times the angle [rad] each step adds between consecutive frames."""
    n, k = scores.shape
    turns = symmetries[:, :3, :3]
    cost = np.full(k, np.inf)
    cost[0] = -scores[0, 0]
    back = np.zeros((n, k), np.int64)
    for t in range(1, n):
        step = poses[t - 1, :3, :3].T @ poses[t, :3, :3]
        # angle between P_{t-1} S_a and P_t S_b: that of S_a^T step S_b
        rel = np.einsum("aji,jk,bkl->abil", turns, step, turns)
        cos = np.clip((np.trace(rel, axis1=2, axis2=3) - 1.0) / 2.0, -1.0, 1.0)
        total = cost[:, None] + turn_cost * np.arccos(cos)
        back[t] = np.argmin(total, axis=0)
        cost = total[back[t], np.arange(k)] - scores[t]
    path = np.zeros(n, np.int64)
    path[-1] = int(np.argmin(cost))
    for t in range(n - 1, 0, -1):
        path[t - 1] = back[t, path[t]]
    return path


def colour_consistent(
    stage, name: str, poses: np.ndarray, masks, cameras, rgb_of, *, stride: int = 3, turn_cost: float = 0.5
) -> tuple[np.ndarray, dict | None]:
    """Object ``name``'s ``poses`` (N, 4, 4), each turned by the shape symmetry that ``symmetry_path``
    picks from the colours of its visual mesh's texture in every ``stride``-th frame of ``rgb_of``
    inside its ``masks`` (list, None where it has none); with what was measured. Unchanged, with
    None, for an object without a texture or without symmetry."""
    mesh = visual_mesh(stage, name)
    if mesh.texture is None or mesh.uv is None or not mesh.texture.exists():
        return poses, None
    local = se3.transform_points(se3.invert(default_pose(stage, name)), mesh.vertices)
    symmetries = shape_symmetries(local, mesh.faces)
    if len(symmetries) < 2:
        return poses, None
    look = symmetric_look(coloured_samples(local, mesh.faces, uv=mesh.uv, image=read_rgb(mesh.texture)), symmetries)
    n = len(poses)
    scores = np.zeros((n, len(symmetries)))
    scored = []
    for t in range(0, n, stride):
        if masks[t] is None or not masks[t].any():
            continue
        s = symmetry_scores(look, poses[t], cameras.world_from_cv[t], cameras.K[t], rgb_of(t), masks[t])
        if s is not None:
            scores[t] = s
            scored.append(t)
    if not scored:
        return poses, None
    path = symmetry_path(poses, symmetries, scores, turn_cost)
    turned = np.einsum("nij,njk->nik", poses, symmetries[path])
    fact = {
        "symmetries": len(symmetries),
        "frames_scored": len(scored),
        "frames_turned": int(np.count_nonzero(path)),
        "score_as_tracked": round(float(scores[scored, 0].mean()), 3),
        "score_turned": round(float(scores[scored, path[scored]].mean()), 3),
    }
    return turned, fact
