"""rrg_planner.client.RRGClient: the planner as other robot software calls it. Without a graph
every call fails with a clear error within its timeout; on a running graph (``rrg-launch``
without a grasp) it selects actions for a Gaussian, resets and reads the belief, reports the
planner's error codes while the graph keeps serving, cancels a robust grasp in the middle, and
the example script prints the planner's answer."""

from __future__ import annotations

import math
import subprocess
import sys
import time

import numpy as np
import pytest
from ros_testing import (
    ROOT,
    Launcher,
    RosClient,
    environment,
    exclusive_domain_id,
    ros_env,
    ros_settings,
)

from rrg_common.ros.msg_conversions import planar_to_msg
from rrg_estimator.belief import Belief
from rrg_estimator.config import LEVELS
from rrg_models.config import WORLD
from rrg_msgs.srv import ResetSim, SelectAction
from rrg_planner.client import (
    Gaussian,
    GraspFeedback,
    RRGClient,
    RRGServiceError,
    RRGUnavailable,
    code_name,
)

OBJECT = "box"
NOMINAL = np.asarray(WORLD.nominal_pose)


def client_in(domain_id: int) -> RRGClient:
    """An RRGClient of its own in the test's DDS domain (loopback discovery, as the graph)."""
    with environment(ros_settings(ros_env(domain_id))):
        return RRGClient(domain_id=domain_id, node_name="rrg_client_test")


# ---------------------------------------------------------------------------- no ROS needed
def test_a_gaussian_is_the_levels_initial_belief_unless_sigma_is_given():
    mean = (0.6, 0.02, 0.3)
    ref = Belief.for_level(LEVELS["high"], mean)
    g = Gaussian(mean).belief()
    assert g.grid == ref.grid and np.allclose(g.weights, ref.weights)
    narrow = Gaussian(mean, sigma=(0.01, 0.01, 0.1)).belief()
    assert narrow.grid == ref.grid and narrow.weights.max() > 5 * ref.weights.max()


@pytest.mark.parametrize(
    "gaussian, message",
    [
        (Gaussian((0.6, 0.0, 0.0), level="huge"), "unknown level"),
        (Gaussian((0.6, 0.0, 0.0), sigma=(0.05, 0.0, 0.3)), "three positive numbers"),
        (Gaussian((0.6, 0.0, 0.0), sigma=(0.05, math.nan, 0.3)), "three positive numbers"),
    ],
)
def test_a_bad_gaussian_is_refused_before_anything_is_sent(gaussian, message):
    with pytest.raises(ValueError, match=message):
        gaussian.belief()


def test_error_codes_have_their_interfaces_names():
    assert code_name(SelectAction.Response, SelectAction.Response.INVALID_HORIZON) == (
        "INVALID_HORIZON"
    )
    assert code_name(SelectAction.Response, 9999) == "UNKNOWN"


# ---------------------------------------------------------------------------- no graph
def test_without_a_graph_every_call_fails_clearly_within_its_timeout():
    with exclusive_domain_id() as domain_id, client_in(domain_id) as rrg:
        assert not rrg.is_ready()
        calls = {
            "wait_until_ready": lambda: rrg.wait_until_ready(timeout_s=1.0),
            "select_action": lambda: rrg.select_action(
                OBJECT, Gaussian(tuple(NOMINAL)), timeout_s=1.0
            ),
            "reset_belief": lambda: rrg.reset_belief(OBJECT, NOMINAL, timeout_s=1.0),
            "get_belief": lambda: rrg.get_belief(timeout_s=1.0),
            "robust_grasp": lambda: rrg.robust_grasp(OBJECT, timeout_s=1.0),
        }
        for name, call in calls.items():
            t0 = time.monotonic()
            with pytest.raises(RRGUnavailable) as err:
                call()
            assert time.monotonic() - t0 < 5.0, name
            assert "/rrg/" in str(err.value) and "not available" in str(err.value), name
        assert "rrg-launch" in str(pytest.raises(RRGUnavailable, rrg.wait_until_ready, 0.2).value)


def test_a_client_on_a_given_node_needs_its_spin():
    with pytest.raises(ValueError, match="spin_once"):
        RRGClient(node=object())


# ---------------------------------------------------------------------------- a running graph
@pytest.fixture(scope="module")
def graph(tmp_path_factory, ros_domain):
    """``rrg-launch`` without a grasp (the box at high uncertainty, the simulator paced at real
    time so that a grasp lasts), and an RRGClient in its domain."""
    tmp = tmp_path_factory.mktemp("client_graph")
    launcher = Launcher(
        tmp,
        "client",
        ros_domain,
        *("--object", OBJECT, "--levels", "high", "--real-time-factor", "1", "--seed", "0"),
    )
    try:
        launcher.read_until("running; Ctrl-C stops the graph")
        rrg = client_in(ros_domain)
        rrg.wait_until_ready(timeout_s=60.0)
        yield ros_domain, rrg
        rrg.close()
    finally:
        launcher.proc.send_signal(2)  # SIGINT: the launcher stops the graph in order
        launcher.finish()


@pytest.mark.slow
def test_select_action_for_a_gaussian_answers_every_wrts_value(graph):
    _, rrg = graph
    choice = rrg.select_action(OBJECT, Gaussian(tuple(NOMINAL)), horizon=1)
    assert choice.wrt_name in choice.values and math.isfinite(choice.value)
    assert choice.value == pytest.approx(choice.values[choice.wrt_name])
    assert 0.0 <= choice.p_goal <= 1.0 and choice.planning_time_s > 0.0
    assert choice.estimate.shape == (3,) and np.all(np.isfinite(choice.estimate))


@pytest.mark.slow
def test_the_planners_error_codes_are_raised_and_the_graph_keeps_serving(graph):
    _, rrg = graph
    with pytest.raises(RRGServiceError) as err:
        rrg.select_action(OBJECT, Gaussian(tuple(NOMINAL)), horizon=9)
    assert err.value.code == SelectAction.Response.INVALID_HORIZON
    assert err.value.code_name == "INVALID_HORIZON" and "horizon" in err.value.message
    with pytest.raises(RRGServiceError, match="UNKNOWN_OBJECT"):
        rrg.reset_belief("no_such_object", NOMINAL)
    assert rrg.select_action(OBJECT, Gaussian(tuple(NOMINAL)), horizon=1).wrt_name


@pytest.mark.slow
def test_reset_belief_then_get_belief_and_plan_on_it(graph):
    _, rrg = graph
    mean = NOMINAL + np.array([0.02, -0.01, 0.1])
    belief = rrg.reset_belief(OBJECT, mean, level="high")
    assert np.allclose(belief.w_star(), mean, atol=1e-9)
    current = rrg.get_belief()
    assert current.object_name == OBJECT
    assert np.allclose(current.belief.weights, belief.weights)
    assert rrg.select_action(OBJECT, None, horizon=1).wrt_name  # the estimator's belief


@pytest.mark.slow
def test_a_grasp_cancelled_in_the_middle_ends_canceled_and_another_can_start(graph):
    domain_id, rrg = graph
    sim = RosClient(ros_env(domain_id), "client_test_sim")
    try:
        reset_sim = sim.node.create_client(ResetSim, "/rrg/reset_sim")
        sim.wait_for_services([reset_sim], [], timeout_s=30.0)
        request = ResetSim.Request(object_name=OBJECT, pose=planar_to_msg(NOMINAL))
        reset = None
        for _ in range(3):  # a server that has just matched may drop the first response
            reset = reset or sim.try_call(reset_sim, request, 20.0)
        assert reset is not None, "reset_sim did not answer"
    finally:
        sim.close()
    assert reset.error_code == ResetSim.Response.NONE, reset.error_msg
    steps: list[GraspFeedback] = []

    def on_feedback(fb: GraspFeedback) -> None:
        steps.append(fb)
        task.cancel()  # from inside the feedback: the first WRT is under way

    task = rrg.start_robust_grasp(OBJECT, level="high", horizon=1, on_feedback=on_feedback)
    t0 = time.monotonic()
    result = task.result(timeout_s=120.0)
    assert steps and steps[0].step == 1 and steps[0].belief.grid.size > 0
    assert result.canceled and result.code_name == "CANCELED", result
    assert not result.success and len(result.actions) <= 1
    assert time.monotonic() - t0 < 60.0
    # the planner is free again: a second grasp is accepted (and cancelled at once)
    again = rrg.start_robust_grasp(OBJECT, level="high", horizon=1)
    again.cancel()
    assert again.result(timeout_s=120.0).canceled


@pytest.mark.slow
def test_the_example_script_prints_the_planners_answer(graph):
    domain_id, _ = graph
    out = subprocess.run(
        [sys.executable, "scripts/example_select_action.py", "--object", OBJECT, "--horizon", "1"],
        env=ros_env(domain_id),
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout.startswith("next action: ") and "planned in" in out.stdout


# ---------------------------------------------------------------------------- the docs' CLI lines
def fill(msg, values: dict):
    """Set ``values`` (a YAML mapping) on ``msg`` as ``ros2 service call`` does: every key must
    be a field, nested mappings fill nested messages."""
    for key, value in values.items():
        assert hasattr(msg, key), f"{type(msg).__name__} has no field {key!r}"
        if isinstance(value, dict):
            fill(getattr(msg, key), value)
        else:
            setattr(msg, key, type(getattr(msg, key))(value))
    return msg


def test_the_documented_ros2_cli_calls_name_real_interfaces_and_fields():
    import importlib
    import re

    import yaml

    text = (ROOT / "docs" / "interfaces.md").read_text()
    calls = re.findall(
        r"ros2 (?:service call|action send_goal) (/rrg/\w+) (\w+)/(srv|action)/(\w+)"
        r' \\?\s*"(\{.*?\})"',
        text,
    )
    assert {c[0] for c in calls} == {
        "/rrg/select_action",
        "/rrg/reset_belief",
        "/rrg/get_belief",
        "/rrg/robust_grasp",
    }
    for name, package, sub, type_name, values in calls:
        interface = getattr(importlib.import_module(f"{package}.{sub}"), type_name)
        request = interface.Request() if sub == "srv" else interface.Goal()
        fill(request, yaml.safe_load(values) or {})
        assert name.rsplit("/", 1)[1] == re.sub(r"(?<!^)([A-Z])", r"_\1", type_name).lower()
