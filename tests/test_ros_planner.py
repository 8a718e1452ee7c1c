"""The planner's select-action service and the estimator's services, as separate node processes:
valid requests get an answer from the core, and every bad input the issue lists gets its error
code and a message while the nodes keep serving (also an observation naming an unknown WRT, and
bad robust-grasp goals)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from rclpy.action import ActionClient
from ros_testing import RosClient, node_processes, ros_env

from rrg_estimator.belief import Belief
from rrg_estimator.config import LOW
from rrg_estimator.grid import Grid
from rrg_estimator.ros.belief_msgs import belief_to_msg
from rrg_msgs.action import RobustGrasp
from rrg_msgs.msg import BeliefGrid
from rrg_msgs.msg import Observation as ObservationMsg
from rrg_msgs.srv import GetBelief, ResetBelief, SelectAction
from rrg_sim.config import WORLD
from rrg_sim.ros_common.msg_conversions import planar_to_msg

DOMAIN_ID = 41
OBJECT = "box"
SA = SelectAction.Response
RB = ResetBelief.Response
NOMINAL = np.asarray(WORLD.nominal_pose)


@pytest.fixture(scope="module")
def graph(tmp_path_factory):
    """Estimator + planner processes (low level only, the box's model preloaded) and a client."""
    env = ros_env(DOMAIN_ID)
    logs = tmp_path_factory.mktemp("logs")
    specs = [
        ("rrg_estimator.ros.estimator_node", {}),
        ("rrg_planner.ros.planner_node", {"levels": "['low']", "preload": f"['{OBJECT}']"}),
    ]
    with node_processes(specs, env, logs) as procs:
        client = RosClient(env)
        node = client.node
        clients = {
            "select": node.create_client(SelectAction, "/rrg/select_action"),
            "reset": node.create_client(ResetBelief, "/rrg/reset_belief"),
            "get": node.create_client(GetBelief, "/rrg/get_belief"),
        }
        client.wait_for_services(clients.values(), procs, timeout_s=180.0)
        yield client, clients, logs, procs
        client.close()


def gaussian_belief_msg(mean=NOMINAL) -> BeliefGrid:
    return belief_to_msg(
        Belief.gaussian(Grid.for_level(LOW, center=mean), mean, LOW.sigma), stamp=Time()
    )


def select_request(**overrides) -> SelectAction.Request:
    req = SelectAction.Request(
        belief=gaussian_belief_msg(), object_name=OBJECT, strategy="rrg-info", horizon=1, delta=0.1
    )
    for k, v in overrides.items():
        setattr(req, k, v)
    return req


def assert_serving(client, clients) -> SelectAction.Response:
    resp = client.call(clients["select"], select_request())
    assert resp.error_code == SA.NONE, resp.error_msg
    return resp


def test_select_action_answers_with_every_action_value(graph):
    client, clients, *_ = graph
    resp = assert_serving(client, clients)
    assert resp.error_msg == ""
    assert resp.wrt_name in resp.action_names
    assert list(resp.action_names) == ["goal", "info1", "info2", "info3", "sweep"]
    assert len(resp.action_values) == len(resp.action_names)
    assert resp.value == pytest.approx(
        resp.action_values[list(resp.action_names).index(resp.wrt_name)]
    )
    assert 0.0 <= resp.p_goal <= 1.0 and resp.planning_time > 0.0
    goal = client.call(clients["select"], select_request(strategy="rrg-goal"))
    assert (goal.error_code, goal.wrt_name, list(goal.action_names)) == (SA.NONE, "goal", [])
    # the goal grasp runs at w* moved to its measured aim: within a few mm and degrees of w*
    aimed = np.array([goal.estimate.x, goal.estimate.y, goal.estimate.theta])
    assert np.all(np.abs(aimed - NOMINAL) < (0.01, 0.01, 0.15)) and np.any(aimed != 0.0)
    assert goal.p_goal == pytest.approx(
        resp.p_goal, abs=0.005
    )  # the search drops the belief's far tail


def _weights(kind: str) -> np.ndarray:
    w = np.asarray(gaussian_belief_msg().weights)
    if kind == "too_few":
        return w[:-1]
    if kind == "too_many":
        return np.r_[w, 0.0]
    if kind == "nan":
        w[5] = math.nan
    elif kind == "negative":
        w[5] = -1e-3
    elif kind == "all_zero":
        w[:] = 0.0
    return w


BAD_REQUESTS = {
    "unknown object": (dict(object_name="teapot"), SA.UNKNOWN_OBJECT, "teapot"),
    "too few weights": (dict(weights="too_few"), SA.INVALID_BELIEF, "weights"),
    "too many weights": (dict(weights="too_many"), SA.INVALID_BELIEF, "weights"),
    "NaN weight": (dict(weights="nan"), SA.INVALID_BELIEF, "NaN"),
    "negative weight": (dict(weights="negative"), SA.INVALID_BELIEF, "non-negative"),
    "all-zero weights": (dict(weights="all_zero"), SA.INVALID_BELIEF, "zero"),
    "horizon 0": (dict(horizon=0), SA.INVALID_HORIZON, "horizon"),
    "horizon 4": (dict(horizon=4), SA.INVALID_HORIZON, "horizon"),
    "delta 0": (dict(delta=0.0), SA.INVALID_DELTA, "delta"),
    "delta 1": (dict(delta=1.0), SA.INVALID_DELTA, "delta"),
    "delta NaN": (dict(delta=math.nan), SA.INVALID_DELTA, "delta"),
    "unknown strategy": (dict(strategy="greedy"), SA.UNKNOWN_STRATEGY, "greedy"),
    "zero x spacing": (dict(grid=("resolution_x", 0.0)), SA.INVALID_GRID, "resolution"),
    "negative theta spacing": (
        dict(grid=("resolution_theta", -0.013)),
        SA.INVALID_GRID,
        "resolution",
    ),
    "NaN y spacing": (dict(grid=("resolution_y", math.nan)), SA.INVALID_GRID, "resolution"),
    "zero size": (dict(grid=("size_theta", 0)), SA.INVALID_GRID, "size"),
    "spacing without tables": (dict(grid=("resolution_x", 0.003)), SA.INVALID_GRID, "spacing"),
}


@pytest.mark.parametrize("case", list(BAD_REQUESTS))
def test_select_action_rejects_bad_input_and_keeps_serving(graph, case):
    client, clients, *_ = graph
    fields, code, words = BAD_REQUESTS[case]
    req = select_request()
    for k, v in fields.items():
        if k == "weights":
            req.belief.weights = _weights(v).tolist()
        elif k == "grid":
            setattr(req.belief.metadata, *v)
        else:
            setattr(req, k, v)
    resp = client.call(clients["select"], req)
    assert resp.error_code == code, resp.error_msg
    assert words in resp.error_msg and resp.wrt_name == ""
    assert_serving(client, clients)


def reset_request(**overrides) -> ResetBelief.Request:
    req = ResetBelief.Request(
        object_name=OBJECT,
        mean=planar_to_msg(NOMINAL),
        sigma_x=LOW.sigma[0],
        sigma_y=LOW.sigma[1],
        sigma_theta=LOW.sigma[2],
        level="low",
    )
    for k, v in overrides.items():
        setattr(req, k, v)
    return req


BAD_RESETS = {
    "unknown object": (dict(object_name="teapot"), RB.UNKNOWN_OBJECT),
    "zero sigma": (dict(sigma_x=0.0), RB.INVALID_SIGMA),
    "negative sigma": (dict(sigma_theta=-0.1), RB.INVALID_SIGMA),
    "NaN sigma": (dict(sigma_y=math.nan), RB.INVALID_SIGMA),
    "NaN mean": (dict(mean=planar_to_msg([math.nan, 0.0, 0.0])), RB.INVALID_MEAN),
    "unknown level": (dict(level="medium"), RB.UNKNOWN_LEVEL),
}


def test_current_belief_before_and_after_reset(graph):
    """Ordered before the tests that reset: no belief yet, then the estimator's reset one."""
    client, clients, *_ = graph
    resp = client.call(
        clients["select"], select_request(use_current_belief=True, belief=BeliefGrid())
    )
    assert resp.error_code == SA.NO_BELIEF, resp.error_msg
    assert (
        client.call(clients["get"], GetBelief.Request()).error_code == GetBelief.Response.NO_BELIEF
    )
    reset = client.call(clients["reset"], reset_request(), timeout_s=120.0)
    assert reset.error_code == RB.NONE, reset.error_msg
    resp = client.call(
        clients["select"], select_request(use_current_belief=True, belief=BeliefGrid())
    )
    assert resp.error_code == SA.NONE, resp.error_msg
    other = client.call(
        clients["select"], select_request(use_current_belief=True, object_name="can")
    )
    assert other.error_code == SA.INVALID_BELIEF and "box" in other.error_msg


@pytest.mark.parametrize("case", list(BAD_RESETS))
def test_reset_belief_rejects_bad_input_and_keeps_serving(graph, case):
    client, clients, *_ = graph
    fields, code = BAD_RESETS[case]
    resp = client.call(clients["reset"], reset_request(**fields))
    assert resp.error_code == code and resp.error_msg, resp.error_msg
    assert len(resp.belief.weights) == 0
    ok = client.call(clients["reset"], reset_request(), timeout_s=120.0)
    assert ok.error_code == RB.NONE, ok.error_msg
    assert len(ok.belief.weights) == int(np.prod(LOW.shape))


def test_observation_with_unknown_wrt_is_logged_and_ignored(graph):
    client, clients, logs, _ = graph
    assert client.call(clients["reset"], reset_request(), timeout_s=120.0).error_code == RB.NONE
    before = client.call(clients["get"], GetBelief.Request())
    pub = client.node.create_publisher(ObservationMsg, "/rrg/observation", 10)
    assert client.spin_until(lambda: pub.get_subscription_count() > 0, 20.0)
    obs = ObservationMsg(
        object_name=OBJECT, wrt_name="no_such_wrt", estimate=planar_to_msg(NOMINAL)
    )
    obs.hand_pose.orientation.w = 1.0
    pub.publish(obs)
    log = logs / "estimator_node.log"
    assert client.spin_until(lambda: "unknown WRT" in log.read_text(), 20.0), log.read_text()
    after = client.call(clients["get"], GetBelief.Request())
    assert after.error_code == GetBelief.Response.NONE
    assert after.belief.header.stamp == before.belief.header.stamp
    np.testing.assert_array_equal(
        np.asarray(after.belief.weights), np.asarray(before.belief.weights)
    )
    assert_serving(client, clients)
    client.node.destroy_publisher(pub)


BAD_GRASPS = {
    "unknown object": (dict(object_name="teapot"), RobustGrasp.Result.UNKNOWN_OBJECT),
    "unknown level": (dict(level="medium"), RobustGrasp.Result.UNKNOWN_LEVEL),
    "level not loaded": (dict(level="high"), RobustGrasp.Result.UNKNOWN_LEVEL),
    "negative sigma": (dict(sigma_x=-0.01), RobustGrasp.Result.INVALID_SIGMA),
    "horizon 0": (dict(horizon=0), RobustGrasp.Result.INVALID_HORIZON),
    "delta 1": (dict(delta=1.0), RobustGrasp.Result.INVALID_DELTA),
    "unknown strategy": (dict(strategy="greedy"), RobustGrasp.Result.UNKNOWN_STRATEGY),
    "too many actions": (dict(max_actions=11), RobustGrasp.Result.INVALID_MAX_ACTIONS),
}


def test_robust_grasp_rejects_bad_goals_and_keeps_serving(graph):
    """Validated before anything moves (there is no executor in this graph)."""
    client, clients, *_ = graph
    action = ActionClient(client.node, RobustGrasp, "/rrg/robust_grasp")
    assert action.wait_for_server(timeout_sec=30.0)
    for case, (fields, code) in BAD_GRASPS.items():
        goal = RobustGrasp.Goal(
            object_name=OBJECT, level="low", strategy="rrg-info", horizon=1, delta=0.1
        )
        for k, v in fields.items():
            setattr(goal, k, v)
        handle = client.result(action.send_goal_async(goal), 10.0)
        result = client.result(handle.get_result_async(), 30.0).result
        assert result.error_code == code and result.error_msg, (case, result.error_msg)
        assert not result.success and list(result.actions_taken) == []
    assert_serving(client, clients)
