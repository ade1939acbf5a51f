"""The Franka Emika Panda with its parallel gripper, as the ``mani-skill`` 3.0.1 wheel describes it
(``mani_skill/assets/robots/panda/panda_v2.urdf`` and its collision meshes, Apache-2.0).

The files are not part of rose_usd: ``./dev.sh setup`` installs that wheel with ``--no-deps`` and
rose reads its files where pip put them, never importing the package (it needs torch). This
module finds them, parses the URDF's kinematic chain for a vectorized forward kinematics in numpy
(the planner and the grasp checks need thousands of poses), and holds the numbers the collect
stage drives the robot with.

Frames: ``base`` is ``panda_link0``; the tool frame ``tcp`` is ``panda_hand_tcp``, between the
two finger pads' centres, 0.1034 m beyond the hand along its z axis (the approach direction);
the fingers close along the hand's y axis.
"""

from __future__ import annotations

import functools
import importlib.metadata
import importlib.util
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from rose_usd.errors import EnvironmentProblem

WHEEL = "mani-skill==3.0.1"
"""The wheel the description comes from (installed with ``pip install --no-deps``)."""
URDF_IN_WHEEL = "mani_skill/assets/robots/panda/panda_v2.urdf"

ARM_JOINTS = tuple(f"panda_joint{i}" for i in range(1, 8))
FINGER_JOINTS = ("panda_finger_joint1", "panda_finger_joint2")
JOINTS = ARM_JOINTS + FINGER_JOINTS
"""Joint coordinates in Newton's order after ``add_urdf`` (depth first): 7 arm joints [rad], then
the two finger joints [m] (0 closed, 0.04 open; joint2 mimics joint1)."""
TCP_LINK = "panda_hand_tcp"
HAND_LINK = "panda_hand"
FINGER_LINKS = ("panda_leftfinger", "panda_rightfinger")

HOME_Q = np.array([0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785, 0.04, 0.04])
"""The ready pose: elbow up, hand pointing down, gripper open."""
FINGER_OPEN_M = 0.04
"""Finger joint at its upper limit: the pads' inner faces are 2 x 0.04 m apart."""
MAX_OPENING_M = 2 * FINGER_OPEN_M

# PD drives (Franka's own impedance defaults are of this order); URDF gains import as zero
ARM_KE = (4500.0, 4500.0, 3500.0, 3500.0, 2000.0, 2000.0, 2000.0)
ARM_KD = (450.0, 450.0, 350.0, 350.0, 200.0, 200.0, 200.0)
ARM_EFFORT_N_M = (87.0, 87.0, 87.0, 87.0, 12.0, 12.0, 12.0)
ARM_ARMATURE = (0.3, 0.3, 0.3, 0.3, 0.11, 0.11, 0.11)
ARM_MAX_VELOCITY_RAD_S = (2.175, 2.175, 2.175, 2.175, 2.61, 2.61, 2.61)
"""The URDF's joint velocity limits (not enforced by the simulation; a path that needs more is reported)."""
FINGER_KE = 2000.0
FINGER_KD = 50.0
FINGER_ARMATURE = 0.15

# The gripper as boxes in the tcp frame, for collision checks of grasp candidates: (centre, half
# extents) [m]. The hand body (from hand.stl's bounds, 0.1034 m behind the tcp) and one finger
# (its four URDF boxes' bounding box) on each side, placed for a given opening.
HAND_BOX = (np.array([0.0, 0.0, -0.0834]), np.array([0.032, 0.104, 0.046]))
FINGER_BOX_Y = (0.0, 0.026)
"""A finger's extent along the closing axis, measured outward from its pad's inner face [m]."""
FINGER_BOX_Z = (-0.045, 0.0095)
"""A finger's extent along the approach axis, from its base to the pad's tip, in the tcp frame [m]."""
FINGER_HALF_X = 0.011
PAD_HALF_X = 0.00875
"""Half the rubber pad's width across the closing axis [m] (its URDF box is 17.5 mm)."""
PAD_Z = (-0.00925, 0.00925)
"""The pad's extent along the approach axis in the tcp frame [m] (18.5 mm, centred on the tcp)."""


def finger_box(side: float) -> tuple[np.ndarray, np.ndarray]:
    """One finger as a box, centre (3,) and half extents (3,) [m], in a frame at its pad's inner
    face: the tcp frame moved ``side`` (+1 or -1) x half the opening along the closing axis (y)."""
    half_y = (FINGER_BOX_Y[1] - FINGER_BOX_Y[0]) / 2
    zc, hz = (FINGER_BOX_Z[0] + FINGER_BOX_Z[1]) / 2, (FINGER_BOX_Z[1] - FINGER_BOX_Z[0]) / 2
    return np.array([0.0, side * (FINGER_BOX_Y[0] + half_y), zc]), np.array([FINGER_HALF_X, half_y, hz])


# ----------------------------------------------------------------------------- the files
def panda_urdf() -> Path:
    """The Panda's URDF inside the installed mani-skill wheel.

    Raises:
        EnvironmentProblem: the wheel is not installed (one line naming the fix).
    """
    return _urdf_path()


@functools.cache
def _urdf_path() -> Path:
    # find_spec on a top-level package locates it without running its __init__
    spec = importlib.util.find_spec("mani_skill")
    roots = [Path(p) for p in (spec.submodule_search_locations or [])] if spec is not None else []
    try:
        dist = importlib.metadata.distribution("mani-skill")
        roots.append(Path(str(dist.locate_file("mani_skill"))))
    except importlib.metadata.PackageNotFoundError:
        pass
    for root in roots:
        path = root.parent / URDF_IN_WHEEL
        if path.is_file():
            return path
    raise EnvironmentProblem(
        "the Franka Panda's description (mani-skill's panda_v2.urdf) is not installed",
        hint=f'install it: pip install --no-deps "{WHEEL}" (./dev.sh setup does)',
    )


# ----------------------------------------------------------------------------- kinematics
def _origin(element: ET.Element | None) -> np.ndarray:
    """The 4x4 transform of a URDF ``<origin xyz rpy>`` (identity when absent)."""
    pose = np.eye(4)
    if element is None:
        return pose
    xyz = [float(v) for v in element.get("xyz", "0 0 0").split()]
    rpy = [float(v) for v in element.get("rpy", "0 0 0").split()]
    pose[:3, :3] = Rotation.from_euler("xyz", rpy).as_matrix()  # URDF: fixed axes roll, pitch, yaw
    pose[:3, 3] = xyz
    return pose


@dataclass(frozen=True)
class LinkGeometry:
    """One collision element of a link: a mesh file or a box, placed in the link frame."""

    link: str
    kind: str
    """``mesh`` or ``box``."""
    link_from_geometry: np.ndarray
    """(4, 4)."""
    mesh_file: Path | None = None
    box_size_m: np.ndarray | None = None
    """Full extents (3,) of a box [m]."""


@dataclass(frozen=True)
class Chain:
    """The Panda's links from ``panda_link0`` out, each with its parent, the fixed transform from
    the parent and the joint (coordinate index into :data:`JOINTS`, axis, type) that moves it."""

    links: tuple[str, ...]
    parent: tuple[int, ...]
    """Index of each link's parent link (-1 for the base)."""
    parent_from_joint: np.ndarray
    """(L, 4, 4)."""
    joint_index: tuple[int, ...]
    """Index into :data:`JOINTS` of the joint moving each link, -1 for fixed ones."""
    axis: np.ndarray
    """(L, 3) joint axes in the joint frame."""
    prismatic: tuple[bool, ...]
    geometry: tuple[LinkGeometry, ...]
    lower: np.ndarray
    """(9,) joint lower limits."""
    upper: np.ndarray
    """(9,) joint upper limits."""

    def index(self, link: str) -> int:
        return self.links.index(link)

    def forward(self, q: np.ndarray) -> np.ndarray:
        """Base-frame poses of every link, (..., L, 4, 4), for joint coordinates q (..., 9)."""
        q = np.asarray(q, dtype=float)
        batch = q.shape[:-1]
        out = np.zeros(batch + (len(self.links), 4, 4))
        for i, parent in enumerate(self.parent):
            local = np.broadcast_to(self.parent_from_joint[i], batch + (4, 4)).copy()
            j = self.joint_index[i]
            if j >= 0:
                motion = np.broadcast_to(np.eye(4), batch + (4, 4)).copy()
                if self.prismatic[i]:
                    motion[..., :3, 3] = q[..., j, None] * self.axis[i]
                else:
                    motion[..., :3, :3] = (
                        Rotation.from_rotvec((q[..., j, None] * self.axis[i]).reshape(-1, 3))
                        .as_matrix()
                        .reshape(batch + (3, 3))
                    )
                local = local @ motion
            out[..., i, :, :] = local if parent < 0 else out[..., parent, :, :] @ local
        return out

    def tcp(self, q: np.ndarray) -> np.ndarray:
        """Base-frame tcp poses (..., 4, 4) for joint coordinates q (..., 9)."""
        return self.forward(q)[..., self.index(TCP_LINK), :, :]


@functools.cache
def chain() -> Chain:
    """The Panda's kinematic chain and collision geometry, read from the URDF."""
    path = panda_urdf()
    root = ET.parse(path).getroot()
    joints = root.findall("joint")
    child_of = {j.find("child").get("link"): j for j in joints}
    order: list[str] = []

    def visit(link: str) -> None:
        order.append(link)
        for j in joints:
            if j.find("parent").get("link") == link:
                visit(j.find("child").get("link"))

    visit("panda_link0")
    parent, transforms, joint_index, axes, prismatic = [], [], [], [], []
    lower, upper = np.zeros(len(JOINTS)), np.zeros(len(JOINTS))
    for link in order:
        j = child_of.get(link)
        if j is None:
            parent.append(-1)
            transforms.append(np.eye(4))
            joint_index.append(-1)
            axes.append(np.zeros(3))
            prismatic.append(False)
            continue
        parent.append(order.index(j.find("parent").get("link")))
        transforms.append(_origin(j.find("origin")))
        name, kind = j.get("name"), j.get("type")
        moving = kind in ("revolute", "prismatic") and name in JOINTS
        joint_index.append(JOINTS.index(name) if moving else -1)
        axis = j.find("axis")
        axes.append(np.array([float(v) for v in axis.get("xyz").split()]) if axis is not None else np.zeros(3))
        prismatic.append(kind == "prismatic")
        if moving:
            limit = j.find("limit")
            lower[JOINTS.index(name)] = float(limit.get("lower"))
            upper[JOINTS.index(name)] = float(limit.get("upper"))
    geometry = []
    for link_el in root.findall("link"):
        for col in link_el.findall("collision"):
            geom = col.find("geometry")
            place = _origin(col.find("origin"))
            mesh, box = geom.find("mesh"), geom.find("box")
            if mesh is not None:
                file = path.parent / mesh.get("filename")
                geometry.append(LinkGeometry(link_el.get("name"), "mesh", place, mesh_file=file))
            elif box is not None:
                size = np.array([float(v) for v in box.get("size").split()])
                geometry.append(LinkGeometry(link_el.get("name"), "box", place, box_size_m=size))
    return Chain(
        links=tuple(order),
        parent=tuple(parent),
        parent_from_joint=np.stack(transforms),
        joint_index=tuple(joint_index),
        axis=np.stack(axes),
        prismatic=tuple(prismatic),
        geometry=tuple(geometry),
        lower=lower,
        upper=upper,
    )
