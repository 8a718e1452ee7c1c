"""The planner's select-action service and the estimator's services, as separate node processes:
valid requests get the answer the core computes in-process on the same belief, and every bad
input the issue lists gets its error code and a message while the nodes keep serving (also
observations the estimator cannot use, which it logs while keeping its belief, and bad
robust-grasp goals)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import NamedTuple

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from rclpy.action import ActionClient
from ros_testing import RosClient, node_processes, ros_env

from rrg_common.ros.msg_conversions import observation_to_msg, planar_to_msg
from rrg_common.ros.qos import LATCHED, STREAM
from rrg_estimator.belief import Belief
from rrg_estimator.config import LOW
from rrg_estimator.grid import Grid
from rrg_estimator.ros.belief_msgs import belief_from_msg, belief_to_msg
from rrg_models.config import WORLD
from rrg_models.objects import get_object
from rrg_models.poses import compose_planar
from rrg_msgs.action import RobustGrasp
from rrg_msgs.msg import BeliefGrid
from rrg_msgs.msg import Observation as ObservationMsg
from rrg_msgs.srv import GetBelief, ResetBelief, SelectAction
from rrg_planner.agent import RobustGraspAgent
from rrg_planner.closed_loop import decide
from rrg_planner.planning_model import PlanningModel
from rrg_planner.search import ForwardSearch
from rrg_sim.geometric_sim import GeometricSimulator

pytestmark = pytest.mark.slow  # node processes

OBJECT = "box"
SA = SelectAction.Response
RB = ResetBelief.Response
NOMINAL = np.asarray(WORLD.nominal_pose)


class Graph(NamedTuple):
    client: RosClient
    clients: dict
    logs: Path
    procs: list
    #: the answers of select_action (on the current belief) and get_belief before any request
    #: changed the estimator: it has no belief yet
    fresh: dict


@pytest.fixture(scope="module")
def graph(tmp_path_factory, ros_domain):
    """Estimator + planner processes (low level only, the box's model preloaded) and a client."""
    env = ros_env(ros_domain)
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
        # asked here, before any test runs, so the answers do not depend on the tests' order
        fresh = {
            "select": client.call(
                clients["select"], select_request(use_current_belief=True, belief=BeliefGrid())
            ),
            "get": client.call(clients["get"], GetBelief.Request()),
        }
        yield Graph(client, clients, logs, procs, fresh)
        client.close()


@pytest.fixture(scope="module")
def model() -> PlanningModel:
    """The planning model the planner node loads (level low; its tables from the disk cache)."""
    return PlanningModel(OBJECT, levels=("low",), progress=False)


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


def two_peaked_belief() -> Belief:
    """Two Gaussians 2.4 cm apart in y (weights 0.6, 0.4) on the grid centred at the nominal
    pose: with δ = 0.01 the search chooses an information-gathering WRT."""
    grid = Grid.for_level(LOW, center=NOMINAL)
    peak = [
        Belief.gaussian(grid, compose_planar(NOMINAL, (0.0, dy, 0.0)), np.asarray(LOW.sigma) / 2)
        for dy in (0.012, -0.012)
    ]
    return Belief(grid, 0.6 * peak[0].weights + 0.4 * peak[1].weights)


def gaussian_at(mean, center=None) -> Belief:
    mean = np.asarray(mean, dtype=float)
    grid = Grid.for_level(LOW, center=mean if center is None else center)
    return Belief.gaussian(grid, mean, LOW.sigma)


#: name: (belief, horizon, delta, the WRT chosen: a check that the cases differ)
SEARCH_CASES = {
    "centred H=1": (lambda: gaussian_at(NOMINAL), 1, 0.1, "goal"),
    "off-centre H=3": (
        lambda: gaussian_at(NOMINAL + (0.01, -0.008, 0.05), center=NOMINAL),
        3,
        0.1,
        "goal",
    ),
    "two peaks H=2": (two_peaked_belief, 2, 0.01, "sweep"),
    # far to the side and turned: info2 and the sweep cannot run there (their values NaN)
    "partly infeasible H=1": (lambda: gaussian_at((0.75, -0.3, 2.0)), 1, 0.1, "goal"),
}


@pytest.mark.parametrize("case", list(SEARCH_CASES))
def test_select_action_answers_as_the_in_process_search(graph, model, case):
    """The node's chosen WRT, estimate, every action's value and v(b) are those the core
    computes in this process on the same belief (decide: what the node runs; ForwardSearch:
    the search alone), with NaN where an action is infeasible."""
    client, clients, *_ = graph
    make_belief, horizon, delta, chosen = SEARCH_CASES[case]
    msg = belief_to_msg(make_belief(), stamp=Time())
    resp = client.call(clients["select"], select_request(belief=msg, horizon=horizon, delta=delta))
    assert resp.error_code == SA.NONE, resp.error_msg
    belief = belief_from_msg(msg)  # what the node decided on
    local = decide(RobustGraspAgent(model, "rrg-info", horizon, delta), belief, 1)
    search = ForwardSearch(model).select(belief, horizon, delta)
    assert resp.wrt_name == local.wrt == chosen
    assert list(resp.action_names) == model.names
    expected = np.where(np.isfinite(search.action_values), search.action_values, np.nan)
    np.testing.assert_allclose(
        [local.action_values[n] for n in model.names], search.action_values, rtol=1e-12
    )
    got = np.asarray(resp.action_values)
    assert np.array_equal(np.isnan(got), np.isnan(expected))
    assert np.isfinite(expected).sum() >= 3
    if case.startswith("partly"):
        assert np.isnan(expected).any()
    np.testing.assert_allclose(got, expected, rtol=1e-9, atol=1e-12, equal_nan=True)
    assert resp.p_goal == pytest.approx(search.p_goal, rel=1e-9, abs=1e-12)
    assert resp.p_goal == pytest.approx(local.p_goal, rel=1e-9, abs=1e-12)
    assert resp.value == pytest.approx(local.value, rel=1e-9, abs=1e-12)
    estimate = np.array([resp.estimate.x, resp.estimate.y, resp.estimate.theta])
    np.testing.assert_allclose(estimate, local.estimate, rtol=0, atol=1e-12)


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
    """No belief before the first reset (asked when the graph started), then the reset one."""
    client, clients, *_ = graph
    resp = graph.fresh["select"]
    assert resp.error_code == SA.NO_BELIEF and resp.error_msg, resp.error_msg
    assert resp.wrt_name == "" and len(resp.action_values) == 0
    assert graph.fresh["get"].error_code == GetBelief.Response.NO_BELIEF
    assert graph.fresh["get"].error_msg and len(graph.fresh["get"].belief.weights) == 0
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


def observation_msg(wrt: str, stamp_sec: int, **changes) -> ObservationMsg:
    """The observation of the box's WRT ``wrt`` run at the nominal pose with the box 1 cm off in
    x (geometric simulator), stamped stamp_sec (after the belief's last event: the estimator
    skips older events as applied); ``changes``: message fields to overwrite."""
    obj = get_object(OBJECT)
    true = compose_planar(NOMINAL, (0.01, 0.0, 0.0))
    obs = GeometricSimulator(obj, obj.wrt(wrt)).simulate(true, NOMINAL)
    msg = observation_to_msg(obs, OBJECT, wrt, NOMINAL, Time(sec=stamp_sec))
    for k, v in changes.items():
        setattr(msg, k, v)
    return msg


def _no_motion(msg: ObservationMsg) -> ObservationMsg:
    msg.contact = True
    msg.motion_dir.x = msg.motion_dir.y = math.nan
    return msg


#: name: (observation stamped some seconds after t [s], what the estimator's error log says)
BAD_OBSERVATIONS = {
    "NaN closures": (
        lambda t: observation_msg("info1", t + 101, closure=np.full(3, math.nan)),
        "non-finite closure",
    ),
    "infinite closure": (
        lambda t: observation_msg("info1", t + 106, closure=np.array([0.5, math.inf, 0.5])),
        "non-finite closure",
    ),
    "another object": (lambda t: observation_msg("info1", t + 102, object_name="can"), "'can'"),
    "unknown WRT": (
        lambda t: observation_msg("info1", t + 103, wrt_name="no_such_wrt"),
        "unknown WRT",
    ),
    # a contact with no direction of the hand's motion: no push to model
    "contact without a motion": (
        lambda t: _no_motion(observation_msg("info1", t + 104)),
        "motion direction",
    ),
}


def test_bad_observations_are_logged_and_the_belief_is_kept(graph):
    """Each bad observation is logged as an error and changes nothing (no belief published,
    get_belief's belief the same); a valid one afterwards updates the belief."""
    client, clients, logs, _, _ = graph
    reset = client.call(clients["reset"], reset_request(), timeout_s=120.0)
    assert reset.error_code == RB.NONE, reset.error_msg
    published: list[BeliefGrid] = []
    sub = client.node.create_subscription(BeliefGrid, "/rrg/belief", published.append, LATCHED)
    # latched, as the executor publishes it: the estimator asks for TRANSIENT_LOCAL (qos.STREAM)
    pub = client.node.create_publisher(ObservationMsg, "/rrg/observation", STREAM)
    log = logs / "estimator_node.log"
    try:
        # the latched belief is the reset's
        assert client.spin_until(
            lambda: published and published[-1].header.stamp == reset.belief.header.stamp, 20.0
        )
        assert client.spin_until(lambda: pub.get_subscription_count() > 0, 20.0)
        n_published = len(published)
        t = reset.belief.header.stamp.sec  # the reset is the belief's last event
        for case, (make, words) in BAD_OBSERVATIONS.items():
            seen = len(log.read_text())
            pub.publish(make(t))

            def refused(words=words, seen=seen) -> bool:
                new = log.read_text()[seen:]
                return any("ERROR" in line and words in line for line in new.splitlines())

            assert client.spin_until(refused, 20.0), (case, log.read_text()[seen:])
            assert "belief kept" in log.read_text()[seen:], case
            kept = client.call(clients["get"], GetBelief.Request())
            assert kept.error_code == GetBelief.Response.NONE, case
            assert kept.belief.header.stamp == reset.belief.header.stamp, case
            np.testing.assert_array_equal(
                np.asarray(kept.belief.weights), np.asarray(reset.belief.weights), err_msg=case
            )
        good = observation_msg("info1", t + 105)
        pub.publish(good)
        assert client.spin_until(lambda: len(published) > n_published, 20.0), log.read_text()
        # the first belief published since the reset's is the valid observation's: none of
        # the bad ones published one
        assert published[n_published].header.stamp == good.header.stamp
        updated = client.call(clients["get"], GetBelief.Request())
        assert updated.belief.header.stamp == good.header.stamp
        assert not np.array_equal(
            np.asarray(updated.belief.weights), np.asarray(reset.belief.weights)
        )
        assert "updated with info1" in log.read_text()
        assert_serving(client, clients)
    finally:
        client.node.destroy_publisher(pub)
        client.node.destroy_subscription(sub)


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
