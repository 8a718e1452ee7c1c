"""``rrg-launch``'s supervision of its children (operations §8): stopping escalates from SIGINT to
SIGTERM to SIGKILL, and a child that dies while the graph runs is reported, published as a
NodeEvent and restarted after a growing delay, until its restarts are used up and the launcher
gives up. Small stand-in children (tests/launch_children.py) keep these fast and deterministic;
the last test kills the real recorder in a real graph."""

from __future__ import annotations

import json
import os
import re
import signal
import time
from pathlib import Path

import pytest
import yaml
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from ros_testing import (
    Launcher,
    RosClient,
    environment,
    foxglove_read,
    ros_settings,
)

from rrg_bags.bag_info import bag_info
from rrg_bags.bag_read import NODE_EVENTS_TOPIC, read_messages
from rrg_bringup.graph import Graph
from rrg_bringup.supervisor import LaunchError, exit_description, respawn_delay, ros_environment
from rrg_msgs.msg import NodeEvent

CHILD = str(Path(__file__).resolve().parents[1] / "launch_children.py")
EVENTS_QOS = QoSProfile(
    depth=100, durability=DurabilityPolicy.TRANSIENT_LOCAL, reliability=ReliabilityPolicy.RELIABLE
)


def wait_for(condition, timeout_s: float = 20.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not condition():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.02)


def log_text(tmp_path: Path, name: str) -> str:
    path = tmp_path / f"{name}.log"
    return path.read_text() if path.is_file() else ""


@pytest.mark.parametrize(
    ("ignored", "ended_by"),
    [("", signal.SIGINT), ("INT", signal.SIGTERM), ("INT,TERM", signal.SIGKILL)],
)
def test_stop_escalates_until_the_child_ends(tmp_path, ignored, ended_by):
    """A child that ignores SIGINT gets SIGTERM after the timeout, one that ignores SIGTERM too
    gets SIGKILL after another."""
    graph = Graph(dict(os.environ), None, tmp_path)
    graph.spawn("child", [CHILD, "sleep", "--ignore", ignored])
    wait_for(lambda: "ready" in log_text(tmp_path, "child"))
    escalate_s = 0.3
    t0 = time.monotonic()
    graph.stop(escalate_s)
    waited = time.monotonic() - t0
    proc = graph.children[0].proc
    assert proc.returncode == -ended_by
    steps = [signal.SIGINT, signal.SIGTERM, signal.SIGKILL].index(ended_by)
    assert waited >= steps * escalate_s  # it waited out each ignored signal
    log = log_text(tmp_path, "child")
    assert ("ignored SIGINT" in log) == ("INT" in ignored)
    assert ("ignored SIGTERM" in log) == ("TERM" in ignored)


def test_exits_and_backoff_in_words():
    assert exit_description(3) == "exited with status 3"
    assert exit_description(-signal.SIGKILL) == "killed by SIGKILL"
    assert exit_description(-signal.SIGSEGV) == "killed by SIGSEGV"
    assert [respawn_delay(k, 0.5) for k in range(1, 9)] == [0.5, 1, 2, 4, 8, 16, 30, 30]


def test_a_killed_child_is_restarted_with_its_restart_arguments(tmp_path, capfd):
    """Without the launcher's node (no events published): SIGKILL a child, the supervision
    restarts it once with --append before its ROS arguments, and gives up at the second kill."""
    graph = Graph(dict(os.environ), None, tmp_path, respawn_max=1, respawn_delay_s=0.0)
    graph.spawn("sleeper", [CHILD, "sleep", "--ros-args", "-p", "x:=1"], restart_args=["--append"])
    child = graph.children[0]
    try:
        wait_for(lambda: "ready" in log_text(tmp_path, "sleeper"))
        first = child.proc.pid
        os.kill(first, signal.SIGKILL)
        child.proc.wait(10)
        graph.supervise()  # schedules the restart (no delay)
        graph.supervise()  # and makes it
        assert child.proc.pid != first and child.restarts == 1
        wait_for(lambda: log_text(tmp_path, "sleeper").count("ready") == 2)
        log = log_text(tmp_path, "sleeper")
        assert "ready ['--append', '--ros-args', '-p', 'x:=1']" in log
        assert f"sleeper killed by SIGKILL (pid {first}); restarting it in 0.0 s" in log
        os.kill(child.proc.pid, signal.SIGKILL)
        child.proc.wait(10)
        with pytest.raises(LaunchError, match=r"SIGKILL \(pid \d+\); gave up after 1 restart$"):
            graph.supervise()
    finally:
        graph.stop(0.3)
    err = capfd.readouterr().err
    assert f"sleeper restarted (pid {child.proc.pid}, attempt 1 of 1)" in err


def test_a_child_that_keeps_dying_is_restarted_up_to_the_limit_then_the_graph_gives_up(
    tmp_path, ros_domain, capfd
):
    """A child exiting with status 3 every 0.3 s, two restarts allowed, 0.05 s first delay: the
    spin loop restarts it twice (after 0.05 s, then 0.1 s), then raises, which rrg-launch turns
    into exit status 1. Every event is published latched: a subscriber that comes after them
    (as a restarted recorder does) receives all five. The other child is left alone."""
    env = ros_environment(ros_domain)
    graph = Graph(env, None, tmp_path, respawn_max=2, respawn_delay_s=0.05)
    graph.spawn("steady", [CHILD, "sleep"])
    graph.spawn("crasher", [CHILD, "die", "0.3", "3"])
    steady = graph.children[0].proc
    with environment(ros_settings(env)):
        graph.connect()
    watcher = None
    try:
        with pytest.raises(LaunchError) as raised:
            graph.spin_until(lambda: False, 60.0, "the crasher to give up")
        assert str(raised.value).endswith("gave up after 2 restarts")
        watcher = RosClient(env, "node_events_watcher")
        events: list[NodeEvent] = []
        watcher.node.create_subscription(NodeEvent, NODE_EVENTS_TOPIC, events.append, EVENTS_QOS)
        assert watcher.spin_until(lambda: len(events) == 5, 20.0), events
        assert steady.poll() is None and graph.children[0].proc is steady
    finally:
        graph.disconnect()
        graph.stop(0.3)
        if watcher is not None:
            watcher.close()
    assert [e.event for e in events] == [
        NodeEvent.EVENT_EXITED,
        NodeEvent.EVENT_RESTARTED,
        NodeEvent.EVENT_EXITED,
        NodeEvent.EVENT_RESTARTED,
        NodeEvent.EVENT_GAVE_UP,
    ]
    assert {e.node for e in events} == {"crasher"}
    assert [e.attempt for e in events] == [1, 1, 2, 2, 2]
    assert {e.max_attempts for e in events} == {2}
    assert [e.delay for e in events] == [0.05, 0.0, 0.1, 0.0, 0.0]
    ended = [e for e in events if e.event != NodeEvent.EVENT_RESTARTED]
    assert {(e.exit_code, e.signal) for e in ended} == {(3, 0)}
    assert len({e.pid for e in events}) == 3  # three processes
    assert events[1].pid == events[2].pid  # the restarted one is the one that exited next
    stamps = [e.header.stamp.sec + e.header.stamp.nanosec * 1e-9 for e in events]
    assert stamps == sorted(stamps)
    err = capfd.readouterr().err
    assert (
        f"crasher exited with status 3 (pid {events[2].pid}); restarting it in 0.1 s "
        "(attempt 2 of 2)" in err
    )
    assert [e.message for e in events[:-1]] == re.findall(r"\[rrg-launch\] (crasher .*)", err)
    assert events[-1].message == str(raised.value)
    assert log_text(tmp_path, "crasher").count("ready") == 3


@pytest.mark.slow  # the launcher's node processes
def test_a_killed_recorder_is_restarted_into_a_new_split_and_the_restart_is_in_the_bag(
    tmp_path, ros_domain, capsys
):
    """SIGKILL the recorder while the first WRT runs (the simulator at 0.3 × real time, so that
    the grasp outlasts the restart): the launcher restarts it, the grasp goes on, and the bag has
    two files: the killed one, which the restarted recorder closed after its last complete
    record, and the restarted recorder's, both finalized and named in metadata.yaml. The restart
    is recorded as NodeEvents and listed by ``rrg-bag summary``; ``rrg-bag info``, Foxglove's
    and rosbags' readers read both files, the same messages."""
    name = "respawn"
    launcher = Launcher(
        tmp_path,
        name,
        ros_domain,
        *("--grasp", "box", "--level", "low", "--levels", "low", "--seed", "4", "--json"),
        *("--real-time-factor", "0.3"),
    )
    try:
        launcher.read_until("step 1:")  # the first action is under way
        recorder = launcher.pid("recorder")
        # the recorder writes what it has received every second: wait for the first decision
        wait_for(lambda: any(read_messages(launcher.bag, {"/rrg/grasp_step"})), 10.0)
        os.kill(recorder, signal.SIGKILL)
        launcher.read_until("recorder restarted")
        text = launcher.finish()
    except BaseException:
        launcher.proc.kill()
        raise
    assert launcher.proc.returncode == 0, text
    outcome = json.loads(text.strip().splitlines()[-1])
    assert outcome["error"] == "" and outcome["judge"], text
    assert f"recorder killed by SIGKILL (pid {recorder}); restarting it in 0.5 s" in text
    bag = launcher.bag
    assert sorted(p.name for p in bag.iterdir()) == [
        "metadata.yaml",
        f"{name}_0.mcap",
        f"{name}_1.mcap",
    ]
    meta = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert meta["relative_file_paths"] == [f"{name}_0.mcap", f"{name}_1.mcap"]
    info = bag_info(bag)
    assert info.unfinalized == []  # the killed split was closed by the restarted recorder
    assert meta["message_count"] == info.message_count
    assert [f["message_count"] for f in meta["files"]] == [
        bag_info(p).message_count for p in info.files
    ]
    assert "NOT finalized" not in text
    assert (
        f"closed the split {name}_0.mcap its killed recorder left open (summary)"
        in (launcher.log_dir / "recorder.log").read_text()
    )
    events = [m.msg for m in read_messages(bag, {NODE_EVENTS_TOPIC})]
    assert [(e.node, e.event, e.signal, e.attempt) for e in events] == [
        ("recorder", NodeEvent.EVENT_EXITED, signal.SIGKILL, 1),
        ("recorder", NodeEvent.EVENT_RESTARTED, 0, 1),
    ]
    outcomes = list(read_messages(bag, {"/rrg/eval/grasp_outcome"}))
    assert len(outcomes) == 1 and outcomes[0].msg.success == outcome["success"]
    counts = {t.name: t.count for t in info.topics if t.count}
    fox: dict[str, int] = {}
    for path in info.files:
        for topic, v in foxglove_read(path)["topics"].items():
            fox[topic] = fox.get(topic, 0) + v["count"]
    assert {t: n for t, n in fox.items() if n} == counts
    from rosbags.highlevel import AnyReader

    with AnyReader([bag]) as reader:
        assert sum(1 for _ in reader.messages()) == info.message_count
    from rrg_bags.bag_cli import main as bag_cli

    capsys.readouterr()
    assert bag_cli(["info", str(bag)]) == 0
    printed = capsys.readouterr().out
    assert f"{name}_0.mcap" in printed and f"{name}_1.mcap" in printed
    assert bag_cli(["summary", str(bag)]) == 0
    printed = capsys.readouterr().out
    assert f"Restarts:  recorder killed by SIGKILL (pid {recorder})" in printed
    assert "step 1:" in printed and "Simulator: " in printed


@pytest.mark.slow  # the launcher's node processes
def test_a_node_killed_more_often_than_allowed_stops_the_graph_with_exit_status_1(
    tmp_path, ros_domain
):
    """The graph alone, one restart allowed: the executor killed once is restarted, killed again
    the launcher gives up, stops the graph (the recorder last) and exits with status 1; the bag
    is finalized and holds the three events."""
    launcher = Launcher(
        tmp_path,
        "give_up",
        ros_domain,
        *("--object", "box", "--levels", "low", "--respawn-max", "1", "--respawn-delay", "0.1"),
    )
    try:
        launcher.read_until("running; Ctrl-C stops the graph")
        executor = launcher.pid("executor")
        os.kill(executor, signal.SIGKILL)
        restarted = int(re.search(r"\(pid (\d+)", launcher.read_until("executor restarted"))[1])
        os.kill(restarted, signal.SIGKILL)
        text = launcher.finish()
    except BaseException:
        launcher.proc.kill()
        raise
    assert launcher.proc.returncode == 1, text
    assert f"error: executor killed by SIGKILL (pid {restarted}); gave up after 1 restart" in text
    info = bag_info(launcher.bag)
    assert info.finalized and len(info.files) == 1
    events = [m.msg for m in read_messages(launcher.bag, {NODE_EVENTS_TOPIC})]
    assert [(e.node, e.event, e.pid) for e in events] == [
        ("executor", NodeEvent.EVENT_EXITED, executor),
        ("executor", NodeEvent.EVENT_RESTARTED, restarted),
        ("executor", NodeEvent.EVENT_GAVE_UP, restarted),
    ]
