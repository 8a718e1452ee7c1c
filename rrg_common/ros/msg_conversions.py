"""Conversions between RRG's model types and ROS messages (planar and 3-D poses, observations,
fingertip contacts). Plain functions, no node: the sim, executor and estimator nodes share them.
"""

from __future__ import annotations

import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import Point, Pose, Vector3
from scipy.spatial.transform import Rotation

from rrg_models.config import N_SENSORS
from rrg_models.observation import Observation
from rrg_msgs.msg import FingertipContact, PlanarPose
from rrg_msgs.msg import Observation as ObservationMsg

WORLD_FRAME = "world"
#: Joint names of the arm/hand interface (sim node and hardware bridge alike): the WAM's 7
#: joints, and the BarrettHand's spread (finger 1's spread joint; finger 2's mirrors it) and
#: proximal joints.
ARM_JOINT_NAMES = tuple(f"wam_j{i}" for i in range(1, 8))
SPREAD_JOINT_NAME = "bh_f1_spread"
PROXIMAL_JOINT_NAMES = tuple(f"bh_f{i}_prox" for i in (1, 2, 3))


def stamp_to_ns(stamp: Time) -> int:
    """A message stamp in nanoseconds."""
    return stamp.sec * 1_000_000_000 + stamp.nanosec


def ns_to_stamp(stamp_ns: int) -> Time:
    """The message stamp of ``stamp_ns`` nanoseconds."""
    sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
    return Time(sec=sec, nanosec=nanosec)


def planar_to_msg(w) -> PlanarPose:
    """(x [m], y [m], θ [rad]) → rrg_msgs/PlanarPose."""
    x, y, theta = (float(v) for v in np.asarray(w, dtype=float).reshape(3))
    return PlanarPose(x=x, y=y, theta=theta)


def planar_from_msg(msg: PlanarPose) -> np.ndarray:
    """rrg_msgs/PlanarPose → (3,) (x, y, θ)."""
    return np.array([msg.x, msg.y, msg.theta], dtype=float)


def pose_to_msg(T: np.ndarray) -> Pose:
    """(4,4) rigid transform → geometry_msgs/Pose."""
    T = np.asarray(T, dtype=float)
    x, y, z, w = Rotation.from_matrix(T[:3, :3]).as_quat()
    msg = Pose()
    msg.position.x, msg.position.y, msg.position.z = (float(v) for v in T[:3, 3])
    msg.orientation.x, msg.orientation.y, msg.orientation.z, msg.orientation.w = (
        float(x),
        float(y),
        float(z),
        float(w),
    )
    return msg


def pose_from_msg(msg: Pose) -> np.ndarray:
    """geometry_msgs/Pose → (4,4); raises ValueError for a zero or non-finite quaternion."""
    q = np.array([msg.orientation.x, msg.orientation.y, msg.orientation.z, msg.orientation.w])
    p = np.array([msg.position.x, msg.position.y, msg.position.z])
    if not (np.all(np.isfinite(q)) and np.all(np.isfinite(p)) and np.linalg.norm(q) > 0.0):
        raise ValueError(f"invalid pose: position {p}, quaternion {q}")
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat(q).as_matrix()
    T[:3, 3] = p
    return T


def point_to_msg(p) -> Point:
    x, y, z = (float(v) for v in p)
    return Point(x=x, y=y, z=z)


def vector_to_msg(v) -> Vector3:
    x, y, z = (float(c) for c in v)
    return Vector3(x=x, y=y, z=z)


def xyz(msg: Point | Vector3) -> np.ndarray:
    return np.array([msg.x, msg.y, msg.z], dtype=float)


def tip_contacts_to_msg(
    points: np.ndarray, normals: np.ndarray, wrenches: np.ndarray | None = None
) -> list[FingertipContact]:
    """Fingertip contacts of fingers 1-3: points and normals (3,3) in the hand frame (NaN rows:
    no contact), optional wrenches (3,6) [N, N m] in each sensor's frame."""
    out = []
    for i in range(3):
        c = FingertipContact(valid=bool(np.all(np.isfinite(points[i]))))
        if c.valid:
            c.point, c.normal = point_to_msg(points[i]), vector_to_msg(normals[i])
        if wrenches is not None:
            c.wrench.force, c.wrench.torque = (
                vector_to_msg(wrenches[i, :3]),
                vector_to_msg(wrenches[i, 3:]),
            )
        out.append(c)
    return out


def tip_contacts_from_msg(contacts: list[FingertipContact]) -> tuple[np.ndarray, np.ndarray]:
    """Fingertip contacts → points and normals (3,3) in the hand frame, NaN rows where not valid."""
    points, normals = np.full((3, 3), np.nan), np.full((3, 3), np.nan)
    for i, c in enumerate(contacts):
        if c.valid:
            points[i], normals[i] = xyz(c.point), xyz(c.normal)
    return points, normals


def observation_to_msg(
    obs: Observation, object_name: str, wrt_name: str, e, stamp: Time, frame_id: str = WORLD_FRAME
) -> ObservationMsg:
    """An Observation of WRT ``wrt_name`` executed at estimate e → rrg_msgs/Observation."""
    msg = ObservationMsg(
        object_name=object_name,
        wrt_name=wrt_name,
        estimate=planar_to_msg(e),
        contact=bool(obs.contact),
        progress=float(obs.progress),
        hand_pose=pose_to_msg(obs.hand_pose),
    )
    msg.header.stamp, msg.header.frame_id = stamp, frame_id
    msg.sensors = [bool(s) for s in obs.sensors]
    msg.closure = np.asarray(obs.closure, dtype=float)
    valid = np.all(np.isfinite(obs.tip_points), axis=1) & np.all(
        np.isfinite(obs.tip_normals), axis=1
    )
    msg.tip_valid = [bool(v) for v in valid]
    msg.tip_points = [point_to_msg(p) if v else Point() for p, v in zip(obs.tip_points, valid)]
    msg.tip_normals = [vector_to_msg(n) if v else Vector3() for n, v in zip(obs.tip_normals, valid)]
    msg.motion_dir = vector_to_msg(obs.motion_dir)
    msg.unconfirmed_stops = int(obs.unconfirmed_stops)
    msg.table_height = float(obs.table_height)
    return msg


def observation_from_msg(msg: ObservationMsg) -> Observation:
    """rrg_msgs/Observation → Observation (tip rows that are not valid become NaN); raises
    ValueError on a malformed message (wrong sensor count, non-finite progress or pose)."""
    if len(msg.sensors) != N_SENSORS:
        raise ValueError(f"observation needs {N_SENSORS} sensor flags, got {len(msg.sensors)}")
    if not np.isfinite(msg.progress):
        raise ValueError(f"observation progress is not finite: {msg.progress}")
    valid = np.asarray(msg.tip_valid, dtype=bool)
    points = np.where(valid[:, None], np.array([xyz(p) for p in msg.tip_points]), np.nan)
    normals = np.where(valid[:, None], np.array([xyz(n) for n in msg.tip_normals]), np.nan)
    return Observation(
        contact=bool(msg.contact),
        progress=float(msg.progress),
        hand_pose=pose_from_msg(msg.hand_pose),
        sensors=np.asarray(msg.sensors, dtype=bool),
        closure=np.asarray(msg.closure, dtype=float),
        tip_points=points,
        tip_normals=normals,
        motion_dir=xyz(msg.motion_dir),
        unconfirmed_stops=int(msg.unconfirmed_stops),
        table_height=float(msg.table_height),
    )
