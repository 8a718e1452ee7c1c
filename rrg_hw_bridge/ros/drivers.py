"""Clients of the real drivers below the bridge, one class per backend: the arm's
FollowJointTrajectory controller or Barrett's wam_node, Barrett's BarrettHand services, and the
fingertip sensors (the built-in Net F/T RDT client, or WrenchStamped topics of an existing
driver).

Every class is used from inside callbacks of a MultiThreadedExecutor (reentrant callback
group) and never blocks longer than its timeout.
"""

from __future__ import annotations

import itertools
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from action_msgs.msg import GoalStatus
from bhand_srvs.srv import FingerPosition, FingerVelocity, SpreadPosition
from builtin_interfaces.msg import Duration
from control_msgs.action import FollowJointTrajectory
from geometry_msgs.msg import WrenchStamped
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from rclpy.task import Future
from std_srvs.srv import SetBool, Trigger
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint
from wam_msgs.msg import RTJointPositions

from rrg_common.ros.futures import ThreadSafeActionClient, WaitTimeout, wait_for

from ..bridge_core import BridgeCore
from ..driver_api import DriverError, Gate, Latched, open_gate
from ..rdt import (
    CONFIG_PAGE,
    BoxConfig,
    Calibration,
    RdtClient,
    RdtSample,
    read_box_config,
    set_box_rdt_rate,
)

#: A box's netftapi2.xml request times out after this long [s], and an unread page is asked
#: for again this often [s] (chosen: a box on the lab network answers within milliseconds).
CONFIG_TIMEOUT_S = 1.0
CONFIG_RETRY_S = 2.0

#: Longest wait [s] for a driver's answer to one request (a goal, a cancel, a service call).
DRIVER_TIMEOUT = 2.0


def answer(future: Future, service: str):
    """The response of a service call, waiting at most DRIVER_TIMEOUT; DriverError when the
    driver does not answer."""
    try:
        return wait_for(future, DRIVER_TIMEOUT)
    except WaitTimeout as exc:
        raise DriverError(f"{service}: no answer") from exc


def duration(seconds: float) -> Duration:
    sec = int(np.floor(seconds))
    return Duration(sec=sec, nanosec=int(round((seconds - sec) * 1e9)) % 1_000_000_000)


class TrajectoryArm:
    """The arm through ``control_msgs/action/FollowJointTrajectory`` (any ros2_control arm)."""

    def __init__(
        self,
        node: Node,
        action_name: str,
        joint_names: tuple[str, ...],
        group,
        gate: Gate = open_gate,
    ):
        self.joint_names = joint_names
        self.client = ThreadSafeActionClient(
            node, FollowJointTrajectory, action_name, callback_group=group
        )
        self.action_name = action_name
        self.gate = gate

    def ready(self) -> bool:
        return self.client.server_is_ready()

    def goal(self, q: np.ndarray, t: np.ndarray, goal_time_tolerance: float):
        """The FollowJointTrajectory goal of via-points q (K,7) [rad] at times t (K,) [s] > 0."""
        traj = JointTrajectory(
            joint_names=list(self.joint_names),
            points=[
                JointTrajectoryPoint(positions=qk.tolist(), time_from_start=duration(tk))
                for qk, tk in zip(q, t)
            ],
        )
        return FollowJointTrajectory.Goal(
            trajectory=traj, goal_time_tolerance=duration(goal_time_tolerance)
        )

    def send(self, goal):
        """Send a goal through the gate; returns its ClientGoalHandle once accepted (Latched
        when the gate is shut, DriverError when the controller refuses or is silent)."""
        sent, future = self.gate(lambda: self.client.send_goal_async(goal))
        if not sent:
            raise Latched(f"{self.action_name}: the E-stop is latched; the goal was not sent")
        try:
            handle = wait_for(future, DRIVER_TIMEOUT)
        except WaitTimeout as exc:
            raise DriverError(f"{self.action_name}: no answer to the goal") from exc
        if not handle.accepted:
            raise DriverError(f"{self.action_name} rejected the goal")
        return handle

    def hold(self, q: np.ndarray, hold_time: float) -> None:
        """Hold the arm at ``q`` (7,) [rad]: a one-point goal ``hold_time`` [s] ahead, which
        replaces the running goal (JTC preempts by arrival). A stop: no gate, no wait."""
        self.client.send_goal_async(self.goal(np.asarray(q)[None, :], np.array([hold_time]), 1.0))


# ---------------------------------------------------------------------- Barrett's wam_node
#: wam_node's real-time rate [Hz]: its updateRT loop and /joint_states run at 500 Hz
#: (barrett-ros2-pkg wam_node, wam_subscribers.h: kPublishFrequency), libbarrett's 2 ms period.
WAM_COMMAND_RATE = 500.0
#: wam_node holds the arm (moveTo its measured position) when no real-time command arrived for
#: this long [s], and only then leaves its real-time mode (wam_subscribers.h: kRtMsgTimeout,
#: updateRT). A stream that starts after a hold but before that is ignored: holdJointPosition
#: replaces the reference the arm tracks without leaving the real-time mode, whose commands then
#: keep it alive without reaching the arm.
WAM_RT_TIMEOUT = 0.5
#: Margin [s] on WAM_RT_TIMEOUT (chosen: 50 of wam_node's periods, for DDS and executor latency).
WAM_RT_MARGIN = 0.1
#: Largest distance [rad] between the measured arm and the command being streamed; beyond it the
#: stream stops and the arm holds (chosen: twice the lag of a PD that tracks the 1.5 rad/s limit
#: with 0.07 s lag, the model's largest kv/kp; catches a stream that does not reach the arm).
WAM_TRACKING_TOLERANCE = 0.2
#: The arm has stopped when every joint stayed within a range of this speed times the window
#: [rad/s] (chosen: half BRIDGE.settle_speed, for positions rather than velocities) ...
WAM_STILL_SPEED = 0.01
#: ... over this window [s] of measured joint states (chosen: 50 wam_node periods; a shorter one
#: takes the turning point of a joint's swing after a hold for a stop) ...
WAM_STILL_WINDOW = 0.1
#: ... or, after a hold, once this long [s] has passed (chosen: a WAM stops in ~ 0.05 s).
WAM_STOP_TIMEOUT = 0.5


@dataclass
class WamStream:
    """A WamNodeArm goal: via-points q (K,7) [rad] at times t (K,) [s] > 0 after the start (the
    measured configuration is prepended at 0), and the same as a JointTrajectory (the plan)."""

    q: np.ndarray
    t: np.ndarray
    goal_time_tolerance: float
    trajectory: JointTrajectory


@dataclass
class WamStreamResult:
    """What a WamStreamHandle's get_result_async() resolves to, shaped like an action's result:
    status (action_msgs/GoalStatus) and result (FollowJointTrajectory.Result: error_code 0,
    PATH_TOLERANCE_VIOLATED or GOAL_TOLERANCE_VIOLATED, and error_string)."""

    status: int
    result: FollowJointTrajectory.Result


class WamStreamHandle:
    """A stream being sent, used as the bridge uses a ClientGoalHandle: cancel_goal_async() stops
    the stream and holds the arm at once; get_result_async() resolves once the stream has ended
    and the arm has stopped."""

    accepted = True

    def __init__(self, arm: WamNodeArm):
        self._arm = arm
        self._result = Future()
        self.canceled = False
        self.wake = threading.Event()  # set on cancel, once the hold is sent
        self.hold_future: Future | None = None  # the cancel's holdJointPosition call

    def cancel_goal_async(self) -> Future:
        return self._arm._cancel(self)

    def get_result_async(self) -> Future:
        return self._result


def _sample(t: np.ndarray, q: np.ndarray, s: float) -> np.ndarray:
    """The via-point polyline q (K,7) at times t (K,) [s], at time s (held past its end)."""
    i = int(np.clip(np.searchsorted(t, s, side="right") - 1, 0, len(t) - 2))
    a = float(np.clip((s - t[i]) / (t[i + 1] - t[i]), 0.0, 1.0))
    return q[i] + a * (q[i + 1] - q[i])


class _Stillness:
    """Whether the arm has stopped: measured positions (7,) over the last WAM_STILL_WINDOW."""

    def __init__(self):
        self.samples: deque[tuple[float, np.ndarray]] = deque()

    def add(self, now: float, q: np.ndarray) -> bool:
        """Add a measurement; True once every joint stayed within WAM_STILL_SPEED ×
        WAM_STILL_WINDOW over a full window."""
        self.samples.append((now, q))
        while len(self.samples) > 2 and now - self.samples[1][0] >= WAM_STILL_WINDOW:
            self.samples.popleft()
        if now - self.samples[0][0] < WAM_STILL_WINDOW:
            return False
        window = np.array([qk for _, qk in self.samples])
        if not np.all(np.isfinite(window)):
            return False
        return bool(np.ptp(window, axis=0).max() < WAM_STILL_SPEED * WAM_STILL_WINDOW)


class WamNodeArm:
    """The arm through Barrett's own ROS 2 ``wam_node`` (barrett-ros2-pkg), the same interface as
    TrajectoryArm for the bridge: goal(q, t, tolerance) → send(goal) → a handle with
    cancel_goal_async() and get_result_async().

    A goal is streamed on wam_node's real-time joint position topic (wam_msgs/RTJointPositions)
    at WAM_COMMAND_RATE from a thread paced by deadlines: the via-points interpolated linearly in
    time from the measured configuration, one period further per command (a late command delays
    the rest, the reference never jumps), then the last one until the arm has stopped (or the
    goal time tolerance has passed: GOAL_TOLERANCE_VIOLATED). Before a stream the arm is made to
    hold (holdJointPosition true) unless it still tracks the previous stream's end, and after a
    hold the stream waits until wam_node has left its real-time mode (WAM_RT_TIMEOUT). A cancel
    stops the stream and calls holdJointPosition(true) at once, so the arm holds now rather than
    after wam_node's 0.5 s timeout; a command the arm does not follow (WAM_TRACKING_TOLERANCE)
    does the same (PATH_TOLERANCE_VIOLATED). /wam/idle is never called: it releases the arm.

    measured() returns the newest measured arm configuration (7,) [rad], J1-J7 (NaN: none yet).
    """

    def __init__(
        self,
        node: Node,
        joint_names: tuple[str, ...],
        group,
        measured: Callable[[], np.ndarray],
        rt_topic: str = "/wam/RTJointPositionCMD",
        hold_service: str = "/wam/holdJointPosition",
        gate: Gate = open_gate,
    ):
        self.node, self.joint_names, self.measured = node, joint_names, measured
        self.gate = gate  # every streamed command passes it; a shut gate ends the stream
        self.rt_topic, self.hold_service = rt_topic, hold_service
        self.publisher = node.create_publisher(RTJointPositions, rt_topic, 10)
        self.hold_client = node.create_client(SetBool, hold_service, callback_group=group)
        self._lock = threading.Lock()
        self._active: WamStreamHandle | None = None
        self._last_sent = -np.inf  # time.monotonic() of the newest streamed command
        self._tracking = False  # the arm tracks that stream (no hold since)

    def ready(self) -> bool:
        return self.hold_client.service_is_ready() and self.publisher.get_subscription_count() > 0

    def describe(self) -> str:
        return f"wam_node ({self.rt_topic} at {WAM_COMMAND_RATE:.0f} Hz, {self.hold_service})"

    def goal(self, q: np.ndarray, t: np.ndarray, goal_time_tolerance: float) -> WamStream:
        """The stream of via-points q (K,7) [rad] at times t (K,) [s] > 0."""
        q, t = np.asarray(q, dtype=float), np.asarray(t, dtype=float)
        traj = JointTrajectory(
            joint_names=list(self.joint_names),
            points=[
                JointTrajectoryPoint(positions=qk.tolist(), time_from_start=duration(tk))
                for qk, tk in zip(q, t)
            ],
        )
        return WamStream(q, t, float(goal_time_tolerance), traj)

    def send(self, goal: WamStream) -> WamStreamHandle:
        """Start streaming ``goal`` (after making the arm hold); DriverError when the goal is
        malformed, wam_node is not there or the hold is refused."""
        q, t = goal.q, goal.t
        if q.ndim != 2 or q.shape[1] != 7 or len(q) == 0 or t.shape != (len(q),):
            raise DriverError(f"need q (K,7) and t (K,), got {q.shape} and {t.shape}")
        if not (np.all(np.isfinite(q)) and np.all(np.isfinite(t))):
            raise DriverError("non-finite via-points or times")
        if t[0] <= 0.0 or np.any(np.diff(t) <= 0.0):
            raise DriverError("via-point times must be > 0 and increase strictly")
        if self.publisher.get_subscription_count() == 0:
            raise DriverError(f"nothing subscribes to {self.rt_topic}: is wam_node running?")
        with self._lock:
            if self._active is not None:
                raise DriverError("a stream is still running")
            start_after = time.monotonic()
            tracking = self._tracking and start_after - self._last_sent < (
                WAM_RT_TIMEOUT - WAM_RT_MARGIN
            )
        if not tracking:  # the arm may be anywhere: hold first, then wait out the RT mode
            self._hold(wait=True)
            start_after = max(start_after, self._last_sent + WAM_RT_TIMEOUT + WAM_RT_MARGIN)
        handle = WamStreamHandle(self)
        with self._lock:
            self._active = handle
        threading.Thread(
            target=self._stream,
            args=(handle, q, t, goal.goal_time_tolerance, start_after),
            name="wam_stream",
            daemon=True,
        ).start()
        return handle

    def hold(self, q: np.ndarray, hold_time: float) -> None:
        """Hold the arm where it is (holdJointPosition true; ``q`` and ``hold_time`` are
        TrajectoryArm's). A stop: no gate, no wait."""
        self._hold(wait=False)

    def _hold(self, wait: bool) -> Future:
        """holdJointPosition(true); waiting for the answer (DriverError if refused or missing)."""
        with self._lock:
            self._tracking = False
        if wait and not self.hold_client.service_is_ready():
            raise DriverError(f"{self.hold_service} is not available: is wam_node running?")
        future = self.hold_client.call_async(SetBool.Request(data=True))
        if not wait:
            return future
        response = answer(future, self.hold_service)
        if not response.success:
            raise DriverError(f"{self.hold_service} refused: {response.message}")
        return future

    def _cancel(self, handle: WamStreamHandle) -> Future:
        with self._lock:
            if handle.canceled or handle._result.done():
                done = Future()
                done.set_result(None)
                return done
            handle.canceled = True  # checked under the lock before every publish
        handle.hold_future = self._hold(wait=False)
        handle.wake.set()
        return handle.hold_future

    def _stream(self, handle, q, t, tolerance, start_after) -> None:
        try:
            outcome = self._run(handle, q, t, tolerance, start_after)
        except Exception as exc:  # never leave the bridge without an answer
            try:
                self._hold(wait=False)
            except Exception:  # shutting down: wam_node holds after its stream timeout
                pass
            outcome = self._outcome(
                GoalStatus.STATUS_ABORTED,
                FollowJointTrajectory.Result.INVALID_GOAL,
                f"streaming failed: {type(exc).__name__}: {exc}",
            )
        with self._lock:
            self._active = None
        handle._result.set_result(outcome)

    @staticmethod
    def _outcome(status: int, code: int, text: str) -> WamStreamResult:
        return WamStreamResult(
            status, FollowJointTrajectory.Result(error_code=code, error_string=text)
        )

    def _run(self, handle, q, t, tolerance, start_after) -> WamStreamResult:
        R = FollowJointTrajectory.Result
        wait = start_after - time.monotonic()
        if wait > 0.0:
            handle.wake.wait(wait)
        if handle.canceled:
            return self._stopped(handle)
        q0 = np.asarray(self.measured(), dtype=float)
        if not np.all(np.isfinite(q0)):
            self._hold(wait=False)
            return self._outcome(GoalStatus.STATUS_ABORTED, R.INVALID_GOAL, "no measured arm")
        tq, qq = np.r_[0.0, t], np.vstack([q0, q])
        period = 1.0 / WAM_COMMAND_RATE
        msg = RTJointPositions()
        still = _Stillness()
        start, start_ns = time.monotonic(), self.node.get_clock().now().nanoseconds
        deadline, ended = start, None
        # Command k is the polyline at k periods: a late tick delays the rest of the trajectory
        # instead of jumping ahead, so the arm never gets a step (wam_node does not limit the
        # rate of its reference).
        for k in itertools.count():
            if deadline > time.monotonic():
                handle.wake.wait(deadline - time.monotonic())
            now = time.monotonic()
            deadline = max(deadline + period, now + 0.75 * period)  # no burst after a stall
            s = k * period
            command = _sample(tq, qq, s)
            stamp_ns = start_ns + int(round((now - start) * 1e9))
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
            msg.joint_states = command.tolist()
            with self._lock:
                if handle.canceled:
                    break
                sent, _ = self.gate(lambda: self.publisher.publish(msg))
                if not sent:  # latched: the bridge cancels, which sends the hold
                    break
                self._last_sent, self._tracking = time.monotonic(), True
            measured = np.asarray(self.measured(), dtype=float)
            error = np.abs(measured - command)
            if np.nanmax(error) > WAM_TRACKING_TOLERANCE:
                self._hold(wait=False)
                j = int(np.nanargmax(error))
                return self._outcome(
                    GoalStatus.STATUS_ABORTED,
                    R.PATH_TOLERANCE_VIOLATED,
                    f"joint {j + 1} is {error[j]:.3f} rad from the streamed command at "
                    f"{s:.2f} s (over {WAM_TRACKING_TOLERANCE} rad): holding",
                )
            if s >= tq[-1]:
                ended = now if ended is None else ended
                if still.add(now, measured):
                    return self._outcome(GoalStatus.STATUS_SUCCEEDED, R.SUCCESSFUL, "")
                if now - ended > tolerance:
                    self._hold(wait=False)
                    return self._outcome(
                        GoalStatus.STATUS_ABORTED,
                        R.GOAL_TOLERANCE_VIOLATED,
                        f"the arm still moves {tolerance:.2f} s after the trajectory's end: "
                        "holding",
                    )
        return self._stopped(handle)

    def _stopped(self, handle: WamStreamHandle) -> WamStreamResult:
        """After a cancel: wait for the hold's answer and for the arm to stop."""
        R = FollowJointTrajectory.Result
        text = "canceled: holding"
        handle.wake.wait(DRIVER_TIMEOUT)  # the cancel has sent the hold
        try:
            if handle.hold_future is None:
                raise WaitTimeout("the hold was not sent")
            if not wait_for(handle.hold_future, DRIVER_TIMEOUT).success:
                text = f"canceled, but {self.hold_service} refused to hold"
        except WaitTimeout:
            text = (
                f"canceled; {self.hold_service} did not answer (wam_node holds "
                f"{WAM_RT_TIMEOUT} s after the stream's end)"
            )
        still, deadline = _Stillness(), time.monotonic() + WAM_STOP_TIMEOUT
        period = 1.0 / WAM_COMMAND_RATE
        while time.monotonic() < deadline:
            if still.add(time.monotonic(), np.asarray(self.measured(), dtype=float)):
                break
            time.sleep(period)
        return self._outcome(GoalStatus.STATUS_CANCELED, R.SUCCESSFUL, text)


class BarrettHandServices:
    """The BarrettHand through Barrett's ROS 2 services (barrett-ros2-pkg's wam_node)."""

    def __init__(self, node: Node, prefix: str, group, gate: Gate = open_gate):
        self.gate = gate  # every motion command passes it; stop() does not
        make = lambda srv, name: node.create_client(srv, f"{prefix}/{name}", callback_group=group)
        self.finger_position = make(FingerPosition, "moveToFingerPositions")
        self.spread_position = make(SpreadPosition, "moveToSpreadPosition")
        self.finger_velocity = make(FingerVelocity, "moveToFingerVelocities")
        self.idle_client = make(Trigger, "idle")

    def ready(self) -> bool:
        return all(
            c.service_is_ready()
            for c in (self.finger_position, self.spread_position, self.finger_velocity)
        )

    def _call(self, client, request, wait: bool = True, gated: bool = True):
        if gated:
            sent, future = self.gate(lambda: client.call_async(request))
            if not sent:
                raise Latched(f"{client.srv_name}: the E-stop is latched; not sent")
        else:
            future = client.call_async(request)
        if not wait:
            return future
        response = answer(future, client.srv_name)
        ok = response.success if isinstance(response, Trigger.Response) else response.response
        if not ok:
            raise DriverError(f"{client.srv_name} refused the command")
        return response

    def move_spread(self, spread: float) -> None:
        """Start a spread move to ``spread`` [rad]."""
        self._call(self.spread_position, SpreadPosition.Request(position=float(spread)))

    def move_fingers(self, proximal: np.ndarray) -> None:
        """Start a move of the proximal joints to (3,) [rad]."""
        self._call(
            self.finger_position,
            FingerPosition.Request(position=np.asarray(proximal, dtype=float).tolist()),
        )

    def finger_velocities(self, velocity: np.ndarray, wait: bool = True) -> None:
        """Command proximal velocities (3,) [rad/s]; 0 stops (and holds) that finger. All zero
        is a stop, which no gate holds back."""
        velocity = np.asarray(velocity, dtype=float)
        self._call(
            self.finger_velocity,
            FingerVelocity.Request(velocity=velocity.tolist()),
            wait=wait,
            gated=bool(np.any(velocity != 0.0)),
        )

    def stop(self, spread: float) -> None:
        """Stop every hand motor now, whatever the gate says: the fingers at zero velocity and
        the spread told to stay at ``spread`` [rad] (its measured position; the services have
        no spread velocity). Does not wait for the answers."""
        self._call(self.finger_velocity, FingerVelocity.Request(velocity=[0.0] * 3), False, False)
        if np.isfinite(spread):
            request = SpreadPosition.Request(position=float(spread))
            self._call(self.spread_position, request, wait=False, gated=False)

    def idle(self) -> None:
        self._call(self.idle_client, Trigger.Request(), wait=False)


class RdtSensors:
    """Three Net F/T boxes (one Nano17 each) through the built-in RDT client."""

    #: bias() asks the boxes, which apply it to the records they send after the request.
    biased_by_box = True

    def __init__(
        self,
        hosts: list[str],
        port: int,
        calibration: Calibration,
        on_wrench: Callable[[int, np.ndarray, float], None],
        on_fault: Callable[[int, str, str], None],
        http_port: int = 0,
        on_config: Callable[[int, BoxConfig | None, str], None] | None = None,
        rdt_rate_hz: float = 0.0,
    ):
        """http_port > 0: each box's calibration is read from its netftapi2.xml over HTTP on
        that port (``on_config(finger, config or None, error)`` reports each attempt), and its
        records are not used until then; 0: ``calibration`` holds for every box. With
        ``rdt_rate_hz`` > 0 (and http_port) a box streaming at another rate is set to it
        (comm.cgi) and used once its page says it streams at least that fast."""
        self.clients = []
        self.http_port = http_port
        self.rdt_rate_hz = rdt_rate_hz
        self.on_config = on_config
        #: per box: its configuration once read (None: not yet), or the last reading error
        self.configs: list[BoxConfig | None] = [None] * len(hosts)
        self.config_errors = [""] * len(hosts)
        self._cpu_seen = [(0.0, 0)] * len(hosts)  # per box: (cpu_s, received) at the last status
        self._stopping = threading.Event()
        for i, host in enumerate(hosts):

            def sample(s: RdtSample, i=i) -> None:
                if s.status:  # a record with a status error is reported by on_fault
                    return
                if self.http_port and self.configs[i] is None:
                    return  # scaled by an unknown calibration: not a wrench
                on_wrench(i, s.wrench, s.received_s)

            self.clients.append(
                RdtClient(
                    host,
                    port,
                    calibration,
                    on_sample=sample,
                    on_fault=lambda kind, detail, i=i: on_fault(i, kind, detail),
                    name=f"fingertip{i + 1}",
                )
            )

    def start(self) -> None:
        for c in self.clients:
            c.start()
        if self.http_port:
            threading.Thread(target=self._read_configs, name="netft-config", daemon=True).start()

    def _read_configs(self) -> None:
        """Read every box's netftapi2.xml, again every CONFIG_RETRY_S until each is read."""
        while not self._stopping.is_set():
            for i, c in enumerate(self.clients):
                if self.configs[i] is not None:
                    continue
                try:
                    config = read_box_config(c.host, self.http_port, CONFIG_TIMEOUT_S)
                except (OSError, ValueError) as exc:
                    self._not_used(i, f"{CONFIG_PAGE} not read: {exc}")
                    continue
                if self.rdt_rate_hz and config.rdt_rate_hz != self.rdt_rate_hz:
                    config = self._set_rate(i, config)
                    if config is None:
                        continue
                c.set_calibration(config.calibration)
                self.configs[i], self.config_errors[i] = config, ""
                if self.on_config is not None:
                    self.on_config(i, config, "")
            if all(cfg is not None for cfg in self.configs):
                return
            self._stopping.wait(CONFIG_RETRY_S)

    def _set_rate(self, i: int, config: BoxConfig) -> BoxConfig | None:
        """Set box i to stream at rdt_rate_hz and restart its stream; its configuration read
        back, or None (the reason in config_errors, reported) when the box did not take it."""
        c = self.clients[i]
        try:
            after = set_box_rdt_rate(c.host, self.http_port, self.rdt_rate_hz, CONFIG_TIMEOUT_S)
        except (OSError, ValueError) as exc:
            return self._not_used(i, f"RDT rate not set to {self.rdt_rate_hz:g} Hz: {exc}")
        if after.rdt_rate_hz < self.rdt_rate_hz:  # a box may round up, never down
            return self._not_used(
                i,
                f"RDT rate {after.rdt_rate_hz:g} Hz after setting {self.rdt_rate_hz:g} Hz "
                f"(it was {config.rdt_rate_hz:g} Hz)",
            )
        c.restream()  # the stream runs at the new rate from its restart
        return after

    def _not_used(self, i: int, error: str) -> None:
        """Box i's configuration could not be read or set: keep why, and report it."""
        self.config_errors[i] = error
        if self.on_config is not None:
            self.on_config(i, None, error)

    def revive(self, silent_s: float) -> list[str]:
        """Ask every box silent for longer than ``silent_s`` [s] to stream again (it was not up
        when the bridge started, or it rebooted); returns their names."""
        silent = [c for c in self.clients if c.health().age_s > silent_s]
        for c in silent:
            c.restream()
        return [c.name for c in silent]

    def bias(self) -> None:
        """Bias every box at its current (unloaded!) reading."""
        for c in self.clients:
            c.bias()

    def reset_latch(self, finger: int) -> None:
        """Clear box ``finger``'s latched threshold status (RESET_THRESHOLD_LATCH)."""
        self.clients[finger].reset_latch()

    def stop(self) -> None:
        self._stopping.set()
        for c in self.clients:
            c.stop()

    def describe(self) -> str:
        return ", ".join(f"{c.name}@{c.host}" for c in self.clients)

    def status(self) -> dict[str, str]:
        """Each box's receive rate [Hz], lost records, status and length errors, age [s], and
        the CPU [µs] its receive thread spent per record (decode and the guard) since the
        previous call."""
        out = {}
        for i, c in enumerate(self.clients):
            h = c.health()
            cpu0, received0 = self._cpu_seen[i]
            self._cpu_seen[i] = (h.cpu_s, h.received)
            per_record = (
                (h.cpu_s - cpu0) / (h.received - received0) if h.received > received0 else 0
            )
            out[c.name] = (
                f"{h.rate_hz:.0f} Hz, {h.lost} lost, {h.status_errors} status errors, "
                f"{h.length_errors} length errors, age {h.age_s:.3f} s, "
                f"{per_record * 1e6:.1f} µs CPU/record"
            )
            if self.http_port:
                cfg = self.configs[i]
                out[c.name] += f"; {cfg.describe()}" if cfg else f"; {self.config_errors[i]}"
        return out

    def unread(self) -> dict[str, str]:
        """The boxes whose calibration is not known yet, and why (name: error)."""
        if not self.http_port:
            return {}
        return {
            c.name: self.config_errors[i] or f"{CONFIG_PAGE} not read yet"
            for i, c in enumerate(self.clients)
            if self.configs[i] is None
        }


class WrenchTopicSensors:
    """Fingertip wrenches from ``geometry_msgs/WrenchStamped`` topics of an existing driver."""

    #: bias() leaves the driver alone: the bridge's tare is the whole bias.
    biased_by_box = False

    def __init__(
        self,
        node: Node,
        topics: list[str],
        on_wrench: Callable[[int, np.ndarray, float], None],
        clock: Callable[[], float],
        group,
    ):
        self.topics = topics
        for i, topic in enumerate(topics):

            def callback(msg: WrenchStamped, i=i) -> None:
                f, t = msg.wrench.force, msg.wrench.torque
                on_wrench(i, np.array([f.x, f.y, f.z, t.x, t.y, t.z]), clock())

            node.create_subscription(
                WrenchStamped, topic, callback, qos_profile_sensor_data, callback_group=group
            )

    def start(self) -> None:
        pass

    def revive(self, silent_s: float) -> list[str]:
        return []

    def bias(self) -> None:
        """Topic drivers bias through their own services; the bridge tares in software."""

    def reset_latch(self, finger: int) -> None:
        """Topic drivers report no status word."""

    def stop(self) -> None:
        pass

    def describe(self) -> str:
        return ", ".join(self.topics)

    def status(self) -> dict[str, str]:
        return {}

    def unread(self) -> dict[str, str]:
        """Topic drivers publish calibrated wrenches: nothing to read first."""
        return {}


def create_drivers(
    node: Node, io: Node, p: Callable[[str], object], core: BridgeCore, group
) -> tuple:
    """(arm, its description, hand, fingertip sensors): the drivers a bridge node's parameters
    name (p(name): a parameter's value), calling back into its core
    (rrg_hw_bridge.bridge_core.BridgeCore); ``io`` spins the wrench topics."""
    if p("arm_backend") == "wam_node":
        arm = WamNodeArm(
            node,
            core.options.arm_driver_joints,
            group,
            lambda: core.measured().arm_q,
            p("wam_rt_joint_topic"),
            p("wam_hold_service"),
            core.estop.run_if_released,
        )
        arm_text = arm.describe()
    else:
        arm = TrajectoryArm(
            node,
            p("arm_action"),
            core.options.arm_driver_joints,
            group,
            core.estop.run_if_released,
        )
        arm_text = p("arm_action")
    hand = BarrettHandServices(node, p("hand_service_prefix"), group, core.estop.run_if_released)
    if p("wrench_source") == "rdt":
        sensors = RdtSensors(
            list(p("rdt_hosts")),
            int(p("rdt_port")),
            Calibration(p("counts_per_force"), p("counts_per_torque")),
            core.on_wrench,
            core.on_sensor_fault,
            http_port=int(p("netft_http_port")),
            on_config=core.on_box_config,
            rdt_rate_hz=float(p("rdt_rate")),
        )
    else:
        sensors = WrenchTopicSensors(
            io, list(p("wrench_topics")), core.on_wrench, time.monotonic, None
        )
    return arm, arm_text, hand, sensors
