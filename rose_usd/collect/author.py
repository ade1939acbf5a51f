"""Authoring layers/robot.usda: the robot as one Xform per link with its collision geometry (so
usdview and ``rose-usd inspect`` show it), the best rollout's link poses and joint positions as
time samples at the video's time codes, and every rollout's verdict (``RoseCollectAPI``).

The link geometry has ``purpose = proxy``: it is the robot's collision geometry standing in for
its render meshes (the wheel's GLBs, not authored). usdview shows proxies by default; the gate's
re-render (default and render purposes) never draws the robot into the video it compares with.
The prims carry no physics schemas: the robot is a picture of a rollout, not a body Newton
would load from the stage.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numpy as np
from pxr import Gf, Sdf, Usd, UsdGeom, Vt

from rose_usd.collect.rollout import Rollout
from rose_usd.sim import panda
from rose_usd.stage_api import StageContext
from rose_usd.usd import paths, schema, tokens
from rose_usd.usd.geom import MeshData, author_mesh

ROBOT = "Panda"
LINK_COLOR = (0.85, 0.85, 0.82)
PAD_COLOR = (0.15, 0.15, 0.15)


@dataclass
class Outcome:
    """What the stage found, as it goes into the layer."""

    status: str
    message: str = ""
    object_name: str = ""
    base_pose: np.ndarray | None = None
    base_source: str = "reachability"
    rollouts: list[Rollout] = field(default_factory=list)
    best: int = -1
    dataset_info: str | None = None
    """Path of the dataset's meta/info.json relative to the layer folder, None when none."""


@functools.cache
def link_meshes() -> dict[str, MeshData]:
    """Each Panda link's collision geometry merged into one mesh in the link frame."""
    import trimesh

    parts: dict[str, list] = {}
    for geom in panda.chain().geometry:
        if geom.kind == "mesh":
            mesh = trimesh.load(geom.mesh_file, force="mesh")
        else:
            mesh = trimesh.creation.box(extents=geom.box_size_m)
        mesh.apply_transform(geom.link_from_geometry)
        parts.setdefault(geom.link, []).append(mesh)
    out = {}
    for link, meshes in parts.items():
        merged = trimesh.util.concatenate(meshes)
        color = PAD_COLOR if "finger" in link else LINK_COLOR
        out[link] = MeshData(np.asarray(merged.vertices), np.asarray(merged.faces), color=color)
    return out


def _matrix(pose: np.ndarray) -> Gf.Matrix4d:
    return Gf.Matrix4d(np.asarray(pose, dtype=float).T.tolist())


def author_robot(ctx: StageContext, outcome: Outcome) -> None:
    """Write /World/Robots/Panda: links, time samples of the best rollout, every rollout's verdict."""
    stage, n = ctx.stage, ctx.time_info.n_frames
    UsdGeom.Scope.Define(stage, paths.ROBOTS)
    robot = UsdGeom.Xform.Define(stage, paths.robot_path(ROBOT)).GetPrim()
    robot.ApplyAPI(schema.COLLECT_API)
    best = outcome.rollouts[outcome.best] if outcome.best >= 0 else None
    if outcome.base_pose is not None:
        chain = panda.chain()
        if best is not None and best.follow_start >= 0:
            ticks = best.ticks_of_frames(n)
            poses = best.links[ticks]  # (n, L, 4, 4) world
            joints = best.q[ticks]
        else:  # no rollout reached the path: the robot stands at home
            poses = np.einsum("ij,ljk->lik", outcome.base_pose, chain.forward(panda.HOME_Q))[None]
            joints = panda.HOME_Q[None]
        meshes = link_meshes()
        for li, link in enumerate(chain.links):
            if link not in meshes:
                continue
            xform = UsdGeom.Xform.Define(stage, paths.robot_link(ROBOT, link))
            op = xform.AddTransformOp()
            if len(poses) == 1:
                op.Set(_matrix(poses[0, li]))
            else:
                for t in range(n):
                    op.Set(_matrix(poses[t, li]), Usd.TimeCode(t))
            author_mesh(stage, paths.robot_link(ROBOT, link).AppendChild("Geometry"), meshes[link], purpose="proxy")
        attr = robot.GetAttribute(tokens.COLLECT_JOINT_POSITIONS)
        if len(joints) == 1:
            attr.Set(Vt.DoubleArray(joints[0].tolist()))
        else:
            for t in range(n):
                attr.Set(Vt.DoubleArray(joints[t].tolist()), Usd.TimeCode(t))
        robot.GetAttribute(tokens.COLLECT_BASE_POSE).Set(_matrix(outcome.base_pose))
        robot.GetAttribute(tokens.COLLECT_BASE_SOURCE).Set(outcome.base_source)
        robot.GetAttribute(tokens.COLLECT_JOINT_NAMES).Set(list(panda.JOINTS))
    rollouts = outcome.rollouts
    successes = sum(r.success for r in rollouts)
    robot.GetAttribute(tokens.COLLECT_STATUS).Set(outcome.status)
    robot.GetAttribute(tokens.COLLECT_MESSAGE).Set(outcome.message)
    robot.GetAttribute(tokens.COLLECT_OBJECT).Set(outcome.object_name)
    robot.GetAttribute(tokens.COLLECT_ROLLOUTS).Set(len(rollouts))
    robot.GetAttribute(tokens.COLLECT_SUCCESSES).Set(int(successes))
    robot.GetAttribute(tokens.COLLECT_SUCCESS_RATE).Set(float(successes / len(rollouts)) if rollouts else 0.0)
    robot.GetAttribute(tokens.COLLECT_BEST_ROLLOUT).Set(int(outcome.best))
    robot.GetAttribute(tokens.COLLECT_ROLLOUT_SUCCESS).Set([bool(r.success) for r in rollouts])
    robot.GetAttribute(tokens.COLLECT_ROLLOUT_REASON).Set([r.reason for r in rollouts])
    robot.GetAttribute(tokens.COLLECT_ROLLOUT_GRASP).Set([int(r.grasp) for r in rollouts])
    for token, values in (
        (tokens.COLLECT_MEAN_ERROR, [r.mean_error_m for r in rollouts]),
        (tokens.COLLECT_FINAL_ERROR, [r.final_error_m for r in rollouts]),
        (tokens.COLLECT_FINAL_ROTATION_ERROR, [r.final_error_deg for r in rollouts]),
        (tokens.COLLECT_DRIFT, [r.drift_m for r in rollouts]),
        (tokens.COLLECT_PENETRATION, [r.penetration_m for r in rollouts]),
    ):
        robot.GetAttribute(token).Set(Vt.FloatArray([float(v) for v in values]))
    if outcome.dataset_info is not None:
        robot.GetAttribute(tokens.COLLECT_DATASET).Set(Sdf.AssetPath(outcome.dataset_info))
