"""Every node's health on /diagnostics (rrg_common.ros.diagnostics): the planner node, built
in this process, publishes a DiagnosticArray once a second under its status name, WARN while
the executor and the estimator it watches have not come up, OK once they have, and ERROR as
soon as they are lost (a peer process killed)."""

from __future__ import annotations

import signal
import subprocess
import sys
import time

import pytest
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.executors import SingleThreadedExecutor
from ros_testing import ROOT, environment, ros_env, ros_settings

from rrg_common.ros.diagnostics import ERROR, OK, WARN, Health, NodeDiagnostics

#: A process that announces itself as the executor and the estimator (their liveliness only).
PEERS = """
import time, rclpy
from rrg_common.ros.liveliness import announce
rclpy.init()
node = rclpy.create_node("diagnostics_test_peers")
announce(node, "executor")
announce(node, "estimator")
print("announced", flush=True)
while True:
    time.sleep(1.0)
"""


def test_health_escalates_worst_first_and_never_lowers():
    health = Health()
    health.escalate(WARN, "waiting for the executor")
    health.escalate(ERROR, "estimator lost")
    health.escalate(WARN, "slow")
    assert health.level == ERROR
    assert health.message == "estimator lost; waiting for the executor; slow"
    health.escalate(OK, "fine")
    assert health.level == ERROR and "fine" not in health.message


@pytest.fixture
def planner(ros_domain):
    """The planner node and a listener on /diagnostics in one executor of this process (the
    default context, in the test's domain): yields (spin_until, the arrays received with their
    arrival times, the test's environment)."""
    from rrg_planner.ros.planner_node import PlannerNode

    env = ros_env(ros_domain)
    with environment(ros_settings(env)):
        rclpy.init(domain_id=ros_domain)
    try:
        node = PlannerNode()
        listener = rclpy.create_node("diagnostics_listener")
        received: list[tuple[float, DiagnosticArray]] = []
        listener.create_subscription(
            DiagnosticArray, "/diagnostics", lambda m: received.append((time.monotonic(), m)), 10
        )
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        executor.add_node(listener)

        def spin_until(condition, timeout_s: float) -> bool:
            deadline = time.monotonic() + timeout_s
            while not condition():
                if time.monotonic() > deadline:
                    return False
                executor.spin_once(timeout_sec=0.05)
            return True

        yield spin_until, received, env
        executor.shutdown()
        node.destroy_node()
        listener.destroy_node()
    finally:
        rclpy.try_shutdown()


def planner_statuses(received: list, since: float = 0.0) -> list:
    return [
        (t, st)
        for t, a in received
        if t >= since
        for st in a.status
        if st.name == "planner: status"
    ]


def test_the_planner_reports_at_1_hz_and_a_lost_peer_as_an_error(planner):
    spin_until, received, env = planner
    start = time.monotonic()
    spin_until(lambda: time.monotonic() - start > 3.5, 5.0)
    reports = planner_statuses(received)
    assert len(reports) >= 2, [a.status for _, a in received]
    gaps = [b[0] - a[0] for a, b in zip(reports, reports[1:])]
    assert all(0.5 < g < 1.6 for g in gaps), gaps
    _, status = reports[-1]
    values = {v.key: v.value for v in status.values}
    assert status.hardware_id == "planner" and status.level[0] == WARN
    assert values["peer executor"] == values["peer estimator"] == "not seen yet"
    assert values["models loaded"] == "none" and values["last step"] == "none"
    assert "last select_action latency [ms]" in values

    peers = subprocess.Popen(
        [sys.executable, "-c", PEERS], env=env, cwd=ROOT, stdout=subprocess.PIPE, text=True
    )
    try:
        assert peers.stdout.readline().strip() == "announced"
        up = lambda: any(st.level[0] == OK for _, st in planner_statuses(received, start))
        assert spin_until(up, 30.0), [st for _, st in planner_statuses(received, start)][-1]
        _, status = next((t, st) for t, st in planner_statuses(received) if st.level[0] == OK)
        assert status.message == "ready"
        assert {v.key: v.value for v in status.values}["peer executor"] == "up"
        killed = time.monotonic()
        peers.send_signal(signal.SIGKILL)
        lost = lambda: any(st.level[0] == ERROR for _, st in planner_statuses(received, killed))
        assert spin_until(lost, 10.0), planner_statuses(received, killed)
    finally:
        peers.kill()
        peers.wait()
    status = next(st for _, st in planner_statuses(received, killed) if st.level[0] == ERROR)
    values = {v.key: v.value for v in status.values}
    assert "executor lost" in status.message and "estimator lost" in status.message
    assert values["peer executor"] == "lost" and values["peer executor losses"] == "1"


def test_a_failing_check_is_reported_as_an_error(ros_domain):
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=ros_domain)
    try:
        node = rclpy.create_node("diagnostics_check", context=context)

        def broken() -> Health:
            raise ValueError("no tables")

        status = NodeDiagnostics(node, broken, aspect="tables").status()
        node.destroy_node()
    finally:
        rclpy.try_shutdown(context=context)
    assert status.name == "diagnostics_check: tables" and status.level[0] == ERROR
    assert status.message == "the health check failed: ValueError: no tables"
