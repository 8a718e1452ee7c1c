"""The hardware bridge against the emulated drivers, over ROS: every safety check fires (joint
position and velocity limits and the workspace box before anything is sent, the watchdog on
wrench silence, the latched E-stop, the force ceiling, dry run, Net F/T status errors and
sequence gaps, the measured joint-limit fault), a guarded move stops on contact with the stop
pose measured, the hand closes finger by finger (also with a stuck finger), and one robust
grasp runs end to end through ``rrg-launch --mode hw --fake-hw`` into a bag both readers decode.

One fake_hw node and one bridge (retime off, so an over-fast trajectory is refused rather than
slowed) serve the whole module; before every test the faults are cleared, the E-stop released
and the world reset (arm home, hand open, the box out of the hand's reach). Latencies use the
fake's event times, ``time.monotonic()`` stamps comparable across processes on this machine.
"""

from __future__ import annotations

import time
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
from action_msgs.msg import GoalStatus
from builtin_interfaces.msg import Duration
from diagnostic_msgs.msg import DiagnosticStatus
from rcl_interfaces.srv import SetParameters
from rclpy.action import ActionClient
from rclpy.parameter import Parameter
from ros_testing import ROOT, RosClient, ros_env, start_node, stop_process
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool
from std_srvs.srv import Trigger
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from rrg_hw_bridge.fake.fake_hw_node import FAULTS
from rrg_msgs.action import GuardedMove
from rrg_msgs.srv import HandCommand, ResetSim
from rrg_planner.bringup.graph import rdt_addresses
from rrg_sim import wam
from rrg_sim.config import HAND, SENSING
from rrg_sim.ros_common.msg_conversions import (
    ARM_JOINT_NAMES,
    PROXIMAL_JOINT_NAMES,
    planar_to_msg,
)

pytestmark = pytest.mark.slow  # node processes, MuJoCo in real time

R = GuardedMove.Result
H = HandCommand.Response
Q = HandCommand.Request
FAKE = "rrg_hw_bridge.fake.fake_hw_node"
BRIDGE = "rrg_hw_bridge.ros.bridge_node"
NODE_MODULES = ROOT / ".cache" / "npm" / "node_modules"
#: The box, far from the hand at home (hand frame origin at (0.45, 0, 0.55) m): the hand closes
#: on nothing, and the small arm moves here never reach it.
BOX_POSE = np.array([0.9, 0.45, 0.0])
#: Joint 1 travel [rad] and duration [s] of the slow move that the stop tests interrupt.
SLOW_TRAVEL, SLOW_TIME = 0.3, 3.0
#: Longest wait [s] for a result, a readiness or a stop.
WAIT = 15.0
#: The bridge's timing bounds: the arm holds within 150 ms of wrench silence, and the E-stop
#: cancels a running move within 50 ms.
SILENCE_HOLD_S = 0.150
ESTOP_CANCEL_S = 0.050


def fmt_list(values) -> str:
    return f"[{','.join(repr(v) for v in values)}]"


class Rig:
    """The fake_hw node and the bridge as processes in one domain, and a test node driving the
    bridge's upward interface and the fake's fault parameters."""

    def __init__(self, env: dict, domain_id: int, log_dir: Path):
        self.env, self.log_dir = env, log_dir
        hosts = fmt_list(rdt_addresses(domain_id))
        self.fake_params = {"object_name": "box", "seed": 0, "rdt_hosts": hosts}
        self.bridge_params = {"rdt_hosts": hosts, "retime": "false"}
        self.procs: dict[str, object] = {}
        self.bridge_runs = 0
        self.client = RosClient(env, "hw_bridge_test")
        try:
            self._connect()
        except BaseException:
            self.close()
            raise

    def _connect(self) -> None:
        self.procs["fake"] = start_node(
            FAKE, self.env, self.log_dir / "fake_hw.log", self.fake_params
        )
        n = self.client.node
        self.move = ActionClient(n, GuardedMove, "/rrg/guarded_move")
        self.hand = n.create_client(HandCommand, "/rrg/hand_command")
        self.reset_estop = n.create_client(Trigger, "/rrg/bridge/reset_estop")
        self.params = n.create_client(SetParameters, "/fake_hw/set_parameters")
        self.reset_sim = n.create_client(ResetSim, "/rrg/reset_sim")
        self.estop_pub = n.create_publisher(Bool, "/rrg/estop", 10)
        self.seen: dict[str, list] = {k: [] for k in ("events", "safety", "plan", "status", "js")}

        def keep(key: str, limit: int = 2000):
            def store(msg) -> None:
                self.seen[key].append((time.monotonic(), msg))
                del self.seen[key][:-limit]

            return store

        n.create_subscription(DiagnosticStatus, "/fake_hw/events", keep("events"), 100)
        n.create_subscription(DiagnosticStatus, "/rrg/bridge/safety", keep("safety"), 100)
        n.create_subscription(JointTrajectory, "/rrg/bridge/plan", keep("plan"), 10)
        n.create_subscription(DiagnosticStatus, "/rrg/bridge/status", keep("status"), 10)
        n.create_subscription(JointState, "/rrg/joint_states", keep("js", 200), 10)
        self.start_bridge()
        assert self.client.spin_until(lambda: self.estop_pub.get_subscription_count() > 0, WAIT)

    # ------------------------------------------------------------------ processes
    def start_bridge(self, **extra: str) -> None:
        """Start the bridge (with ``extra`` parameters) and wait until it is ready."""
        self.bridge_runs += 1
        log = self.log_dir / f"hw_bridge_{self.bridge_runs}.log"
        self.procs["bridge"] = start_node(BRIDGE, self.env, log, {**self.bridge_params, **extra})
        procs = list(self.procs.values())
        services = [self.hand, self.reset_estop, self.params, self.reset_sim]
        self.client.wait_for_services(services, procs, timeout_s=60.0)
        assert self.move.wait_for_server(timeout_sec=30.0)
        self.wait_ready(60.0, dry_run=str(extra.get("dry_run", "false")).capitalize())

    def stop_bridge(self) -> None:
        stop_process(self.procs.pop("bridge"))

    @contextmanager
    def bridge_with(self, **extra: str):
        """The bridge restarted with ``extra`` parameters for the block, then as before."""
        self.stop_bridge()
        self.start_bridge(**extra)
        try:
            yield
        finally:
            self.stop_bridge()
            self.start_bridge()

    def close(self) -> list[str]:
        """Stop everything (also after a failed start); returns the log files that contain a
        Python traceback."""
        for name in ("bridge", "fake"):
            if name in self.procs:
                stop_process(self.procs.pop(name))
        self.client.close()
        return [p.name for p in self.log_dir.glob("*.log") if "Traceback" in p.read_text()]

    # ------------------------------------------------------------------ waiting
    def spin(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        self.client.spin_until(lambda: time.monotonic() > end, seconds + 1.0)

    def wait_ready(self, timeout_s: float = WAIT, dry_run: str | None = None) -> None:
        """Until a bridge/status published from now on says ready (no E-stop, fresh data, no
        sensor or joint-limit fault), from a bridge with dry_run ``dry_run`` when given."""
        since = time.monotonic()

        def ready() -> bool:
            for t, msg in reversed(self.seen["status"]):
                if t < since:
                    return False
                values = {v.key: v.value for v in msg.values}
                if dry_run is not None and values.get("dry_run") != dry_run:
                    continue
                return msg.level == DiagnosticStatus.OK
            return False

        last = lambda: self.seen["status"][-1][1].message if self.seen["status"] else "none"
        assert self.client.spin_until(ready, timeout_s), f"bridge not ready: {last()}"

    def events(self, name: str, since: float) -> list[float]:
        """Times (time.monotonic() [s], the fake's clock) of the fake's ``name`` events at or
        after ``since``."""
        times = []
        for _, e in self.seen["events"]:
            t = float({v.key: v.value for v in e.values}["time"])
            if e.name == name and t >= since:
                times.append(t)
        return times

    def wait_event(self, name: str, since: float, timeout_s: float = WAIT) -> float:
        assert self.client.spin_until(lambda: self.events(name, since), timeout_s), name
        return self.events(name, since)[0]

    def safety(self, since: float) -> list[DiagnosticStatus]:
        return [m for t, m in self.seen["safety"] if t >= since]

    # ------------------------------------------------------------------ arm
    def joints(self, fresh_after: float | None = None) -> JointState:
        """The newest /rrg/joint_states message (received after ``fresh_after`` if given)."""
        after = time.monotonic() if fresh_after is None else fresh_after
        js = self.seen["js"]
        assert self.client.spin_until(lambda: js and js[-1][0] > after, WAIT)
        return js[-1][1]

    def arm_q(self, fresh_after: float | None = None) -> np.ndarray:
        js = self.joints(fresh_after)
        return np.array([js.position[js.name.index(n)] for n in ARM_JOINT_NAMES])

    def send(self, goal: GuardedMove.Goal):
        handle = self.client.result(self.move.send_goal_async(goal))
        assert handle.accepted  # the bridge refuses in its result, with the check's code
        return handle

    def result(self, handle, timeout_s: float = WAIT):
        """(status, GuardedMove.Result) of a sent goal."""
        answer = self.client.result(handle.get_result_async(), timeout_s)
        return answer.status, answer.result

    def run(self, goal: GuardedMove.Goal, timeout_s: float = WAIT):
        return self.result(self.send(goal), timeout_s)

    def started(self, goal: GuardedMove.Goal):
        """Send a goal, wait until the fake's controller runs it and 0.3 s more (the arm is on
        its way); returns the handle."""
        since = time.monotonic()
        handle = self.send(goal)
        self.wait_event("goal_accepted", since)
        self.spin(0.3)
        return handle

    # ------------------------------------------------------------------ faults and E-stop
    def set_fault(self, name: str, value) -> None:
        req = SetParameters.Request(parameters=[Parameter(name, value=value).to_parameter_msg()])
        result = self.client.call(self.params, req).results[0]
        assert result.successful, result.reason

    def estop(self, engaged: bool) -> float:
        """Publish on the E-stop topic; returns the publish time [s, monotonic]."""
        t = time.monotonic()
        self.estop_pub.publish(Bool(data=engaged))
        return t

    def reset(self) -> None:
        """Faults off, E-stop released, world reset (arm home, hand open, box away), ready."""
        for name, fault in FAULTS.items():
            self.set_fault(name, fault.default)
        self.estop(False)
        assert self.client.spin_until(
            lambda: self.client.call(self.reset_estop, Trigger.Request()).success, WAIT
        )
        req = ResetSim.Request(object_name="box", pose=planar_to_msg(BOX_POSE))
        assert self.client.call(self.reset_sim, req).error_code == ResetSim.Response.NONE
        self.wait_ready()
        for stored in self.seen.values():
            stored.clear()

    # ------------------------------------------------------------------ hand
    def hand_command(self, mode: int, spread: float = 0.0) -> HandCommand.Response:
        return self.client.call(self.hand, HandCommand.Request(mode=mode, spread=spread), WAIT)


def duration(seconds: float) -> Duration:
    sec = int(np.floor(seconds))
    return Duration(sec=sec, nanosec=int(round((seconds - sec) * 1e9)))


def goal(points: list[tuple[np.ndarray, float]], stop_on_contact: bool = False) -> GuardedMove.Goal:
    """A guarded-move goal through joint via-points (q (7,) [rad], time_from_start [s])."""
    return GuardedMove.Goal(
        trajectory=JointTrajectory(
            joint_names=list(ARM_JOINT_NAMES),
            points=[
                JointTrajectoryPoint(
                    positions=np.asarray(q, float).tolist(), time_from_start=duration(t)
                )
                for q, t in points
            ],
        ),
        stop_on_contact=stop_on_contact,
    )


def joint_move(q0: np.ndarray, joint: int, travel: float, seconds: float) -> GuardedMove.Goal:
    """From q0, move one joint by ``travel`` [rad] in ``seconds``."""
    q = np.array(q0, dtype=float)
    q[joint] += travel
    return goal([(q, seconds)])


def slow_move(rig: Rig, stop_on_contact: bool = False) -> GuardedMove.Goal:
    """Joint 1 by SLOW_TRAVEL in SLOW_TIME from the measured configuration."""
    g = joint_move(rig.arm_q(), 0, SLOW_TRAVEL, SLOW_TIME)
    g.stop_on_contact = stop_on_contact
    return g


def short_move(rig: Rig) -> GuardedMove.Goal:
    """A small valid move that the arm finishes in 0.5 s."""
    return joint_move(rig.arm_q(), 3, -0.05, 0.5)


def assert_refused(
    rig: Rig, g: GuardedMove.Goal, code: int, reported: bool = True
) -> GuardedMove.Result:
    """The goal is refused with ``code`` (reported on bridge/safety when ``reported``) and
    nothing reaches the fake's controller."""
    since = time.monotonic()
    status, res = rig.run(g)
    assert status == GoalStatus.STATUS_ABORTED
    assert res.error_code == code, res.error_msg
    assert res.error_msg
    if reported:
        reports = lambda: [m for m in rig.safety(since) if m.values[0].value == str(code)]
        assert rig.client.spin_until(reports, 5.0), f"no bridge/safety report of code {code}"
        assert "refused" in reports()[0].message
    rig.spin(0.2)
    assert not rig.events("goal_accepted", since), "a goal reached the fake's controller"
    return res


def assert_runs(rig: Rig) -> None:
    """A valid goal runs to its end."""
    status, res = rig.run(short_move(rig))
    assert status == GoalStatus.STATUS_SUCCEEDED and res.error_code == R.NONE, res.error_msg
    assert res.path_fraction == pytest.approx(1.0, abs=0.02)


def assert_stopped(rig: Rig, handle, code: int, since: float) -> float:
    """The running goal ends with ``code``, the fake's controller got a cancel after ``since``
    and the arm holds; returns the cancel's time [s, monotonic]."""
    status, res = rig.result(handle)
    assert status == GoalStatus.STATUS_ABORTED and res.error_code == code, res.error_msg
    cancel = rig.wait_event("cancel_received", since)
    q = rig.arm_q()
    rig.spin(0.3)
    np.testing.assert_allclose(rig.arm_q(), q, atol=5e-3)  # holding
    assert 0.0 < res.path_fraction < 1.0
    return cancel


@pytest.fixture(scope="module")
def rig(tmp_path_factory, ros_domain):
    log_dir = tmp_path_factory.mktemp("hw_bridge_logs")
    r = Rig(ros_env(ros_domain), ros_domain, log_dir)
    try:
        yield r
    finally:
        tracebacks = r.close()
    assert not tracebacks, f"tracebacks in {tracebacks} ({log_dir})"


@pytest.fixture
def hw(rig):
    rig.reset()
    yield rig


# ---------------------------------------------------------------------- before anything is sent
def test_out_of_limit_trajectories_are_refused_before_anything_is_sent(hw):
    q0 = hw.arm_q()
    past = q0.copy()
    past[0] = 2.7  # J1's limit is 2.6 rad
    res = assert_refused(hw, goal([((q0 + past) / 2, 4.0), (past, 8.0)]), R.JOINT_LIMITS)
    assert "wam_j1_joint" in res.error_msg and "via-point 2" in res.error_msg
    # 0.3 rad in 0.1 s: 3 rad/s against 1.5 rad/s (retime is off)
    res = assert_refused(hw, joint_move(q0, 0, 0.3, 0.1), R.JOINT_VELOCITY_LIMIT)
    assert "wam_j1_joint" in res.error_msg
    assert_runs(hw)


def test_a_waypoint_outside_the_workspace_box_is_refused(hw):
    q0 = hw.arm_q()
    low = q0.copy()
    low[1] += 1.1  # shoulder forward: the hand frame origin 0.04 m above the table
    assert wam.fk(low)[2, 3] < 0.06
    res = assert_refused(hw, goal([(low, 6.0), (q0, 12.0)]), R.WORKSPACE)
    assert "via-point 1" in res.error_msg and "hand frame origin" in res.error_msg


# ---------------------------------------------------------------------- stops while moving
def test_wrench_silence_holds_the_arm_and_refuses_goals_until_the_data_returns(hw):
    handle = hw.started(slow_move(hw))
    silenced = time.monotonic()
    hw.set_fault("fault.silent_box", 3)  # every box
    cancel = assert_stopped(hw, handle, R.STALE_DATA, silenced)
    hold = cancel - silenced
    print(f"hold {hold * 1e3:.1f} ms after the silence")
    assert hold < SILENCE_HOLD_S
    res = assert_refused(hw, short_move(hw), R.STALE_DATA)
    assert "fingertip" in res.error_msg
    hw.set_fault("fault.silent_box", -1)
    hw.wait_ready()
    assert_runs(hw)


def test_the_estop_cancels_a_running_move_and_holds_until_reset(hw):
    handle = hw.started(slow_move(hw))
    pressed = hw.estop(True)
    cancel = assert_stopped(hw, handle, R.ESTOP, pressed)
    latency = cancel - pressed
    print(f"E-stop cancel {latency * 1e3:.1f} ms after the publish")
    assert latency < ESTOP_CANCEL_S
    assert_refused(hw, short_move(hw), R.ESTOP)
    answer = hw.client.call(hw.reset_estop, Trigger.Request())
    assert not answer.success and "still says engaged" in answer.message
    assert_refused(hw, short_move(hw), R.ESTOP)  # the latch holds
    hw.estop(False)
    reset = lambda: hw.client.call(hw.reset_estop, Trigger.Request())
    assert hw.client.spin_until(lambda: reset().success, 5.0)
    assert_runs(hw)


def test_the_force_ceiling_aborts_a_move(hw):
    handle = hw.started(slow_move(hw))
    since = time.monotonic()
    hw.set_fault("fault.extra_force", 25.0)  # N on fingertip 1; the ceiling is 20 N
    assert_stopped(hw, handle, R.FORCE_LIMIT, since)
    assert any("fingertip 1" in m.message for m in hw.safety(since))


def test_status_word_errors_and_sequence_gaps_are_reported_and_stop_the_arm(hw):
    for fault, value, kind in (
        ("fault.status_word", 0x20000, "status"),
        ("fault.drop_probability", 0.3, "gap"),
    ):
        handle = hw.started(slow_move(hw))
        since = time.monotonic()
        hw.set_fault(fault, value)
        assert_stopped(hw, handle, R.SENSOR_FAULT, since)
        reports = [m for m in hw.safety(since) if m.values[0].value == str(R.SENSOR_FAULT)]
        assert reports and kind in reports[0].message and "Net F/T" in reports[0].message
        assert_refused(hw, short_move(hw), R.SENSOR_FAULT)
        hw.set_fault(fault, FAULTS[fault].default)
        hw.wait_ready()
        assert_runs(hw)


def test_a_measured_joint_past_its_limit_stops_the_arm_and_refuses_goals(hw):
    handle = hw.started(slow_move(hw))
    since = time.monotonic()
    hw.set_fault("fault.joint_limit", True)  # J4 reads 0.2 rad past its upper limit
    assert_stopped(hw, handle, R.JOINT_LIMITS, since)
    res = assert_refused(hw, short_move(hw), R.JOINT_LIMITS)
    assert "joint 4" in res.error_msg
    hw.set_fault("fault.joint_limit", False)
    hw.wait_ready()
    assert_runs(hw)


def test_a_guarded_move_stops_on_contact_at_the_measured_pose(hw):
    g = slow_move(hw, stop_on_contact=True)
    target = np.array(g.trajectory.points[-1].positions)
    handle = hw.started(g)
    since = time.monotonic()
    hw.set_fault("fault.extra_force", SENSING.tip_force_threshold + 0.2)  # N on fingertip 1
    status, res = hw.result(handle)
    assert status == GoalStatus.STATUS_SUCCEEDED and res.error_code == R.NONE, res.error_msg
    assert res.stopped_on_contact
    assert res.sensors[7] and not any(res.sensors[8:])  # tip 1 only
    assert 0.05 < res.path_fraction < 0.9
    hw.wait_event("cancel_received", since)
    final = res.final_joint_state
    q_final = np.array([final.position[final.name.index(n)] for n in ARM_JOINT_NAMES])
    np.testing.assert_allclose(q_final, hw.arm_q(), atol=5e-3)  # where the arm is measured
    assert np.abs(q_final - target).max() > 0.03  # not the commanded end


# ---------------------------------------------------------------------- dry run
def test_dry_run_publishes_the_plan_and_commands_nothing(hw):
    with hw.bridge_with(dry_run="true"):
        hw.seen["plan"].clear()
        q0 = hw.arm_q()
        g = goal([(q0 + 0.05, 1.0), (q0 + 0.1, 2.0)])
        res = assert_refused(hw, g, R.DRY_RUN, reported=False)
        assert "dry run" in res.error_msg
        assert hw.client.spin_until(lambda: hw.seen["plan"], 5.0)
        plan = hw.seen["plan"][-1][1]
        assert len(plan.points) == 2
        np.testing.assert_allclose(plan.points[-1].positions, q0 + 0.1, atol=1e-9)
        assert plan.points[-1].time_from_start.sec == 2
        answer = hw.hand_command(Q.MODE_CLOSE)
        assert answer.error_code == H.REFUSED and "dry run" in answer.error_msg
        hw.spin(0.3)
        assert not hw.events("goal_accepted", 0.0)


# ---------------------------------------------------------------------- hand
def proximal(answer: HandCommand.Response) -> np.ndarray:
    js = answer.joint_state
    return np.array([js.position[js.name.index(n)] for n in PROXIMAL_JOINT_NAMES])


def test_closing_the_hand_stops_each_finger_and_a_stuck_finger_does_not_hang_it(hw):
    limit = HAND.proximal_range[1]
    answer = hw.hand_command(Q.MODE_CLOSE)
    assert answer.error_code == H.NONE, answer.error_msg
    np.testing.assert_allclose(proximal(answer), limit, atol=0.15)  # closed on nothing
    assert not any(answer.touched)
    answer = hw.hand_command(Q.MODE_OPEN)
    assert answer.error_code == H.NONE, answer.error_msg
    np.testing.assert_allclose(proximal(answer), 0.0, atol=0.05)

    hw.set_fault("fault.stuck_finger", 1)  # finger 2
    answer = hw.hand_command(Q.MODE_CLOSE)
    assert answer.error_code == H.NONE, answer.error_msg
    q = proximal(answer)
    assert q[1] == pytest.approx(0.0, abs=0.05)
    np.testing.assert_allclose(q[[0, 2]], limit, atol=0.15)
