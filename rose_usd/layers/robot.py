"""The robot layer (``/World/Robots/<Robot>``, ``RoseCollectAPI``): the collect stage's rollouts,
their verdicts and errors, and the best rollout's joint states per time code."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pxr import Usd

from rose_usd.usd import paths, schema, tokens


@dataclass(frozen=True)
class CollectResult:
    """What the collect stage found, for one robot."""

    robot: str
    status: str
    message: str
    object_name: str
    base_pose: np.ndarray
    """(4, 4) world pose of the robot base."""
    rollouts: int
    successes: int
    success_rate: float
    best_rollout: int
    rollout_success: list[bool]
    rollout_reason: list[str]
    mean_error_m: np.ndarray
    final_error_m: np.ndarray
    final_rotation_error_deg: np.ndarray
    drift_m: np.ndarray
    penetration_m: np.ndarray
    joint_names: list[str]
    dataset: str | None
    """Resolved path of the LeRobot dataset's meta/info.json, None when none was written."""

    @property
    def robomimic(self) -> str | None:
        """The same rollouts as a robomimic HDF5 file, written beside the LeRobot dataset."""
        return paths.robomimic_beside(self.dataset) if self.dataset else None

    def joint_positions(self, stage: Usd.Stage, n_frames: int) -> np.ndarray:
        """(n_frames, J) joint positions of the best rollout at time codes 0..n_frames-1 (empty when none)."""
        attr = stage.GetPrimAtPath(paths.robot_path(self.robot)).GetAttribute(tokens.COLLECT_JOINT_POSITIONS)
        if not attr.GetNumTimeSamples():
            return np.zeros((0, len(self.joint_names)))
        return np.array([np.asarray(attr.Get(Usd.TimeCode(t)), dtype=float) for t in range(n_frames)])

    def summary(self) -> str:
        if self.rollouts == 0:
            return f"collect {self.status}: {self.message}"
        best = ""
        if self.best_rollout >= 0:
            b = self.best_rollout
            best = (
                f"; best rollout {b}: path error {100 * self.mean_error_m[b]:.1f} cm mean, "
                f"{100 * self.final_error_m[b]:.1f} cm final, slip {100 * self.drift_m[b]:.1f} cm"
            )
        # "ok" only says that rollouts ran: the count says how they went
        head = "collect" if self.status == "ok" else f"collect {self.status}"
        return (
            f"{head}: {self.successes}/{self.rollouts} rollouts of {self.robot} moving "
            f"{self.object_name} succeeded ({100 * self.success_rate:.0f} %){best}"
        )


def robots(stage: Usd.Stage) -> list[str]:
    """Names of the robots under /World/Robots that carry collect results."""
    root = stage.GetPrimAtPath(paths.ROBOTS)
    if not root:
        return []
    return [c.GetName() for c in root.GetChildren() if c.HasAPI(schema.COLLECT_API)]


def read_collect(stage: Usd.Stage, robot: str | None = None) -> CollectResult | None:
    """The collect results of ``robot`` (default: the first), None when the stage has none."""
    names = robots(stage)
    if not names:
        return None
    robot = robot or names[0]
    prim = stage.GetPrimAtPath(paths.robot_path(robot))

    def get(token, default=None):
        attr = prim.GetAttribute(token)
        value = attr.Get() if attr and attr.HasAuthoredValue() else None
        return default if value is None else value

    def floats(token) -> np.ndarray:
        return np.asarray(list(get(token, [])), dtype=float)

    dataset = prim.GetAttribute(tokens.COLLECT_DATASET).Get()
    return CollectResult(
        robot=robot,
        status=str(get(tokens.COLLECT_STATUS, "")),
        message=str(get(tokens.COLLECT_MESSAGE, "")),
        object_name=str(get(tokens.COLLECT_OBJECT, "")),
        base_pose=np.asarray(get(tokens.COLLECT_BASE_POSE, np.eye(4)), dtype=float).T,
        rollouts=int(get(tokens.COLLECT_ROLLOUTS, 0)),
        successes=int(get(tokens.COLLECT_SUCCESSES, 0)),
        success_rate=float(get(tokens.COLLECT_SUCCESS_RATE, 0.0)),
        best_rollout=int(get(tokens.COLLECT_BEST_ROLLOUT, -1)),
        rollout_success=[bool(v) for v in get(tokens.COLLECT_ROLLOUT_SUCCESS, [])],
        rollout_reason=[str(v) for v in get(tokens.COLLECT_ROLLOUT_REASON, [])],
        mean_error_m=floats(tokens.COLLECT_MEAN_ERROR),
        final_error_m=floats(tokens.COLLECT_FINAL_ERROR),
        final_rotation_error_deg=floats(tokens.COLLECT_FINAL_ROTATION_ERROR),
        drift_m=floats(tokens.COLLECT_DRIFT),
        penetration_m=floats(tokens.COLLECT_PENETRATION),
        joint_names=[str(v) for v in get(tokens.COLLECT_JOINT_NAMES, [])],
        dataset=dataset.resolvedPath or None if dataset is not None and dataset.path else None,
    )
