"""The robot's tf2 frames (rrg_models.robot_frames, from the URDF and the joint states) against the
project's own kinematics, and the vendored tf2_msgs against upstream's type hash."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

from rrg_common.ros.msg_conversions import ARM_JOINT_NAMES, PROXIMAL_JOINT_NAMES, SPREAD_JOINT_NAME
from rrg_models import wam
from rrg_models.description.urdf_robot import PALM_LINK, robot_urdf, ros_name
from rrg_models.hand import FINGERS, body_poses, joint_angles
from rrg_models.robot_frames import RobotFrames, compose, urdf_joints

#: RIHS01 type hash of upstream tf2_msgs/msg/TFMessage (tf2_msgs 0.36.4, ros2/geometry2 jazzy
#: branch, commit 646342c): upstream's own package built with this venv's rosidl (ROS 2 Jazzy
#: wheels), read from its generated type description JSON.
UPSTREAM_TFMESSAGE_HASH = "RIHS01_e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087"


@pytest.fixture(scope="module")
def frames() -> RobotFrames:
    return RobotFrames(robot_urdf())


def test_the_frames_at_joint_states_are_the_models_poses(frames):
    """200 random joint states as the arm/hand interface publishes them (the arm, the spread
    and the proximal joints; no distal joints, which follow by their mimic): the palm is where
    rrg_models.wam.fk puts the hand and every hand link where rrg_models.hand puts it, to 1e-9."""
    rng = np.random.default_rng(39)
    names = [*ARM_JOINT_NAMES, SPREAD_JOINT_NAME, *PROXIMAL_JOINT_NAMES]
    for _ in range(200):
        q = rng.uniform(wam.LOWER, wam.UPPER)
        spread, proximal = rng.uniform(0.0, np.pi), rng.uniform(0.0, 2.44, 3)
        poses = compose(frames.static() + frames.moving(names, [*q, spread, *proximal]), "world")
        palm = wam.fk(q)
        np.testing.assert_allclose(poses[PALM_LINK], palm, atol=1e-9)
        for body, T in body_poses(spread, proximal).items():
            np.testing.assert_allclose(poses[ros_name(f"bh/{body}")], palm @ T, atol=1e-9)


def test_measured_distal_angles_win_over_their_mimic_and_gaps_are_left_out(frames):
    """A joint state that gives a distal joint's angle is used as it is; a joint whose angle is
    missing or NaN (a driver without that interface) is left out with its mimics."""
    names = [*ARM_JOINT_NAMES, SPREAD_JOINT_NAME, *PROXIMAL_JOINT_NAMES, "bh_f1_dist"]
    positions = [*wam.HOME_Q, 0.5, 1.0, 1.0, np.nan, 0.2]
    angles = frames.angles(names, positions)
    assert angles["bh_f1_dist"] == 0.2  # measured, not 1.0 × the coupling
    assert angles["bh_f2_dist"] == pytest.approx(joint_angles(0.5, np.ones(3))["f2_dist"])
    assert "bh_f3_prox" not in angles and "bh_f3_dist" not in angles
    children = {child for _, child, _ in frames.moving(names, positions)}
    assert "bh_f3_prox" not in children and "bh_f2_prox" in children
    assert {j.name for j in urdf_joints(robot_urdf()) if j.mimic} == {
        "bh_f2_spread",
        *(f"bh_f{i}_dist" for i in FINGERS),
    }


def test_tf2_msgs_is_upstreams():
    """The venv's tf2_msgs (built by scripts/setup_ros.sh from rrg_common/interfaces/tf2_msgs)
    hashes TFMessage as upstream jazzy does, and holds no other type."""
    from tf2_msgs.msg import TFMessage

    share = Path(sys.prefix) / "share" / "tf2_msgs"
    assert (
        Path(sys.modules[TFMessage.__module__].__file__)
        .resolve()
        .is_relative_to(Path(sys.prefix).resolve())
    )
    hashes = {
        e["type_name"]: e["hash_string"]
        for e in json.loads((share / "msg" / "TFMessage.json").read_text())["type_hashes"]
    }
    assert hashes["tf2_msgs/msg/TFMessage"] == UPSTREAM_TFMESSAGE_HASH
    assert sorted(p.name for p in (share / "msg").glob("*.msg")) == ["TFMessage.msg"]
