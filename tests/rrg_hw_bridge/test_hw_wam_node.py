"""The hardware bridge on Barrett's own wam_node (arm_backend wam_node), against the emulated
wam_node of rrg_fake_hw (arm_interface wam_node): a guarded move is streamed on
/wam/RTJointPositionCMD along its via-points at 500 Hz and ends where commanded; a contact
stops the stream and holds the arm at once through /wam/holdJointPosition, and the result
reports the measured stop pose; a refused trajectory streams nothing."""

from __future__ import annotations

import time

import numpy as np
import pytest
from fake_hw_testing import BOX_POSE, HOSTS, free_udp_port

from rrg_common.ros.msg_conversions import ARM_JOINT_NAMES
from rrg_models import wam

#: wam_node's arm joint names in /joint_states.
WAM_JOINTS = tuple(f"q{i}" for i in range(1, 8))
#: Via-points near home (the hand ~0.5 m above the table, inside the workspace box).
STEP = np.array([0.15, -0.1, 0.1, 0.2, 0.0, 0.1, 0.05])
#: wam_node's command period [s].
PERIOD = 0.002


# ---------------------------------------------------------------------- interfaces
def test_wam_interfaces_have_barretts_layout():
    """wam_msgs/RTJointPositions and wam_srvs/JointMove field for field as barrett-ros2-pkg's
    (github.com/gaolongsen/WAM-ROS2 at e9056c2: wam_msgs/msg/RTJointPositions.msg,
    wam_srvs/srv/JointMove.srv)."""
    from wam_msgs.msg import RTJointPositions
    from wam_srvs.srv import JointMove

    assert RTJointPositions.get_fields_and_field_types() == {
        "header": "std_msgs/Header",
        "joint_states": "sequence<double>",
        "rate_limits": "sequence<double>",
    }
    assert JointMove.Request.get_fields_and_field_types() == {
        "joint_state": "sensor_msgs/JointState"
    }
    assert JointMove.Response.get_fields_and_field_types() == {"response": "boolean"}


# ---------------------------------------------------------------------- the emulation, no ROS
@pytest.fixture
def robot():
    from rrg_fake_hw.emulated_robot import EmulatedRobot

    r = EmulatedRobot("box", seed=0, sensor_noise=0.0)
    r.reset("box", BOX_POSE)
    return r


def stream(robot, q_from, q_to, seconds: float, stamp0: float = 100.0) -> None:
    """Stream a straight line q_from → q_to over ``seconds`` at wam_node's period, stepping the
    world one period per command."""
    n = int(round(seconds / PERIOD))
    for k in range(n + 1):
        robot.rt_joint_positions(q_from + (k / n) * (q_to - q_from), stamp0 + k * PERIOD)
        robot.advance(PERIOD)


@pytest.mark.slow
def test_emulated_stream_tracks_its_commands_and_silence_holds(robot):
    from rrg_fake_hw.emulated_robot import WAM_RT_TIMEOUT

    q0 = robot.snapshot().arm_q
    robot.rt_joint_positions(q0 + STEP)  # the first command only starts tracking, here
    robot.advance(0.1)
    np.testing.assert_allclose(robot.snapshot().arm_q, q0, atol=1e-4)
    stream(robot, q0, q0 + STEP, 1.0)
    s = robot.snapshot()
    np.testing.assert_allclose(s.arm_q, q0 + STEP, atol=2e-3)  # the feed-forward: little lag
    assert s.arm_torque is not None and abs(s.arm_torque[1]) > 5.0  # gravity included
    robot.advance(WAM_RT_TIMEOUT + 0.01)
    assert [e.name for e in robot.events()] == ["rt_stream_started", "rt_timeout"]
    np.testing.assert_allclose(robot.snapshot().arm_q, q0 + STEP, atol=2e-3)


@pytest.mark.slow
def test_emulated_hold_stops_the_arm_and_the_stream_is_ignored_until_its_timeout(robot):
    q0 = robot.snapshot().arm_q
    stream(robot, q0, q0 + STEP, 0.5)  # half of a 1 s move: moving
    assert np.abs(robot.snapshot().arm_qd).max() > 0.1
    robot.hold_joint_position(True)
    q_hold = robot.snapshot().arm_q
    robot.advance(0.3)
    np.testing.assert_allclose(robot.snapshot().arm_q, q_hold, atol=5e-3)
    stream(robot, q_hold, q0, 0.3, stamp0=200.0)  # wam_node is still in its real-time mode
    np.testing.assert_allclose(robot.snapshot().arm_q, q_hold, atol=5e-3)
    names = [e.name for e in robot.events()]
    assert names == ["rt_stream_started", "hold_received", "rt_command_ignored"]
    robot.advance(0.6)  # silence: the mode ends; a new stream is followed again
    stream(robot, robot.snapshot().arm_q, q0, 0.5, stamp0=300.0)
    robot.advance(0.3)  # settled after the stream's abrupt stop
    np.testing.assert_allclose(robot.snapshot().arm_q, q0, atol=2e-3)
    assert [e.name for e in robot.events()][3:] == ["rt_timeout", "rt_stream_started"]


@pytest.mark.slow
def test_emulated_move_to_joint_position_is_libbarretts_trapezoid(robot):
    from rrg_fake_hw.emulated_robot import MOVE_TO_ACCELERATION, MOVE_TO_VELOCITY, GoalState

    q0 = robot.snapshot().arm_q
    goal = robot.move_to_joint_position(q0 + 2 * STEP)
    length = np.linalg.norm(2 * STEP)
    v, a = MOVE_TO_VELOCITY, MOVE_TO_ACCELERATION
    duration = length / v + v / a  # cruising at 0.5 rad/s (the move is long enough)
    robot.advance(duration / 2)
    speed = np.linalg.norm(robot.snapshot().arm_qd)
    assert speed == pytest.approx(v, rel=0.05)
    while robot.goal_status(goal).state is GoalState.ACTIVE:
        robot.advance(PERIOD)
    np.testing.assert_allclose(robot.snapshot().arm_q, q0 + 2 * STEP, atol=3e-3)
    with pytest.raises(ValueError):
        robot.move_to_joint_position(np.zeros(6))


# ---------------------------------------------------------------------- the bridge over ROS
@pytest.fixture(scope="module")
def wam_bridge(tmp_path_factory, ros_domain):
    from diagnostic_msgs.msg import DiagnosticStatus
    from rcl_interfaces.srv import SetParameters
    from rclpy.action import ActionClient
    from ros_testing import RosClient, node_processes, ros_env
    from sensor_msgs.msg import JointState
    from std_srvs.srv import SetBool
    from wam_msgs.msg import RTJointPositions

    from rrg_common.ros.msg_conversions import planar_to_msg
    from rrg_msgs.action import GuardedMove
    from rrg_msgs.srv import ResetSim

    env = ros_env(ros_domain)
    port = free_udp_port(HOSTS)
    fake = {
        "object_name": "box",
        "sensor_noise": 0.0,
        "rdt_port": port,
        "arm_interface": "wam_node",
    }
    # wam_node has no velocities: the external torque estimated from its efforts lags in
    # acceleration (docs/hardware.md), so the effort guard is off, as advised there. The
    # watchdog (tested on its own elsewhere) is relaxed, so that a loaded
    # test machine does not stop these moves on stale data.
    bridge = {
        "rdt_port": port,
        "arm_backend": "wam_node",
        "netft_http_port": 0,  # the emulated boxes serve no netftapi2.xml here
        "effort_threshold": 0.0,
        "watchdog_timeout": 0.5,
    }
    logs = tmp_path_factory.mktemp("logs")
    bridge.update(arm_on_start="true", estop_latch_file=str(logs / "estop.latched"))
    with node_processes(
        [("rrg_fake_hw.fake_hw_node", fake), ("rrg_hw_bridge.ros.bridge_node", bridge)],
        env,
        logs,
    ) as procs:
        client = RosClient(env)
        n = client.node
        c = {
            "reset": n.create_client(ResetSim, "/rrg/reset_sim"),
            "params": n.create_client(SetParameters, "/fake_hw/set_parameters"),
            "hold": n.create_client(SetBool, "/wam/holdJointPosition"),
        }
        client.wait_for_services(c.values(), procs, timeout_s=60.0)
        c["move"] = ActionClient(n, GuardedMove, "/rrg/guarded_move")
        assert c["move"].wait_for_server(timeout_sec=30.0)
        seen: dict[str, list] = {"joints": [], "rt": [], "events": [], "status": []}

        def keep(key: str, limit: int):
            def store(msg) -> None:
                seen[key].append((time.monotonic(), msg))
                del seen[key][:-limit]

            return store

        n.create_subscription(JointState, "/joint_states", keep("joints", 5000), 100)
        n.create_subscription(RTJointPositions, "/wam/RTJointPositionCMD", keep("rt", 5000), 1000)
        n.create_subscription(DiagnosticStatus, "/fake_hw/events", keep("events", 1000), 100)
        n.create_subscription(DiagnosticStatus, "/rrg/bridge/status", keep("status", 10), 10)
        reset = ResetSim.Request(object_name="box", pose=planar_to_msg(BOX_POSE))
        assert client.call(c["reset"], reset).error_code == 0
        ready = lambda: seen["status"] and seen["status"][-1][1].message == "ready"
        assert client.spin_until(ready, 30.0), seen["status"][-1:]
        yield client, c, seen
        client.close()


def guarded_move(q: np.ndarray, t: np.ndarray, stop_on_contact: bool = False):
    from builtin_interfaces.msg import Duration
    from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

    from rrg_msgs.action import GuardedMove

    points = [
        JointTrajectoryPoint(
            positions=qk.tolist(),
            time_from_start=Duration(sec=int(tk), nanosec=int(round((tk % 1.0) * 1e9))),
        )
        for qk, tk in zip(q, t)
    ]
    return GuardedMove.Goal(
        trajectory=JointTrajectory(joint_names=list(ARM_JOINT_NAMES), points=points),
        stop_on_contact=stop_on_contact,
        tip_force_threshold=0.5,  # N
    )


def run(client, c, goal, during=None, timeout_s: float = 20.0):
    """Send a guarded move, call ``during(client)`` while it runs, and return its result."""
    handle = client.result(c["move"].send_goal_async(goal))
    assert handle.accepted
    answer = handle.get_result_async()
    if during is not None:
        during(client)
    return client.result(answer, timeout_s).result


def measured(seen, since: float = -np.inf) -> tuple[np.ndarray, np.ndarray]:
    """(times (N,) [s, time.monotonic()], arm positions (N,7) [rad]) of wam_node's /joint_states
    received after ``since``."""
    rows = [(t, m) for t, m in seen["joints"] if t > since]
    index = [list(rows[0][1].name).index(n) for n in WAM_JOINTS]
    return (
        np.array([t for t, _ in rows]),
        np.array([np.asarray(m.position)[index] for _, m in rows]),
    )


def settle(client, seconds: float) -> None:
    end = time.monotonic() + seconds
    client.spin_until(lambda: time.monotonic() > end, seconds + 1.0)


def events(seen, since: float = -np.inf) -> list[tuple[str, float]]:
    """The fake's events (name, time.monotonic() of the event) after ``since``."""
    out = []
    for _, e in seen["events"]:
        at = float({v.key: v.value for v in e.values}["time"])
        if at > since:
            out.append((e.name, at))
    return out


def polyline(t: np.ndarray, q: np.ndarray, s: float) -> np.ndarray:
    return np.array([np.interp(s, t, q[:, j]) for j in range(7)])


def set_fault(client, c, name: str, value) -> None:
    from rcl_interfaces.srv import SetParameters
    from rclpy.parameter import Parameter

    req = SetParameters.Request(parameters=[Parameter(name, value=value).to_parameter_msg()])
    assert client.call(c["params"], req).results[0].successful


@pytest.mark.slow
def test_a_guarded_move_is_streamed_along_its_via_points_and_ends_where_commanded(wam_bridge):
    from rrg_msgs.action import GuardedMove

    client, c, seen = wam_bridge
    settle(client, 0.1)
    _, q_arm = measured(seen)
    q0 = q_arm[-1]
    np.testing.assert_allclose(q0, wam.HOME_Q, atol=2e-3)
    q = q0 + np.outer([0.4, 0.7, 1.0], STEP)
    t = np.array([0.6, 1.2, 1.8])
    start = time.monotonic()
    result = run(client, c, guarded_move(q, t))
    assert result.error_code == GuardedMove.Result.NONE, result.error_msg
    assert not result.stopped_on_contact
    assert result.path_fraction == pytest.approx(1.0, abs=0.02)
    final = np.array(result.final_joint_state.position[:7])
    assert list(result.final_joint_state.name[:7]) == list(ARM_JOINT_NAMES)
    np.testing.assert_allclose(final, q[-1], atol=5e-3)
    settle(client, 0.2)  # every message taken

    # The stream: command k is the via-point polyline from the measured start at k periods (a
    # late one delays the rest), sent at wam_node's period, then the last point until the arm
    # had stopped.
    rt = [(at, m) for at, m in seen["rt"] if at > start]
    stamps = [m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec for _, m in rt]
    commands = np.array([m.joint_states for _, m in rt])
    np.testing.assert_allclose(commands[0], q0, atol=2e-3)
    path_t, path_q = np.r_[0.0, t], np.vstack([commands[0], q])
    expected = np.array([polyline(path_t, path_q, k * PERIOD) for k in range(len(commands))])
    np.testing.assert_allclose(commands, expected, atol=1e-9)
    assert len(commands) > t[-1] / PERIOD
    steps = 1e-9 * np.diff(stamps)  # [s], exact in ns
    assert np.percentile(steps, 5) > 0.7 * PERIOD  # paced: never a burst
    assert np.median(steps) < 2 * PERIOD  # 500 Hz (an idle machine: median 2.0 ms)
    # The measured arm passed the via-points and stopped at the last one.
    _, arm = measured(seen, start)
    for qk in q:
        assert np.abs(arm - qk).max(axis=1).min() < 0.01
    np.testing.assert_allclose(measured(seen)[1][-1], q[-1], atol=3e-3)
    names = [name for name, _ in events(seen, start)]
    assert "rt_stream_started" in names and "hold_received" in names  # held before streaming
    assert not {"rt_command_ignored", "release_received"} & set(names)


@pytest.mark.slow
def test_a_contact_stops_the_stream_holds_at_once_and_reports_the_measured_pose(wam_bridge):
    from rrg_msgs.action import GuardedMove

    client, c, seen = wam_bridge
    settle(client, 0.1)
    q0 = measured(seen)[1][-1]
    index = [list(seen["joints"][-1][1].name).index(n) for n in WAM_JOINTS]
    goal_q = q0 - 1.5 * STEP
    start = time.monotonic()
    marks = {}

    def touch(client) -> None:
        away = lambda: np.abs(np.asarray(seen["joints"][-1][1].position)[index] - q0).max() > 0.05
        assert client.spin_until(away, 5.0)  # moving (at ~ 0.2 rad/s)
        marks["touch"] = time.monotonic()
        set_fault(client, c, "fault.extra_force", 2.0)  # N, fingertip 1

    try:
        result = run(client, c, guarded_move(goal_q[None], np.array([1.5]), True), touch)
        settle(client, 0.3)
    finally:
        set_fault(client, c, "fault.extra_force", 0.0)
    assert result.error_code == GuardedMove.Result.NONE, result.error_msg
    assert result.stopped_on_contact and any(result.sensors)
    assert 0.1 < result.path_fraction < 0.8

    held = [at for name, at in events(seen, start) if name == "hold_received"]
    assert held and marks["touch"] < held[-1] < marks["touch"] + 0.3
    # The stream stopped and the hold followed at once (wam_node's own comes 0.5 s later): the
    # last command's stamp (the bridge's system time when sending it) on the monotonic clock.
    last = seen["rt"][-1][1].header.stamp
    last_sent = last.sec + 1e-9 * last.nanosec - (time.time() - time.monotonic())
    assert held[-1] - 0.1 < last_sent < held[-1] + 0.005
    timeouts = [at for name, at in events(seen, held[-1]) if name == "rt_timeout"]
    assert all(at > held[-1] + 0.4 for at in timeouts)  # the hold, not wam_node's timeout

    # The measured arm stopped within ~0.1 s of the hold (unstopped, it would have gone on by
    # 0.02 rad in that time at its planned speed), away from both ends, and the result reports
    # where it is.
    times, arm = measured(seen, start)
    rest = arm[-1]
    after = arm[times > held[-1] + 0.1]
    assert len(after) > 50 and np.abs(after - rest).max() < 0.01
    moved = np.abs(arm[times < held[-1]][-1] - arm[times < held[-1]][0]).max()
    assert moved > 0.05  # it was moving when it touched
    assert np.abs(rest - q0).max() > 0.05 and np.abs(rest - goal_q).max() > 0.05
    final = np.array(result.final_joint_state.position[:7])
    np.testing.assert_allclose(final, rest, atol=2e-3)


@pytest.mark.slow
def test_after_a_hold_the_next_move_waits_out_wam_nodes_real_time_mode(wam_bridge):
    """holdJointPosition leaves wam_node in its real-time mode, whose commands would then be
    ignored until 0.5 s of silence: a move right after a canceled one starts streaming only
    after that, and is followed."""
    from action_msgs.msg import GoalStatus

    from rrg_msgs.action import GuardedMove

    client, c, seen = wam_bridge
    settle(client, 0.1)
    q0 = measured(seen)[1][-1]
    start = time.monotonic()
    handle = client.result(c["move"].send_goal_async(guarded_move((q0 + STEP)[None], [2.0])))
    assert client.spin_until(lambda: any(at > start for at, _ in seen["rt"]), 5.0)
    settle(client, 0.3)
    canceled = time.monotonic()
    client.result(handle.cancel_goal_async())
    answer = client.result(handle.get_result_async(), 10.0)
    assert answer.status == GoalStatus.STATUS_CANCELED
    assert answer.result.error_code == GuardedMove.Result.CANCELED
    last_rt = max(at for at, _ in seen["rt"])
    result = run(client, c, guarded_move(q0[None], np.array([1.0])))
    assert result.error_code == GuardedMove.Result.NONE, result.error_msg
    np.testing.assert_allclose(result.final_joint_state.position[:7], q0, atol=5e-3)
    after = [at for at, _ in seen["rt"] if at > last_rt]
    assert after and after[0] > last_rt + 0.5  # silence: wam_node left its real-time mode
    names = [name for name, _ in events(seen, canceled)]
    assert names.count("rt_stream_started") == 1  # the new stream, after a hold and the timeout
    started = names.index("rt_stream_started")
    assert "hold_received" in names[:started] and "rt_timeout" in names[:started]
    assert "rt_command_ignored" not in names[started:]


@pytest.mark.slow
def test_a_refused_trajectory_streams_nothing(wam_bridge):
    from rrg_msgs.action import GuardedMove

    client, c, seen = wam_bridge
    settle(client, 0.7)  # the previous stream's real-time mode has ended
    q0 = measured(seen)[1][-1]
    beyond = q0.copy()
    beyond[0] = 3.0  # rad, past J1's 2.6 rad limit
    start = time.monotonic()
    result = run(client, c, guarded_move(beyond[None], np.array([3.0])))
    assert result.error_code == GuardedMove.Result.JOINT_LIMITS, result.error_msg
    settle(client, 0.3)
    assert not [at for at, _ in seen["rt"] if at > start]
    assert not events(seen, start)  # no hold, no move, nothing
    np.testing.assert_allclose(measured(seen)[1][-1], q0, atol=1e-3)
