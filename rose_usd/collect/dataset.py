"""The successful rollouts as training data in ``<out>/dataset/``: a LeRobot v3.0 dataset
(``lerobot/``) and robomimic-style HDF5 (``robomimic.hdf5``), one frame per control tick (the
video's frame rate), every tick of a rollout from the home pose to the retreat. With
``collect.render`` the LeRobot dataset has a camera stream too (``collect.video``).

Poses are in the robot base frame, position [m] then quaternion scalar first (w, x, y, z).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from rose_usd.collect import batch
from rose_usd.collect.config import CollectConfig
from rose_usd.collect.rollout import Rollout
from rose_usd.collect.video import RolloutCamera
from rose_usd.core import se3
from rose_usd.io import lerobot, robomimic
from rose_usd.progress import progress
from rose_usd.sim import panda
from rose_usd.stage_api import StageContext
from rose_usd.usd import paths

POSE_NAMES = ("x", "y", "z", "qw", "qx", "qy", "qz")
FEATURES = {
    "observation.state": lerobot.Feature("float32", panda.JOINTS),
    "observation.velocity": lerobot.Feature("float32", panda.JOINTS),
    "observation.ee_pose": lerobot.Feature("float32", POSE_NAMES),
    "observation.environment_state": lerobot.Feature("float32", tuple(f"object.{n}" for n in POSE_NAMES)),
    "action": lerobot.Feature("float32", panda.JOINTS),
    "action.ee_pose": lerobot.Feature("float32", POSE_NAMES + ("gripper_width",)),
}
"""observation.state: joint positions [rad, m]; .velocity: joint velocities; .ee_pose: the tool
frame; .environment_state: the object's pose; action: joint position targets; action.ee_pose:
the tool pose those targets reach (forward kinematics) and the gripper's target opening [m]."""
CAMERA = "observation.images.camera"
"""The camera stream (``collect.render``): the rollout seen from the reconstructed camera."""


def pose7(poses: np.ndarray) -> np.ndarray:
    """(T, 4, 4) -> (T, 7): position, then quaternion w, x, y, z."""
    return np.concatenate([poses[:, :3, 3], se3.quat_wxyz_from_matrix(poses[:, :3, :3])], axis=1)


def episode_arrays(rollout: Rollout, base_pose: np.ndarray) -> dict[str, np.ndarray]:
    """The rollout's per-tick features (T, n)."""
    base_inv = se3.invert(base_pose)
    in_base = lambda poses: np.einsum("ij,tjk->tik", base_inv, poses)  # noqa: E731
    commanded = panda.chain().tcp(rollout.action_q)
    gripper = rollout.action_q[:, 7:].sum(axis=1, keepdims=True)
    return {
        "observation.state": rollout.q,
        "observation.velocity": rollout.qd,
        "observation.ee_pose": pose7(in_base(rollout.tcp)),
        "observation.environment_state": pose7(in_base(rollout.object_pose)),
        "action": rollout.action_q,
        "action.ee_pose": np.concatenate([pose7(commanded), gripper], axis=1),
    }


def write_dataset(
    ctx: StageContext,
    rollouts: list[Rollout],
    object_name: str,
    path: np.ndarray,
    base_pose: np.ndarray,
    cfg: CollectConfig,
) -> str:
    """Write both formats; returns the LeRobot info.json's path relative to the layer folder."""
    folder = ctx.side_dir("dataset")
    task = cfg.task or f"move the {object_name.lower()} along its demonstrated path"
    fps = int(round(ctx.time_info.fps))
    videos, streams = {}, [{} for _ in rollouts]
    if cfg.render:
        camera = RolloutCamera(
            ctx.stage, object_name, ctx.time_info.n_frames, scale=cfg.render_scale, spp=cfg.render_spp
        )
        videos[CAMERA] = (camera.height, camera.width)
        for i, r in enumerate(rollouts):
            links = r.links if len(r.links) == r.frames else batch.link_poses(r, base_pose)
            streams[i][CAMERA] = progress(
                camera.frames(r, links), f"collect: video {i + 1}/{len(rollouts)}", total=r.frames
            )
    episodes = [lerobot.Episode(task, episode_arrays(r, base_pose), v) for r, v in zip(rollouts, streams, strict=True)]
    lerobot.write_dataset(folder / "lerobot", episodes, FEATURES, fps=fps, robot_type="panda", videos=videos)
    demos = []
    for r, ep in zip(rollouts, episodes, strict=True):
        n = r.frames
        rewards = np.zeros(n, np.float32)
        rewards[-1] = 1.0
        demos.append(
            robomimic.Demo(
                actions=ep.data["action"],
                obs={
                    "robot0_joint_pos": ep.data["observation.state"],
                    "robot0_joint_vel": ep.data["observation.velocity"],
                    "robot0_eef_pose": ep.data["observation.ee_pose"],
                    "object": ep.data["observation.environment_state"],
                },
                states=np.concatenate([r.q, r.qd, pose7(r.object_pose)], axis=1),
                rewards=rewards,
                dones=(np.arange(n) == n - 1).astype(np.uint8),
                attrs={
                    "grasp": int(r.grasp),
                    "mean_error_m": float(r.mean_error_m),
                    "follow_start": int(r.follow_start),
                    "object_mass_kg": float(r.perturbation.mass_kg),
                    "object_friction": float(r.perturbation.friction),
                },
            )
        )
    env_args = {
        "env_name": "rose_usd/grasp-and-follow",
        "type": "newton",
        "env_kwargs": {
            "stage": str(Path(ctx.out_dir).resolve() / "rose.usda"),
            "object": object_name,
            "robot": "panda",
            "base_pose": base_pose.tolist(),
            "control_freq": fps,
            "task": task,
            "obs_frame": "robot base; poses x y z qw qx qy qz",
            "states": "joint positions (9), joint velocities (9), object pose (7)",
        },
    }
    robomimic.write_hdf5(folder / paths.ROBOMIMIC_FILE, demos, env_args)
    return "../dataset/lerobot/meta/info.json"
