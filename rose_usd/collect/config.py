from __future__ import annotations

import enum
from dataclasses import dataclass, field

from rose_usd.stage_config import limits


class CollectBackend(enum.Enum):
    AUTO = "auto"  # chosen from what the case holds (rose_usd.plan)
    NEWTON = "newton"  # Newton's SolverMuJoCo (MuJoCo's C backend on CPU), one world per rollout


def parse_base(value) -> tuple[float, ...]:
    """``"x,y"`` or ``"x,y,yaw_deg"`` (or a list of 2 or 3 numbers) as a tuple; ``""`` or ``[]``
    for a base placed by reachability."""
    if isinstance(value, str):
        value = [v for v in value.replace(" ", "").split(",") if v]
    numbers = tuple(float(v) for v in value)
    if len(numbers) not in (0, 2, 3) or not all(abs(v) < 1e6 for v in numbers):
        raise ValueError("write x,y or x,y,yaw_deg (metres and degrees in the world frame)")
    return numbers


class SimDevice(enum.Enum):
    AUTO = "auto"  # a CUDA GPU when Warp sees one, else the CPU
    CPU = "cpu"  # MuJoCo's C backend, one world, rollouts one after another
    CUDA = "cuda"  # mujoco_warp on the GPU: every rollout its own world, stepped together


@dataclass(frozen=True, kw_only=True)
class NewtonConfig:
    """Settings of the newton backend (SolverMuJoCo)."""

    dt_s: float = 0.002
    """Simulation time step [s] (default 0.002)."""
    iterations: int = 20
    """MuJoCo Newton-solver iterations per step (default 20)."""
    grip_force_n: float = 40.0
    """Force limit of each finger's drive: the gripper closes on a target of 0 and squeezes with
    at most this force [N] (default 40; the Franka hand's continuous force is 70)."""
    pad_friction: float = 1.0
    """Friction coefficient of the rubber finger pads [-] (default 1). MuJoCo combines two geoms'
    friction by their maximum, so pad-object contacts use this and object-scene ones the object's prior."""
    contact_timeconst_s: float = 0.004
    """MuJoCo solref time constant of the pad-object contacts [s] (default 0.004; MuJoCo's 0.02
    lets a held object slip 3-5x more)."""
    condim: int = 6
    """MuJoCo contact dimension of pads and object: 6 adds torsional and rolling friction (default 6)."""
    device: SimDevice = SimDevice.AUTO
    """Where rollouts run: ``cuda`` steps them all at once as separate worlds, ``cpu`` one after
    another (default auto: cuda when Warp sees a GPU)."""
    max_worlds: int = field(default=4096, metadata=limits(1))
    """cuda: most worlds stepped at once; more rollouts run in batches of this many (default 4096)."""
    contacts_per_world: int = field(default=384, metadata=limits(16))
    """cuda: contact slots per world (mujoco_warp drops contacts beyond them; a mug of 250 convex
    parts on a table lists about 390 pairs within the 1 cm gap) (default 384)."""
    crop_margin_m: float = 0.3
    """The scene collider is cut to the box around the object's path and the robot base grown by
    this much before its convex decomposition [m] (default 0.3)."""
    coacd_threshold: float = 0.03
    """CoACD concavity threshold of the scene collider's decomposition [-] (default 0.03)."""


@dataclass(frozen=True, kw_only=True)
class CollectConfig:
    backend: CollectBackend = CollectBackend.AUTO
    """Which simulator collects the demonstrations (default auto)."""
    after_failed_gate: bool = False
    """Collect also from a reconstruction the gate failed (default false: the robot layer says the
    gate failed, and no rollout runs and no dataset is written)."""
    object_name: str = ""
    """The object the robot moves (default "": the object whose path is longest)."""
    grasps: int = 3
    """Grasp candidates rolled out, best ranked first (default 3)."""
    perturbations: int = 2
    """Rollouts per grasp: the first as reconstructed, the others with the object's pose, mass
    and friction perturbed (default 2)."""
    seed: int = field(default=0, metadata=limits(0))
    """Seed of the grasp sampling and the perturbations (default 0)."""
    base: tuple[float, ...] = field(default=(), metadata={"parse": parse_base})
    """Robot base "x,y" or "x,y,yaw_deg" in the world [m, deg], on the support's height
    (default "": placed where the whole path is best reachable)."""
    base_tries: int = 2
    """Bases tried, best reachability first, while every rollout from the ones before failed (a
    base placed by reachability only; default 2)."""
    lift_m: float = field(default=0.01, metadata=limits(0.0))
    """The object is carried this far above its reconstructed path, clear of the support [m] (default 0.01)."""
    max_width_m: float = 0.076
    """Widest grasp: the Panda opens 0.08 m, less a clearance (default 0.076)."""
    grasp_clearance_m: float = field(default=0.015, metadata=limits(0.005, 0.04))
    """Before they close, the fingers open evenly about the grasp this far past the object's
    farther side (their pre-shape), at most to the Panda's 0.08 m [m] (default 0.015, at least
    0.005: the pose perturbation's size)."""
    grasp_friction: float = 0.5
    """Friction coefficient of the antipodal test (the cone's half angle is its arctangent) [-] (default 0.5)."""
    surface_points: int = 400
    """Points sampled on the object's visual mesh for antipodal pairs (default 400)."""
    approach_turns: int = 12
    """Approach directions tried about each pair's closing axis (default 12)."""
    pose_noise_m: float = field(default=0.005, metadata=limits(0.0))
    """Largest perturbation of the object's position [m] (default 0.005)."""
    pose_noise_deg: float = field(default=5.0, metadata=limits(0.0))
    """Largest perturbation of the object's yaw [deg] (default 5)."""
    approach_s: float = 1.5
    """Time from the home pose to the pre-grasp pose [s], longer where a route around the scene
    needs it (default 1.5)."""
    approach_clearance_m: float = field(default=0.005, metadata=limits(0.0, 0.1))
    """Clearance [m] the arm keeps from the scene and the objects from home to the pre-grasp: the
    straight joint-space line where it keeps that, else a route OMPL's RRTConnect finds (default 0.005)."""
    max_drift_m: float = 0.02
    """Success: the object's pose in the hand moves less than this from the grasp [m] (default 0.02)."""
    max_drift_deg: float = 10.0
    """Success: ... and turns less than this [deg] (default 10)."""
    max_mean_error_m: float = 0.03
    """Success: mean distance of the object from its reconstructed path [m] (default 0.03)."""
    max_final_error_m: float = 0.03
    """Success: distance from the path's last pose at its end [m] (default 0.03)."""
    max_final_error_deg: float = 15.0
    """Success: rotation from the path's last pose at its end [deg] (default 15)."""
    max_penetration_m: float = 0.01
    """Success: deepest penetration of the robot or the object into the scene [m] (default 0.01)."""
    task: str = ""
    """Task text of the dataset (default "": "move the <object> along its demonstrated path")."""
    render: bool = False
    """Also render camera video of every successful rollout from the reconstructed camera into the
    LeRobot dataset, with Mitsuba (default false: about 16 frames a second at 320 x 240 on two CPU
    cores, benchmarks/results/collect-render)."""
    render_scale: float = field(default=0.5, metadata=limits(maximum=2.0))
    """Size of the rendered video relative to the input video's (default 0.5)."""
    render_spp: int = 4
    """Samples per pixel of the rendered video (default 4)."""
    newton: NewtonConfig = field(default_factory=NewtonConfig)
