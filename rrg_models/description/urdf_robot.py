"""URDF of the robot: the same WAM and BarrettHand as ``mjcf_robot``, for ROS tools (RViz,
Foxglove, tf2, MoveIt) that read ``/robot_description``.

One model, two formats: the kinematics come from the very specs the MJCF is built from
(``config.WAM``'s DH table through ``mjcf_robot.dh_local``, ``wam.HAND_MOUNT`` and
``hand.hand_tree()``), written at full double precision; the masses and inertias are the ones
MuJoCo computes for the MJCF (``robot_xml()`` compiled: Barrett's link data, and the hand's
geoms at their densities), in each body's principal frame. Names follow ROS conventions:
the MJCF's ``wam/j1`` becomes joint ``wam_j1`` (the joint-state names of rrg_common.ros)
and body ``bh/palm`` becomes link ``bh_palm``; the root link is ``world``.

* Each MJCF body is a link; a hinge is a ``revolute`` joint with its limits, and the hand's
  coupled joints (finger 2's spread, the distal joints) carry ``<mimic>``.
* Collision and visual geometry are the MJCF's shapes. URDF has no capsule, so a capsule is
  written as a cylinder and two spheres.
* Joint effort and velocity limits: the WAM's servo torque limits and the joint speeds its
  paths are timed with (``PHYSICS.joint_speed``), the hand's stall torque and closing speeds
  (sources at each constant).

``python -m rrg_models.description.urdf_robot [FILE]`` writes it (stdout without FILE).
"""

from __future__ import annotations

import argparse
import sys
import warnings
import xml.etree.ElementTree as ET
from functools import cache

import mujoco
import numpy as np
from scipy.spatial.transform import Rotation

from rrg_models.config import HAND, PHYSICS, WAM, WAM_TORQUE_LIMIT
from rrg_models.description.mjcf import to_xml
from rrg_models.description.mjcf_robot import (
    ARM_JOINTS,
    ARM_RGBA,
    HAND_RGBA,
    _arm_geoms,
    base_geom,
    dh_local,
    robot_xml,
)
from rrg_models.hand import BodySpec, GeomSpec, hand_tree
from rrg_models.wam import HAND_MOUNT

ROOT_LINK = "world"
BASE_LINK = "wam_base"
PALM_LINK = "bh_palm"
#: The WAM's joint torque limits [N m]: libbarrett's position-PID control_signal_limit
#: (rrg_models.config.WAM_TORQUE_LIMIT, where its source is given).
WAM_JOINT_EFFORT = WAM_TORQUE_LIMIT
#: Significant digits of every number: full double precision, so the URDF's kinematics equal
#: the model's (rrg_models.wam) to round-off.
DIGITS = 17


def ros_name(mjcf_name: str) -> str:
    """The ROS name of an MJCF body or joint: ``wam/link1`` → ``wam_link1``."""
    return mjcf_name.replace("/", "_")


def _num(v) -> str:
    return " ".join(f"{x:.{DIGITS}g}" for x in np.atleast_1d(np.asarray(v, dtype=float)))


def _origin(parent: ET.Element, T: np.ndarray) -> None:
    """An ``<origin>`` of the (4,4) transform T (URDF's rpy: R = Rz(y) Ry(p) Rx(r))."""
    with warnings.catch_warnings():  # at gimbal lock scipy picks one of the equal answers
        warnings.simplefilter("ignore", UserWarning)
        rpy = Rotation.from_matrix(T[:3, :3]).as_euler("xyz")
    ET.SubElement(parent, "origin", xyz=_num(T[:3, 3]), rpy=_num(rpy))


def _transform(pos, quat_wxyz=(1.0, 0.0, 0.0, 0.0)) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat(
        np.asarray(quat_wxyz, dtype=float), scalar_first=True
    ).as_matrix()
    T[:3, 3] = pos
    return T


def _shapes(kind: str, size, T: np.ndarray) -> list[tuple[str, dict, np.ndarray]]:
    """URDF (geometry tag, attributes, origin) of one MJCF shape at T in its body: MJCF sizes
    are half extents; a capsule becomes a cylinder and two spheres."""
    size = [float(s) for s in size]
    if kind == "box":
        return [("box", {"size": _num(2.0 * np.asarray(size))}, T)]
    if kind == "sphere":
        return [("sphere", {"radius": _num(size[0])}, T)]
    if kind == "cylinder":
        return [("cylinder", {"radius": _num(size[0]), "length": _num(2.0 * size[1])}, T)]
    if kind == "capsule":
        r, half = size
        ends = [T @ _transform((0.0, 0.0, s * half)) for s in (-1.0, 1.0)]
        return [("cylinder", {"radius": _num(r), "length": _num(2.0 * half)}, T)] + [
            ("sphere", {"radius": _num(r)}, E) for E in ends
        ]
    raise ValueError(f"no URDF shape for an MJCF {kind!r}")


def _fromto_transform(fromto) -> tuple[np.ndarray, float]:
    """Pose (4,4) of a capsule given by its end points (6,) [m] (z along it), and its half
    length [m]."""
    a, b = np.asarray(fromto[:3], dtype=float), np.asarray(fromto[3:], dtype=float)
    axis = b - a
    half = float(np.linalg.norm(axis)) / 2.0
    R, _ = Rotation.align_vectors([axis / (2.0 * half)], [[0.0, 0.0, 1.0]])
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R.as_matrix(), (a + b) / 2.0
    return T, half


def _geometry(link: ET.Element, shapes: list[tuple[str, dict, np.ndarray]], rgba: str) -> None:
    for tag in ("visual", "collision"):
        for kind, attrs, T in shapes:
            el = ET.SubElement(link, tag)
            _origin(el, T)
            ET.SubElement(ET.SubElement(el, "geometry"), kind, attrs)
            if tag == "visual":
                material = ET.SubElement(el, "material", name=f"rgba {rgba}")
                ET.SubElement(material, "color", rgba=rgba)


def _arm_shapes(geoms: list[dict]) -> list[tuple[str, dict, np.ndarray]]:
    """URDF shapes of the arm's MJCF geoms (mjcf_robot.base_geom, _arm_geoms)."""
    shapes = []
    for g in geoms:
        if "fromto" in g:
            T, half = _fromto_transform(g["fromto"])
            shapes += _shapes(g["type"], (g["size"][0], half), T)
        else:
            shapes += _shapes(g["type"], g["size"], _transform(g.get("pos", (0.0, 0.0, 0.0))))
    return shapes


def _hand_shapes(geoms: tuple[GeomSpec, ...]) -> list[tuple[str, dict, np.ndarray]]:
    return [s for g in geoms for s in _shapes(g.kind, g.size, _transform(g.pos, g.quat))]


@cache
def _compiled() -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_string(robot_xml())


def _inertial(link: ET.Element, mjcf_body: str) -> None:
    """The body's mass and inertia as MuJoCo compiled them, in the body's principal frame."""
    m = _compiled()
    b = m.body(mjcf_body)
    el = ET.SubElement(link, "inertial")
    _origin(el, _transform(b.ipos, b.iquat))
    ET.SubElement(el, "mass", value=_num(b.mass[0]))
    ixx, iyy, izz = b.inertia
    ET.SubElement(
        el, "inertia", ixx=_num(ixx), iyy=_num(iyy), izz=_num(izz), ixy="0", ixz="0", iyz="0"
    )


def _joint(
    robot: ET.Element,
    name: str,
    parent: str,
    child: str,
    T: np.ndarray,
    axis=None,
    limits: tuple[float, float, float, float] | None = None,
    mimic: tuple[str, float] | None = None,
) -> None:
    """A fixed joint, or a revolute one with axis (3,) and limits (lower, upper [rad],
    effort [N m], velocity [rad/s])."""
    j = ET.SubElement(robot, "joint", name=name, type="fixed" if axis is None else "revolute")
    _origin(j, T)
    ET.SubElement(j, "parent", link=parent)
    ET.SubElement(j, "child", link=child)
    if axis is not None:
        ET.SubElement(j, "axis", xyz=_num(axis))
        lower, upper, effort, velocity = limits
        ET.SubElement(
            j, "limit", lower=_num(lower), upper=_num(upper), effort=_num(effort),
            velocity=_num(velocity),
        )  # fmt: skip
    if mimic is not None:
        ET.SubElement(j, "mimic", joint=mimic[0], multiplier=_num(mimic[1]), offset="0")


def _arm(robot: ET.Element) -> str:
    """The WAM's links and joints under ``world``; returns link 7's name."""
    base = ET.SubElement(robot, "link", name=BASE_LINK)
    _inertial(base, "wam/base")
    _geometry(base, _arm_shapes([base_geom()]), ARM_RGBA)
    _joint(robot, "world_to_wam_base", ROOT_LINK, BASE_LINK, np.eye(4))
    parent, T = BASE_LINK, _transform((0.0, 0.0, WAM.base_height))
    for i in range(7):
        name = ros_name(f"wam/link{i + 1}")
        link = ET.SubElement(robot, "link", name=name)
        _inertial(link, f"wam/link{i + 1}")
        _geometry(link, _arm_shapes(_arm_geoms(i)), ARM_RGBA)
        limits = (WAM.lower[i], WAM.upper[i], WAM_JOINT_EFFORT[i], PHYSICS.joint_speed[i])
        _joint(robot, ros_name(ARM_JOINTS[i]), parent, name, T, (0.0, 0.0, 1.0), limits)
        parent, T = name, dh_local(i)
    return parent


def _hand_limits(b: BodySpec) -> tuple[float, float, float, float]:
    """Limits of a hand joint: its range, the stall torque [N m] and the joint's speed [rad/s]
    (the spread servo's, or the proximal closing speed, which the coupled distal joint
    follows at its coupling ratio)."""
    lower, upper = b.joint.range
    if "spread" in b.joint.name:
        return lower, upper, HAND.close_torque, PHYSICS.spread_speed
    ratio = b.joint.coupled_to[1] if b.joint.coupled_to else 1.0
    return lower, upper, HAND.close_torque, HAND.close_speed * abs(ratio)


def _hand(robot: ET.Element, flange: str) -> None:
    """The BarrettHand's links and joints on the WAM's flange."""
    for b in hand_tree():
        name = ros_name(f"bh/{b.name}")
        link = ET.SubElement(robot, "link", name=name)
        _inertial(link, f"bh/{b.name}")
        if b.geoms:
            _geometry(link, _hand_shapes(b.geoms), HAND_RGBA)
        parent = flange if b.parent is None else ros_name(f"bh/{b.parent}")
        T = HAND_MOUNT if b.parent is None else _transform(b.pos, b.quat)
        if b.joint is None:
            _joint(robot, f"{parent}_to_{name}", parent, name, T)
            continue
        joint = ros_name(f"bh/{b.joint.name}")
        mimic = None
        if b.joint.coupled_to is not None:
            mimic = (ros_name(f"bh/{b.joint.coupled_to[0]}"), b.joint.coupled_to[1])
        elif b.joint.name == "f2_spread":  # the MJCF's spread equality: f2 follows f1
            mimic = (ros_name("bh/f1_spread"), 1.0)
        _joint(robot, joint, parent, name, T, b.joint.axis, _hand_limits(b), mimic)


def robot_urdf() -> str:
    """The robot's URDF (a complete ``<robot>`` document), rooted at link ``world``."""
    robot = ET.Element("robot", name="wam_barretthand")
    ET.SubElement(robot, "link", name=ROOT_LINK)
    _hand(robot, _arm(robot))
    return to_xml(robot)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("file", nargs="?", help="write here (default: stdout)")
    args = ap.parse_args(argv)
    text = robot_urdf()
    if args.file:
        with open(args.file, "w") as f:
            f.write(text)
    else:
        sys.stdout.write(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
