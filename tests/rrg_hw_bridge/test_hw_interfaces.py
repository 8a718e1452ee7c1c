"""The interface packages the hardware bridge speaks (rrg_hw_bridge/interfaces/, built into the
venv by scripts/setup_ros.sh): control_msgs hashes and constants equal upstream's, and bhand_srvs
has Barrett's field layout."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest
from bhand_srvs.srv import FingerPosition, FingerVelocity, GraspPosition, SpreadPosition
from control_msgs.action import FollowJointTrajectory
from control_msgs.msg import JointComponentTolerance, JointTolerance
from rclpy.serialization import deserialize_message, serialize_message

SHARE = Path(sys.prefix) / "share" / "control_msgs"

#: RIHS01 type hashes of upstream control_msgs 5.8.0 (jazzy branch, commit f901df2): its own
#: FollowJointTrajectory.action, JointTolerance.msg and JointComponentTolerance.msg built with
#: this venv's rosidl (ROS 2 Jazzy wheels) and read from the generated type description JSON.
UPSTREAM_HASHES = {
    "control_msgs/action/FollowJointTrajectory": (
        "RIHS01_738ebcb7a2d7cfa42f9f1001cc99ce3a4383d1cfe508015d9be8485e4b1c66f6"
    ),
    "control_msgs/action/FollowJointTrajectory_Goal": (
        "RIHS01_8a9060704b269608f5a340934cc26e66869dd14bdac29e2e7fd9ec8b9882d205"
    ),
    "control_msgs/action/FollowJointTrajectory_Result": (
        "RIHS01_8002e99ed2c14c6faa522f2a93c26d744c5982f254f9e98ff9c6f19789bdb220"
    ),
    "control_msgs/action/FollowJointTrajectory_Feedback": (
        "RIHS01_3fd0aaecf71725121ae1ff7f01098a5e0da581e672be18a6b2c286cb43d96b49"
    ),
    "control_msgs/action/FollowJointTrajectory_FeedbackMessage": (
        "RIHS01_80398fcb9674a79081a9906e2ccf0c804dd7cb15e22e362e606ee87186beab71"
    ),
    "control_msgs/action/FollowJointTrajectory_SendGoal": (
        "RIHS01_b13789dddc325a7a962825c45e28c77d37237ec129dd0c34dc5994562938c57f"
    ),
    "control_msgs/action/FollowJointTrajectory_SendGoal_Request": (
        "RIHS01_179c93691f1f6d1d115881ff88c3917b7cc6eac2ba4bf56766cc7c4389e19ef1"
    ),
    "control_msgs/action/FollowJointTrajectory_SendGoal_Response": (
        "RIHS01_e6a48ba740ae254500129a877f0b071be8663a115da1a539b74599cc97921fbf"
    ),
    "control_msgs/action/FollowJointTrajectory_SendGoal_Event": (
        "RIHS01_906dd566308db02673c73c654f69bdd84738589629c1bc2841ddb49059ed1c6f"
    ),
    "control_msgs/action/FollowJointTrajectory_GetResult": (
        "RIHS01_e3ceb38e3e1867c8dc0f46014df26e90eb93422f27e9e97f936e07f94be4bc8b"
    ),
    "control_msgs/action/FollowJointTrajectory_GetResult_Request": (
        "RIHS01_ecf7ea8463d3beec7084bca75216d0b01b87b6e1e4e09679bb26093041efcbe9"
    ),
    "control_msgs/action/FollowJointTrajectory_GetResult_Response": (
        "RIHS01_08eefbaa146ce02ba45898d5e99160afd6c4c54a30d159aee0f2ca6035b1580f"
    ),
    "control_msgs/action/FollowJointTrajectory_GetResult_Event": (
        "RIHS01_43161a489e52daaa5bbc2fa74f73f1804d099574fcf8f819170807d75472662a"
    ),
    "control_msgs/msg/JointTolerance": (
        "RIHS01_c254f9cece0f3b733017b6990fd46d1326e25242d6b8844398c97d9a88e7d648"
    ),
    "control_msgs/msg/JointComponentTolerance": (
        "RIHS01_739ea7566931944d33830fa10f1bf5e7a7fbdc3172bce7a7eaac642bd6e3ffa4"
    ),
}


def _installed_hashes() -> dict[str, str]:
    """Every control_msgs type hash in the installed type descriptions (<venv>/share)."""
    hashes = {}
    for path in ("action/FollowJointTrajectory.json", "msg/JointTolerance.json"):
        for entry in json.loads((SHARE / path).read_text())["type_hashes"]:
            if entry["type_name"].startswith("control_msgs/"):
                hashes[entry["type_name"]] = entry["hash_string"]
    return hashes


def test_control_msgs_is_the_venv_build() -> None:
    """The imported control_msgs is the one installed into this venv, next to its type
    descriptions."""
    import control_msgs

    assert Path(control_msgs.__file__).resolve().is_relative_to(Path(sys.prefix).resolve())
    assert (SHARE / "action" / "FollowJointTrajectory.json").is_file()


@pytest.mark.parametrize("type_name", sorted(UPSTREAM_HASHES))
def test_type_hash_equals_upstream(type_name: str) -> None:
    """Each FollowJointTrajectory part and each tolerance message hashes as upstream 5.8.0's."""
    assert _installed_hashes()[type_name] == UPSTREAM_HASHES[type_name]


def test_no_other_control_msgs_types() -> None:
    """Only the subset RRG needs is built: no type beyond the hashed ones."""
    assert set(_installed_hashes()) == set(UPSTREAM_HASHES)


def test_result_codes() -> None:
    """The result codes a JointTrajectoryController returns."""
    result = FollowJointTrajectory.Result
    assert result.SUCCESSFUL == 0
    assert result.INVALID_GOAL == -1
    assert result.INVALID_JOINTS == -2
    assert result.OLD_HEADER_TIMESTAMP == -3
    assert result.PATH_TOLERANCE_VIOLATED == -4
    assert result.GOAL_TOLERANCE_VIOLATED == -5
    assert result.get_fields_and_field_types() == {"error_code": "int32", "error_string": "string"}


def test_component_constants() -> None:
    """JointComponentTolerance's component codes (constants are not part of the type hash)."""
    c = JointComponentTolerance
    assert (c.X_AXIS, c.Y_AXIS, c.Z_AXIS, c.TRANSLATION, c.ROTATION) == (1, 2, 3, 4, 5)


def test_goal_round_trips() -> None:
    """A goal with a trajectory and tolerances survives CDR serialization."""
    goal = FollowJointTrajectory.Goal()
    goal.trajectory.joint_names = ["wam_j1_joint", "wam_j2_joint"]
    goal.path_tolerance = [JointTolerance(name="wam_j1_joint", position=0.05, velocity=-1.0)]
    goal.goal_time_tolerance.sec = 2
    back = deserialize_message(serialize_message(goal), FollowJointTrajectory.Goal)
    assert back == goal
    assert back.path_tolerance[0].position == 0.05


@pytest.mark.parametrize(
    ("srv", "request_fields"),
    [
        (FingerPosition, {"position": "sequence<float>"}),
        (FingerVelocity, {"velocity": "sequence<float>"}),
        (SpreadPosition, {"position": "double"}),
        (GraspPosition, {"position": "double"}),
    ],
    ids=["FingerPosition", "FingerVelocity", "SpreadPosition", "GraspPosition"],
)
def test_bhand_srvs_layout(srv: type, request_fields: dict[str, str]) -> None:
    """Barrett's layout: float32[] finger arrays or a float64, answered by a bool ``response``."""
    assert srv.Request.get_fields_and_field_types() == request_fields
    assert srv.Response.get_fields_and_field_types() == {"response": "boolean"}


@pytest.mark.parametrize("srv", [FingerPosition, FingerVelocity], ids=lambda s: s.__name__)
def test_finger_arrays_carry_three_fingers(srv: type) -> None:
    """The per-finger request carries fingers 1, 2, 3 in order through CDR (rad or rad/s)."""
    (field,) = srv.Request.get_fields_and_field_types()
    request = srv.Request(**{field: [0.25, 1.5, 2.0]})
    back = deserialize_message(serialize_message(request), srv.Request)
    assert list(getattr(back, field)) == [0.25, 1.5, 2.0]
