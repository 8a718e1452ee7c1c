"""Belief, grid, observation and pose ↔ ROS message conversions: exact round trips, and the
validation that turns a malformed belief message into InvalidGrid / InvalidBelief."""

from __future__ import annotations

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from rclpy.serialization import deserialize_message, serialize_message
from scipy.spatial.transform import Rotation

from rrg_common.ros.msg_conversions import (
    observation_from_msg,
    observation_to_msg,
    planar_from_msg,
    planar_to_msg,
    pose_from_msg,
    pose_to_msg,
    tip_contacts_from_msg,
    tip_contacts_to_msg,
)
from rrg_estimator.belief import Belief
from rrg_estimator.config import HIGH, LOW
from rrg_estimator.grid import Grid
from rrg_estimator.ros.belief_msgs import (
    InvalidBelief,
    InvalidGrid,
    belief_from_msg,
    belief_markers,
    belief_to_msg,
    grid_from_metadata,
    grid_to_metadata,
)
from rrg_models.observation import Observation
from rrg_models.poses import make_pose
from rrg_msgs.msg import Observation as ObservationMsg


def random_belief(seed: int, level=HIGH, center=(0.62, -0.01, 0.3)) -> Belief:
    rng = np.random.default_rng(seed)
    return Belief(Grid.for_level(level, center=center), rng.random(int(np.prod(level.shape))))


def roundtrip(msg):
    return deserialize_message(serialize_message(msg), type(msg))


@pytest.mark.parametrize("level", [HIGH, LOW])
def test_belief_round_trip_is_exact(level):
    b = random_belief(3, level)
    b = type(b)(b.grid, b.weights, "info1")  # held in a posture frame
    msg = roundtrip(belief_to_msg(b, Time(sec=12, nanosec=5)))
    back = belief_from_msg(msg)
    assert back.grid == b.grid and back.frame == "info1" == msg.posture_frame
    np.testing.assert_array_equal(back.weights, b.weights)
    assert msg.header.frame_id == "world" and msg.header.stamp == Time(sec=12, nanosec=5)
    assert msg.metadata.update_time == msg.header.stamp
    np.testing.assert_allclose(planar_from_msg(msg.argmax), b.w_star())
    np.testing.assert_allclose(planar_from_msg(msg.mean), b.mean())
    np.testing.assert_allclose(np.reshape(msg.covariance, (3, 3)), b.cov())


def test_weights_are_c_ordered_over_x_y_theta():
    grid = Grid((0.6, 0.0, 0.0), (0.01, 0.02, 0.1), (3, 5, 7))
    w = np.zeros(grid.size)
    w[(2 * 5 + 1) * 7 + 6] = 1.0  # ix=2, iy=1, itheta=6
    msg = belief_to_msg(Belief(grid, w), Time())
    np.testing.assert_allclose(planar_from_msg(msg.argmax), [0.61, -0.02, 0.3])
    meta = msg.metadata
    assert (meta.size_x, meta.size_y, meta.size_theta) == (3, 5, 7)
    assert grid_from_metadata(grid_to_metadata(grid)) == grid


@pytest.mark.parametrize(
    "field, value, words",
    [
        ("resolution_x", 0.0, "resolution"),
        ("resolution_theta", -0.1, "resolution"),
        ("resolution_y", float("inf"), "resolution"),
        ("size_y", 0, "size"),
    ],
)
def test_invalid_grid(field, value, words):
    msg = belief_to_msg(random_belief(1), Time())
    setattr(msg.metadata, field, value)
    with pytest.raises(InvalidGrid, match=words):
        belief_from_msg(msg)


@pytest.mark.parametrize(
    "edit, words",
    [
        (lambda w: w[:-3], "weights"),
        (lambda w: np.r_[w, 1.0], "weights"),
        (lambda w: np.where(np.arange(w.size) == 7, np.nan, w), "NaN"),
        (lambda w: np.where(np.arange(w.size) == 7, -0.5, w), "non-negative"),
        (lambda w: np.zeros_like(w), "zero"),
    ],
)
def test_invalid_belief(edit, words):
    msg = belief_to_msg(random_belief(2), Time())
    msg.weights = edit(np.asarray(msg.weights)).tolist()
    with pytest.raises(InvalidBelief, match=words):
        belief_from_msg(msg)


def test_pose_and_planar_round_trip():
    rng = np.random.default_rng(5)
    for _ in range(10):
        T = make_pose(rng.normal(size=3), Rotation.random(random_state=rng))
        np.testing.assert_allclose(pose_from_msg(roundtrip(pose_to_msg(T))), T, atol=1e-12)
    np.testing.assert_array_equal(
        planar_from_msg(planar_to_msg([0.1, -0.2, 3.0])), [0.1, -0.2, 3.0]
    )
    bad = pose_to_msg(np.eye(4))
    bad.orientation.w = 0.0
    with pytest.raises(ValueError):
        pose_from_msg(bad)


def test_observation_round_trip_keeps_nan_rows():
    rng = np.random.default_rng(9)
    points = rng.normal(size=(3, 3)) * 0.02
    normals = rng.normal(size=(3, 3))
    points[1] = normals[1] = np.nan  # finger 2's Nano17 did not fire
    obs = Observation(
        contact=True,
        progress=0.137,
        hand_pose=make_pose([0.6, 0.1, 0.2], Rotation.random(random_state=rng)),
        sensors=rng.random(10) < 0.5,
        closure=[0.4, 1.2, 2.0],
        tip_points=points,
        tip_normals=normals,
        motion_dir=[0.0, 0.6, -0.8],
        unconfirmed_stops=2,
    )
    msg = roundtrip(observation_to_msg(obs, "powerdrill", "info2", [0.62, 0.01, -0.2], Time(sec=4)))
    assert msg.unconfirmed_stops == 2 and observation_from_msg(msg).unconfirmed_stops == 2
    assert (msg.object_name, msg.wrt_name, list(msg.tip_valid)) == (
        "powerdrill",
        "info2",
        [True, False, True],
    )
    np.testing.assert_allclose(planar_from_msg(msg.estimate), [0.62, 0.01, -0.2])
    back = observation_from_msg(msg)
    assert back.contact and back.progress == pytest.approx(0.137)
    np.testing.assert_array_equal(back.sensors, obs.sensors)
    for name in ("closure", "tip_points", "tip_normals", "motion_dir"):
        np.testing.assert_allclose(getattr(back, name), getattr(obs, name))
    np.testing.assert_allclose(back.hand_pose, obs.hand_pose, atol=1e-12)
    bad = ObservationMsg()
    bad.hand_pose.orientation.w = 1.0
    bad.progress = float("nan")
    with pytest.raises(ValueError, match="progress"):
        observation_from_msg(bad)


def test_tip_contacts_round_trip():
    points = np.array([[0.01, 0.0, 0.1], [np.nan] * 3, [0.0, -0.01, 0.12]])
    normals = np.array([[0.0, 1.0, 0.0], [np.nan] * 3, [0.0, 0.0, 1.0]])
    contacts = tip_contacts_to_msg(points, normals, np.arange(18.0).reshape(3, 6))
    assert [c.valid for c in contacts] == [True, False, True]
    assert contacts[2].wrench.torque.z == 17.0
    p, n = tip_contacts_from_msg(contacts)
    np.testing.assert_array_equal(p, points)
    np.testing.assert_array_equal(n, normals)


def test_markers_show_the_heaviest_points():
    b = random_belief(4)
    arr = belief_markers(b, Time(), count=50, max_diameter_m=0.02)
    assert arr.markers[0].action == arr.markers[0].DELETEALL
    spheres = arr.markers[1:]
    assert len(spheres) == 50
    heaviest = b.grid.points()[np.argmax(b.weights)]
    assert (spheres[0].pose.position.x, spheres[0].pose.position.y) == pytest.approx(
        tuple(heaviest[:2])
    )
    assert spheres[0].scale.x == pytest.approx(0.02)
    assert all(a.scale.x >= c.scale.x for a, c in zip(spheres, spheres[1:]))
