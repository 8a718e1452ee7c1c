"""Crashed nodes in the middle of a robust grasp (operations §8): the launcher respawns a node
killed with SIGKILL, and the grasp goes on. A restarted estimator restores its belief, a lost
execution is brought home and chosen again, a restarted planner resumes the grasp; the grasp
completes and the simulator judges it, the bag records the restart, and no log holds a
traceback. A dead simulator is a robot fault: the grasp aborts with ROBOT_FAULT and the bag is
finalized."""

from __future__ import annotations

import json
import os
import signal
import time

import pytest
from ros_testing import Launcher, RosClient, ros_env

from rrg_bags.bag_info import bag_info
from rrg_bags.bag_read import read_messages
from rrg_msgs.action import RobustGrasp

#: How long the stall test stops the planner [s]: three liveliness leases
#: (rrg_common.ros.liveliness.ALIVE_LEASE_S), so its peers see it go away.
STALL_S = 3.0


def kill_mid_grasp(
    tmp_path, domain_id: int, node: str, *extra: str, stall: bool = False
) -> tuple[int, str, dict | None, Launcher]:
    """Run a robust grasp of the box (high uncertainty, the simulator at real time), SIGKILL
    ``node`` once step 2 is under way and the arm has left home (``stall``: SIGSTOP it for
    STALL_S instead, then SIGCONT), and return (exit status, the launcher's output, the JSON
    outcome or None, the launcher)."""
    watcher = RosClient(ros_env(domain_id), f"kill_{node}_watcher")
    launcher = Launcher(
        tmp_path,
        node,
        domain_id,
        *("--grasp", "box", "--level", "high", "--seed", "3", "--real-time-factor", "1"),
        "--json",
        *extra,
    )

    def disturb() -> None:
        if stall:
            os.kill(launcher.pid(node), signal.SIGSTOP)
            time.sleep(STALL_S)
            os.kill(launcher.pid(node), signal.SIGCONT)
        else:
            os.kill(launcher.pid(node), signal.SIGKILL)

    try:
        text = launcher.disturb_while_moving(2, watcher, disturb)
    finally:
        watcher.close()
    last = text.strip().splitlines()[-1]
    outcome = json.loads(last) if last.startswith("{") else None
    return launcher.proc.returncode, text, outcome, launcher


def assert_no_traceback(launcher: Launcher) -> None:
    """No node's log holds a Python traceback."""
    for log in launcher.log_dir.glob("*.log"):
        text = log.read_text()
        assert "Traceback" not in text, f"{log.name}:\n{text[-3000:]}"


def restarts_in_bag(bag_dir, node: str) -> list:
    """The launcher's NodeEvent records of ``node`` in the bag."""
    return [
        m.msg
        for m in read_messages(bag_dir, topics=["/rrg/launch/node_events"])
        if m.msg.node == node
    ]


@pytest.mark.slow  # a robust grasp of the ROS graph at real time
@pytest.mark.parametrize(
    "node, extra, log, evidence",
    [
        # restarted 10 s later: the WRT's observation arrives while it is down
        ("estimator", ["--respawn-delay", "10"], "estimator", "restored the belief about box"),
        ("executor", [], "planner", "lost (the executor went away while running"),
        ("planner", [], "planner", "resumed after"),
    ],
)
def test_a_node_killed_mid_grasp_is_respawned_and_the_grasp_completes(
    tmp_path, ros_domain, node, extra, log, evidence
):
    status, text, outcome, launcher = kill_mid_grasp(tmp_path, ros_domain, node, *extra)
    bag = launcher.bag
    assert status == 0, text
    assert evidence in (launcher.log_dir / f"{log}.log").read_text()  # the recovery path ran
    assert outcome is not None and outcome["error"] == "", text
    assert outcome["judge"], text  # the simulator judged the final grasp
    assert outcome["actions"] and outcome["actions"][-1] == "goal", text
    events = restarts_in_bag(bag, node)
    assert events, f"no restart of the {node} in the bag"
    info = bag_info(bag)
    assert info.finalized, text
    assert_no_traceback(launcher)
    # no observation was lost: the estimator published a belief of each one's stamp
    stamps: dict[str, set] = {}
    for m in read_messages(bag, topics=["/rrg/observation", "/rrg/belief"]):
        stamps.setdefault(m.topic, set()).add((m.msg.header.stamp.sec, m.msg.header.stamp.nanosec))
    assert stamps["/rrg/observation"] and stamps["/rrg/observation"] <= stamps["/rrg/belief"]


@pytest.mark.slow  # a robust grasp of the ROS graph at real time
def test_a_planner_that_stalls_mid_grasp_is_waited_on_not_sent_the_grasp_again(
    tmp_path, ros_domain
):
    """A stalled planner loses its liveliness like a dead one; the launcher tells them apart by
    its own child process, so the grasp it runs is not sent again (which it would refuse)."""
    status, text, outcome, launcher = kill_mid_grasp(tmp_path, ros_domain, "planner", stall=True)
    assert status == 0, text
    assert "the planner went away" in text, text  # the stall was long enough to be seen
    assert "the planner had stalled, not died (same process)" in text, text
    assert outcome is not None and outcome["error"] == "", text
    assert outcome["actions"] and outcome["actions"][-1] == "goal", text
    assert not restarts_in_bag(launcher.bag, "planner")
    assert "resumed after" not in (launcher.log_dir / "planner.log").read_text()
    assert_no_traceback(launcher)


@pytest.mark.slow  # a robust grasp of the ROS graph at real time
def test_a_simulator_killed_mid_grasp_aborts_the_grasp_as_a_robot_fault(tmp_path, ros_domain):
    status, text, outcome, launcher = kill_mid_grasp(tmp_path, ros_domain, "sim")
    assert status == 1, text
    assert outcome is not None, text
    assert f"robust_grasp error {RobustGrasp.Result.ROBOT_FAULT}" in outcome["error"], text
    assert bag_info(launcher.bag).finalized, text
    assert_no_traceback(launcher)
