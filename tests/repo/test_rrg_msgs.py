"""rrg_msgs: the generated Python types import from the venv, every message, service and action
part round-trips through CDR, and the interfaces keep the project's conventions."""

from __future__ import annotations

import importlib
import zlib

import numpy as np
import pytest
from rclpy.serialization import deserialize_message, serialize_message
from rosidl_parser.definition import (
    AbstractNestedType,
    AbstractSequence,
    AbstractString,
    Array,
    BasicType,
    NamespacedType,
)

import rrg_msgs.action as actions
import rrg_msgs.msg as msgs
import rrg_msgs.srv as srvs
from rrg_models.config import SENSOR_NAMES

MESSAGES = [
    "PlanarPose",
    "BeliefGridMetaData",
    "BeliefGrid",
    "ContactPads",
    "FingertipContact",
    "Observation",
    "WorldRelativeTrajectory",
    "NodeEvent",
]
SERVICES = ["SelectAction", "ResetBelief", "GetBelief", "ResetSim", "HandCommand"]
ACTIONS = ["GuardedMove", "ExecuteWrt", "RobustGrasp"]

MESSAGE_TYPES = (
    [getattr(msgs, n) for n in MESSAGES]
    + [getattr(getattr(srvs, n), part) for n in SERVICES for part in ("Request", "Response")]
    + [
        getattr(getattr(actions, n), part)
        for n in ACTIONS
        for part in ("Goal", "Result", "Feedback")
    ]
)
RESULT_TYPES = [getattr(srvs, n).Response for n in SERVICES] + [
    getattr(actions, n).Result for n in ACTIONS
]

_INT_RANGES = {
    "int8": (-128, 127),
    "uint8": (0, 255),
    "int16": (-(2**15), 2**15 - 1),
    "uint16": (0, 2**16 - 1),
    "int32": (-(2**31), 2**31 - 1),
    "uint32": (0, 2**32 - 1),
    "int64": (-(2**63), 2**63 - 1),
    "uint64": (0, 2**64 - 1),
}


def _value(t, rng: np.random.Generator):
    """A random, non-default value of a rosidl type (floats exactly representable in float32)."""
    if isinstance(t, Array):
        return [_value(t.value_type, rng) for _ in range(t.size)]
    if isinstance(t, AbstractSequence):
        return [_value(t.value_type, rng) for _ in range(int(rng.integers(1, 5)))]
    if isinstance(t, AbstractString):
        return f"s{int(rng.integers(1000))}"
    if isinstance(t, NamespacedType):
        return _filled(getattr(importlib.import_module(".".join(t.namespaces)), t.name), rng)
    assert isinstance(t, BasicType), t
    if t.typename == "boolean":
        return bool(rng.integers(2))
    if t.typename in ("float", "double"):
        return float(rng.integers(-4000, 4000)) / 8.0
    if t.typename == "octet":
        return bytes([int(rng.integers(256))])
    if t.typename == "char":
        return chr(int(rng.integers(32, 127)))
    lo, hi = _INT_RANGES[t.typename]
    return int(rng.integers(lo, hi, endpoint=True, dtype=np.uint64 if lo == 0 else np.int64))


def _filled(cls, rng: np.random.Generator):
    """An instance of a generated message class with every field set to a random value."""
    msg = cls()
    for name, slot_type in zip(cls.get_fields_and_field_types(), cls.SLOT_TYPES):
        setattr(msg, name, _value(slot_type, rng))
    return msg


def constants(cls) -> dict:
    """The constants of a generated message class (properties of its metaclass)."""
    return {
        name: getattr(cls, name) for name, v in vars(type(cls)).items() if isinstance(v, property)
    }


def nested_types(cls) -> set[str]:
    """Every nested message type name reachable from cls's fields."""
    found = set()
    for t in cls.SLOT_TYPES:
        while isinstance(t, AbstractNestedType):
            t = t.value_type
        if isinstance(t, NamespacedType):
            found.add("/".join(t.namespaced_name()))
            found |= nested_types(getattr(importlib.import_module(".".join(t.namespaces)), t.name))
    return found


@pytest.mark.parametrize("cls", MESSAGE_TYPES, ids=lambda c: c.__name__)
def test_every_type_round_trips_through_cdr(cls):
    rng = np.random.default_rng(zlib.crc32(cls.__name__.encode()))
    msg = _filled(cls, rng)
    back = deserialize_message(serialize_message(msg), cls)
    assert back == msg
    assert back != cls() or not cls.get_fields_and_field_types()


def test_observation_round_trip_keeps_arrays_and_nested_poses():
    obs = msgs.Observation(object_name="powerdrill", wrt_name="goal", contact=True, progress=0.137)
    obs.header.frame_id = "world"
    obs.header.stamp.sec, obs.header.stamp.nanosec = 12, 345
    obs.estimate = msgs.PlanarPose(x=0.62, y=-0.01, theta=0.3)
    sensors = np.zeros(msgs.Observation.NUM_SENSORS, dtype=bool)
    sensors[[msgs.Observation.SENSOR_PALM, msgs.Observation.SENSOR_TIP2]] = True
    obs.sensors = sensors.tolist()
    obs.closure = np.array([1.1, 0.4, 2.44])
    obs.tip_valid = [False, True, False]
    obs.tip_points[1].x, obs.tip_points[1].y, obs.tip_points[1].z = 0.01, 0.05, 0.16
    obs.motion_dir.z = -1.0
    back = deserialize_message(serialize_message(obs), msgs.Observation)
    assert back == obs
    assert back.sensors == sensors.tolist()
    np.testing.assert_array_equal(back.closure, [1.1, 0.4, 2.44])
    assert (back.tip_points[1].y, back.header.frame_id, back.estimate.theta) == (0.05, "world", 0.3)


def test_belief_grid_carries_a_full_grid_of_weights():
    rng = np.random.default_rng(4)
    shape = (31, 31, 25)
    w = rng.random(shape)
    w /= w.sum()
    grid = msgs.BeliefGrid()
    grid.metadata.size_x, grid.metadata.size_y, grid.metadata.size_theta = shape
    grid.metadata.resolution_x = grid.metadata.resolution_y = 0.01
    grid.metadata.resolution_theta = 0.1
    grid.weights = w.ravel().tolist()
    cov = np.diag([0.05, 0.05, 0.52]) ** 2
    grid.covariance = cov.ravel()
    back = deserialize_message(serialize_message(grid), msgs.BeliefGrid)
    weights = np.asarray(back.weights).reshape(
        back.metadata.size_x, back.metadata.size_y, back.metadata.size_theta
    )
    np.testing.assert_array_equal(weights, w)  # C order over (x, y, θ), bit-exact
    np.testing.assert_array_equal(back.covariance.reshape(3, 3), cov)  # row-major 3x3


def test_sensor_indices_follow_the_config_order():
    for i, name in enumerate(SENSOR_NAMES):
        assert getattr(msgs.Observation, f"SENSOR_{name.upper()}") == i
    assert msgs.Observation.NUM_SENSORS == len(SENSOR_NAMES)
    assert len(msgs.Observation().sensors) == len(SENSOR_NAMES)
    assert len(msgs.ContactPads().in_contact) == msgs.Observation.SENSOR_DIST3 + 1


@pytest.mark.parametrize("cls", RESULT_TYPES, ids=lambda c: c.__qualname__)
def test_every_service_response_and_action_result_reports_errors(cls):
    fields = cls.get_fields_and_field_types()
    assert fields["error_code"] == "uint16"
    assert fields["error_msg"] == "string"
    assert cls.NONE == 0
    codes = constants(cls)
    assert "UNKNOWN" in codes
    assert len(set(codes.values())) == len(codes), f"duplicate error codes in {cls.__qualname__}"
    # nav2 style: one block of a hundred per interface, UNKNOWN first
    assert all(
        codes["UNKNOWN"] <= c < codes["UNKNOWN"] + 100 for n, c in codes.items() if n != "NONE"
    )


def test_select_action_has_the_issue_error_codes_and_fields():
    resp = srvs.SelectAction.Response
    for code in (
        "UNKNOWN_OBJECT",
        "INVALID_BELIEF",
        "INVALID_HORIZON",
        "INVALID_DELTA",
        "UNKNOWN_STRATEGY",
        "INVALID_GRID",
    ):
        assert hasattr(resp, code)
    assert set(resp.get_fields_and_field_types()) >= {
        "wrt_name",
        "value",
        "p_goal",
        "action_names",
        "action_values",
        "planning_time",
    }
    req = srvs.SelectAction.Request.get_fields_and_field_types()
    assert req["horizon"] == "uint8" and req["delta"] == "double"
    assert req["belief"] == "rrg_msgs/BeliefGrid"


def test_interfaces_use_standard_types_where_they_fit():
    assert "std_msgs/msg/Header" in nested_types(msgs.BeliefGrid)
    assert msgs.Observation.get_fields_and_field_types()["hand_pose"] == "geometry_msgs/Pose"
    assert (
        "geometry_msgs/Pose" in msgs.WorldRelativeTrajectory.get_fields_and_field_types()["poses"]
    )
    goal = actions.GuardedMove.Goal.get_fields_and_field_types()
    assert goal["trajectory"] == "trajectory_msgs/JointTrajectory"
    assert (
        actions.GuardedMove.Result.get_fields_and_field_types()["final_joint_state"]
        == "sensor_msgs/JointState"
    )
    assert (
        actions.ExecuteWrt.Result.get_fields_and_field_types()["observation"]
        == "rrg_msgs/Observation"
    )
    assert (
        actions.RobustGrasp.Feedback.get_fields_and_field_types()["belief"] == "rrg_msgs/BeliefGrid"
    )
