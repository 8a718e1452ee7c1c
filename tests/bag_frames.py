"""The tf check of a recorded bag: the test's own small tf buffer (rrg_models.robot_frames.compose
over /tf_static and the /tf of one stamp) against the project's forward kinematics."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from rosbags.highlevel import AnyReader
from scipy.spatial.transform import Rotation

from rrg_common.ros.msg_conversions import ARM_JOINT_NAMES
from rrg_models import wam
from rrg_models.hand import FINGERS, body_poses_at
from rrg_models.robot_frames import compose

JOINTS = "/rrg/joint_states"


def stamp_key(stamp) -> int:
    return stamp.sec * 1_000_000_000 + stamp.nanosec


def transform_matrix(t) -> np.ndarray:
    """A geometry_msgs/Transform as a (4,4) matrix."""
    T = np.eye(4)
    q = t.rotation
    T[:3, :3] = Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix()
    T[:3, 3] = t.translation.x, t.translation.y, t.translation.z
    return T


def check_frames(bag: Path, atol_m: float = 1e-6) -> tuple[int, int]:
    """Assert that the bag's /tf_static and the /tf of each recorded joint state (the same
    stamp), composed from ``world``, put the palm where rrg_models.wam.fk puts the hand and each
    fingertip where rrg_models.hand puts it at those joint angles (within ``atol_m``), and that the
    object's estimated and true frames are in /tf; returns (joint states checked, recorded)."""
    static, by_stamp, states = [], {}, []
    with AnyReader([bag]) as reader:
        conns = [c for c in reader.connections if c.topic in ("/tf", "/tf_static", JOINTS)]
        for conn, _, raw in reader.messages(connections=conns):
            msg = reader.deserialize(raw, conn.msgtype)
            if conn.topic == JOINTS:
                states.append(msg)
                continue
            for t in msg.transforms:
                entry = (t.header.frame_id, t.child_frame_id, transform_matrix(t.transform))
                if conn.topic == "/tf_static":
                    static.append(entry)
                else:
                    by_stamp.setdefault(stamp_key(t.header.stamp), {})[t.child_frame_id] = entry
    children = {child for frames in by_stamp.values() for child in frames}
    assert {"object_estimate", "object_true"} <= children, children
    checked = 0
    for msg in states:
        frames = by_stamp.get(stamp_key(msg.header.stamp), {})
        if "wam_link1" not in frames:
            continue
        poses = compose([*static, *frames.values()], "world")
        angles = dict(zip(msg.name, msg.position))
        palm = wam.fk([angles[n] for n in ARM_JOINT_NAMES])
        hand = body_poses_at(
            {n.removeprefix("bh_"): angles[n] for n in msg.name if n.startswith("bh_")}
        )
        np.testing.assert_allclose(poses["bh_palm"], palm, atol=atol_m)
        for i in FINGERS:
            np.testing.assert_allclose(
                poses[f"bh_f{i}_tip"][:3, 3], (palm @ hand[f"f{i}_tip"])[:3, 3], atol=atol_m
            )
        checked += 1
    return checked, len(states)
