"""The robot's frames from its URDF and its joint states, without ROS: what ROS's
robot_state_publisher computes, for tf2.

``RobotFrames(urdf)`` reads the joints of a URDF (rrg_models.description.urdf_robot): each joint's
parent and child link, its origin, and for a revolute joint its axis and the joint it mimics.
``static()`` gives the transforms of the fixed joints (for ``/tf_static``); ``moving(names,
positions)`` those of the revolute joints whose angle is known (for ``/tf``), each as
(parent link, child link, (4,4) child pose in the parent). A mimicking joint follows its driver
(angle = multiplier · driver + offset) unless the joint states give its own angle.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

#: (parent link, child link, (4,4) pose of the child in the parent)
Transform = tuple[str, str, np.ndarray]


@dataclass(frozen=True)
class UrdfJoint:
    """One URDF joint: origin (4,4) in the parent link; axis (3,) for a revolute joint, None
    for a fixed one; mimic (driver joint, multiplier, offset) or None."""

    name: str
    parent: str
    child: str
    origin: np.ndarray
    axis: np.ndarray | None = None
    mimic: tuple[str, float, float] | None = None


def _vector(text: str | None, default: Sequence[float]) -> np.ndarray:
    return np.array([float(v) for v in text.split()]) if text else np.asarray(default, float)


def urdf_joints(urdf: str) -> tuple[UrdfJoint, ...]:
    """The joints of a URDF document (only fixed and revolute joints: the robot has no other);
    ValueError for any other joint type."""
    joints = []
    for j in ET.fromstring(urdf).iter("joint"):
        kind = j.get("type")
        if kind not in ("fixed", "revolute"):
            raise ValueError(f"joint {j.get('name')!r}: type {kind!r} is not supported")
        origin = j.find("origin")
        T = np.eye(4)
        if origin is not None:
            rpy = _vector(origin.get("rpy"), (0.0, 0.0, 0.0))
            T[:3, :3] = Rotation.from_euler("xyz", rpy).as_matrix()
            T[:3, 3] = _vector(origin.get("xyz"), (0.0, 0.0, 0.0))
        axis, mimic = None, None
        if kind == "revolute":
            axis_el = j.find("axis")
            axis = _vector(None if axis_el is None else axis_el.get("xyz"), (1.0, 0.0, 0.0))
            m = j.find("mimic")
            if m is not None:
                mimic = (
                    m.get("joint"),
                    float(m.get("multiplier", 1.0)),
                    float(m.get("offset", 0.0)),
                )
        joints.append(
            UrdfJoint(
                j.get("name"), j.find("parent").get("link"), j.find("child").get("link"), T,
                axis, mimic,
            )
        )  # fmt: skip
    return tuple(joints)


class RobotFrames:
    """The link transforms of one URDF at given joint angles (see the module doc)."""

    def __init__(self, urdf: str):
        self.joints = urdf_joints(urdf)
        self._moving = [j for j in self.joints if j.axis is not None]

    def static(self) -> list[Transform]:
        """The fixed joints' transforms."""
        return [(j.parent, j.child, j.origin) for j in self.joints if j.axis is None]

    def angles(self, names: Sequence[str], positions: Sequence[float]) -> dict[str, float]:
        """Every revolute joint's angle [rad] that the joint states (names, positions) give, or
        that follows from them by a mimic; non-finite readings are left out."""
        known = {n: float(p) for n, p in zip(names, positions) if np.isfinite(p)}
        angles = {j.name: known[j.name] for j in self._moving if j.name in known}
        for j in self._moving:
            if j.name not in angles and j.mimic is not None and j.mimic[0] in known:
                driver, multiplier, offset = j.mimic
                angles[j.name] = multiplier * known[driver] + offset
        return angles

    def moving(self, names: Sequence[str], positions: Sequence[float]) -> list[Transform]:
        """The revolute joints' transforms at the joint states (names, positions) [rad]; a joint
        with no angle (not in the states, nor mimicking one that is) is left out."""
        angles = self.angles(names, positions)
        joints = [j for j in self._moving if j.name in angles]
        if not joints:
            return []
        R = np.zeros((len(joints), 4, 4))  # one batch: scipy's cost is per call
        R[:, :3, :3] = Rotation.from_rotvec(
            np.array([j.axis * angles[j.name] for j in joints])
        ).as_matrix()
        R[:, 3, 3] = 1.0
        return [(j.parent, j.child, j.origin @ Rj) for j, Rj in zip(joints, R)]


def compose(transforms: Sequence[Transform], root: str) -> dict[str, np.ndarray]:
    """Every link's pose (4,4) in ``root`` that the transforms reach from it."""
    children: dict[str, list[Transform]] = {}
    for t in transforms:
        children.setdefault(t[0], []).append(t)
    poses, stack = {root: np.eye(4)}, [root]
    while stack:
        parent = stack.pop()
        for _, child, T in children.get(parent, []):
            poses[child] = poses[parent] @ T
            stack.append(child)
    return poses
