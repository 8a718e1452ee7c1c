r"""Emulated hardware drivers driven by MuJoCo: the interfaces of a WAM under a ros2_control
JointTrajectoryController and under Barrett's wam_node, Barrett's BarrettHand services
(wam_node) and three ATI Net F/T boxes, with a real grasp happening behind them
(rrg_fake_hw.emulated_robot).

    python -m rrg_fake_hw.fake_hw_node \
        [--ros-args -p object_name:=box -p sensor_noise:=1.0 -p rdt_port:=49152]

* action ``/<controller_name>/follow_joint_trajectory`` (control_msgs/FollowJointTrajectory):
  goals must name the 7 arm joints wam_j1_joint … wam_j7_joint (any order) with finite points
  of 7 positions and strictly increasing times; others are rejected (as JTC does). A new goal
  preempts the running one; a cancel holds the arm at once. Feedback ~50 Hz.
* Barrett's wam_node arm interface (WamNodeInterface): ``/wam/RTJointPositionCMD``
  (wam_msgs/RTJointPositions) streaming the servo targets, held 0.5 s after it falls silent;
  ``/wam/holdJointPosition`` (std_srvs/SetBool); ``/wam/moveToJointPosition`` (wam_srvs/JointMove,
  a trapezoidal move). ``arm_interface`` chooses follow_joint_trajectory, wam_node or both (the
  default); both drive the one arm, each command replacing what it tracked.
* ``/joint_states`` (sensor_msgs/JointState) at joint_state_rate: arm joints wam_j1_joint …
  (effort: the motors' joint torque [N m], gravity and motion included, noisy) and, with
  wam_node, q1 … q7 (effort: the same torque as commanded; wam_node alone: no velocities, as
  wam_node's), then the hand's spread,
  proximal and distal joints (effort NaN: not measured).
* services ``/bhand/moveToFingerPositions``, ``/bhand/moveToSpreadPosition``,
  ``/bhand/moveToFingerVelocities``, ``/bhand/moveToGraspPosition`` (bhand_srvs) and
  ``/bhand/openGrasp``, ``/bhand/closeGrasp``, ``/bhand/idle`` (std_srvs/Trigger): the move
  starts and the call returns at once, as wam_node's do.
* ``/bhand/tactile_states`` (wam_msgs/TactilePressureArray, as Barrett's BarrettHand node) at
  pad_rate: the pads' forces on the fingertip and palm pucks' cells (rrg_hw_bridge.tactile);
  and ``/bhand/contact_pads`` (rrg_msgs/ContactPads), all seven pads as a lab's adapter for the
  paper's hand (pads on the proximal links too) would publish them.
* three emulated Net F/T boxes (RDT over UDP on rdt_hosts:rdt_port) streaming the fingertip
  loads at rdt_rate.
* ``/fake_hw/events`` (diagnostic_msgs/DiagnosticStatus): goal_accepted, cancel_received,
  goal_finished, first_crossing and wam_node's rt_stream_started, rt_command_ignored,
  rt_timeout, hold_received, release_received, each with its time.monotonic() instant.
* ``/diagnostics`` (diagnostic_msgs/DiagnosticArray) once a second, as drivers publish theirs:
  the status ``fake_hw: status``, marked emulated, with the stepping thread's real-time
  statistics (WARN when it dropped periods since the last report).
* simulation only: ``/rrg/reset_sim``, ``/rrg/eval/judge_grasp``, ``/rrg/eval/object_pose``,
  ``/rrg/eval/grasp_outcome`` (rrg_sim.ros.eval_services, as the simulator node).

Faults and benchmarks are parameters settable at run time (``fault.*``, ``bench.*``).
"""

from __future__ import annotations

import array
import logging
import sys
import threading
import time
from dataclasses import dataclass

import numpy as np
from bhand_srvs.srv import FingerPosition, FingerVelocity, GraspPosition, SpreadPosition
from control_msgs.action import FollowJointTrajectory
from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
from rcl_interfaces.msg import (
    SetParametersResult,
)
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.action.server import GoalEvent, ServerGoalHandle
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.duration import Duration
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState
from std_srvs.srv import SetBool, Trigger
from trajectory_msgs.msg import JointTrajectoryPoint
from wam_msgs.msg import RTJointPositions, TactilePressure, TactilePressureArray
from wam_srvs.srv import JointMove

from rrg_common.ros.diagnostics import WARN, Health, NodeDiagnostics
from rrg_common.ros.node_main import destroy_action_endpoints, keep_serving, run_node
from rrg_common.ros.parameters import Param, declare
from rrg_common.ros.qos import RESULT_TIMEOUT_S
from rrg_fake_hw.emulated_robot import PREEMPTED_MESSAGE, EmulatedRobot, Event, GoalState
from rrg_fake_hw.fake_netft import FakeNetFtBox
from rrg_hw_bridge.rdt import Calibration
from rrg_hw_bridge.tactile import CELLS, pucks_from_pads
from rrg_models.config import HAND, PHYSICS, SENSING
from rrg_models.trajectory import GOAL_START_TOLERANCE
from rrg_msgs.msg import ContactPads
from rrg_sim.ros.eval_services import EvalNames, EvalServices

NODE_NAME = "fake_hw"
#: Driver joint names (ros2_control / Barrett URDF; PLAN.md).
ARM_JOINTS = tuple(f"wam_j{i}_joint" for i in range(1, 8))
SPREAD_JOINTS = ("bhand_j11_joint", "bhand_j21_joint")
PROXIMAL_JOINTS = ("bhand_j12_joint", "bhand_j22_joint", "bhand_j32_joint")
DISTAL_JOINTS = ("bhand_j13_joint", "bhand_j23_joint", "bhand_j33_joint")
JOINT_NAMES = ARM_JOINTS + SPREAD_JOINTS + PROXIMAL_JOINTS + DISTAL_JOINTS
#: The arm interfaces the node can serve (parameter arm_interface): the trajectory controller,
#: Barrett's wam_node (WamNodeInterface), or both on the one arm.
ARM_INTERFACES = ("follow_joint_trajectory", "wam_node", "both")
#: wam_node's arm joint names in /joint_states (wam_publishers.h: "q" + (i + 1)).
WAM_NODE_ARM_JOINTS = tuple(f"q{i}" for i in range(1, 8))
#: Efforts of the hand joints in wam_node's /joint_states: never set, so 0.
WAM_NODE_HAND_EFFORT = np.zeros(8)
HAND_FRAME = "bhand_palm_link"
#: Efforts of the hand joints in /joint_states: not measured.
UNMEASURED_EFFORT = np.full(8, np.nan)
#: Feedback period [s] of a trajectory goal (chosen; JTC's action_monitor_rate default, 20 Hz,
#: is coarser).
FEEDBACK_PERIOD = 0.02
#: Period [s] of the check for first force crossings of the armed boxes (chosen: the crossing
#: instant is recorded by the box itself; this only delays the event message).
CROSSING_POLL_PERIOD = 0.02
#: Longest wait [s] for the action server to mark a canceled goal as canceling.
CANCEL_STATE_WAIT = 1.0
#: How many boxes fault.silent_box can silence at once: 3 means all of them.
ALL_BOXES = 3


@dataclass(frozen=True)
class _Fault:
    """A run-time parameter: its default, description and range."""

    default: object
    description: str
    lo: float | None = None
    hi: float | None = None


FAULTS: dict[str, _Fault] = {
    "fault.silent_box": _Fault(-1, "Silence one Net F/T box (0-2), all (3) or none (-1)", -1, 3),
    "fault.drop_probability": _Fault(0.0, "Drop each RDT record with this probability", 0.0, 1.0),
    "fault.packet_delay": _Fault(0.0, "Send every RDT record this late [s]", 0.0, 1.0),
    "fault.status_word": _Fault(0, "Status word in every RDT record (0: healthy)", 0, 2**32 - 1),
    "fault.wrong_length": _Fault(False, "Send 35-byte datagrams instead of RDT records"),
    "fault.joint_limit": _Fault(False, "Report joint 4 past its upper limit (encoder glitch)"),
    "fault.zero_drift": _Fault(
        0.0, "Drift [N] of every Net F/T box's unloaded Fx (temperature)", -20.0, 20.0
    ),
    "fault.silent_tactile": _Fault(
        False, "Stop publishing the pads, tactile pucks and ContactPads (a hand driver hung)"
    ),
    "fault.ignore_cancel": _Fault(
        False, "The trajectory controller accepts a cancel and keeps the goal running"
    ),
    "fault.stuck_finger": _Fault(-1, "Finger (0-2) that ignores every command; -1: none", -1, 2),
    "fault.extra_force": _Fault(
        0.0, "Force [N] added to fingertip 1's load along its z (synthetic contact)", -100.0, 100.0
    ),
    "fault.palm_push": _Fault(
        0.0, "Force [N] pushing the palm up (world +z): a contact on the arm", -100.0, 100.0
    ),
    "bench.crossing_threshold": _Fault(
        0.0, "Record every box's first |force| over this [N] (0: off)", 0.0, 1000.0
    ),
}


def _seconds(duration) -> float:
    return duration.sec + 1e-9 * duration.nanosec


def validate_trajectory(goal, q_now: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(q (M,7) in ARM_JOINTS order [rad], t (M,) [s]) of a FollowJointTrajectory goal; ValueError
    with the reason when a JTC would reject it."""
    traj = goal.trajectory
    names = list(traj.joint_names)
    if len(names) != 7 or set(names) != set(ARM_JOINTS):
        raise ValueError(f"joint_names must be the 7 arm joints {list(ARM_JOINTS)}, got {names}")
    if not traj.points:
        raise ValueError("the trajectory has no points")
    order = [names.index(n) for n in ARM_JOINTS]
    q, t = [], []
    for k, p in enumerate(traj.points):
        if len(p.positions) != 7:
            raise ValueError(f"point {k} has {len(p.positions)} positions, not 7")
        for field in ("velocities", "accelerations"):
            n = len(getattr(p, field))
            if n not in (0, 7):
                raise ValueError(f"point {k} has {n} {field}, not 0 or 7")
            if n and not np.all(np.isfinite(getattr(p, field))):
                raise ValueError(f"point {k} has non-finite {field}")
        q.append(np.asarray(p.positions, dtype=float)[order])
        t.append(_seconds(p.time_from_start))
    q, t = np.array(q), np.array(t)
    if not np.all(np.isfinite(q)):
        raise ValueError("non-finite positions")
    if t[0] < 0.0 or np.any(np.diff(t) <= 0.0):
        raise ValueError(f"time_from_start must increase strictly from >= 0, got {t.tolist()}")
    last_v = traj.points[-1].velocities
    if len(last_v) and np.any(np.asarray(last_v) != 0.0):
        raise ValueError("the last point must have zero velocity")
    if t[0] == 0.0 and np.abs(q[0] - q_now).max() > GOAL_START_TOLERANCE:
        raise ValueError("the first point, at time 0, is away from the arm's configuration")
    return q, t


#: The node's parameters (rrg_common.ros.parameters): fixed at start, and the faults
#: (FAULTS), which may change at run time.
PARAMETERS: tuple[Param, ...] = (
    Param(
        "object_name",
        "powerdrill",
        "Installed object at start (rrg-object list); reset_sim may change it",
        read_only=True,
    ),
    Param("seed", 0, "Seed of the sensor noise", read_only=True, low=0, high=2**31 - 1),
    Param(
        "sensor_noise",
        1.0,
        "Scale of every sensor's noise sigma (1: config values, 0: noiseless)",
        read_only=True,
        low=0.0,
        high=10.0,
    ),
    Param(
        "joint_state_rate",
        500.0,
        "Rate [Hz] of /joint_states (wam_node: 500)",
        read_only=True,
        low=1.0,
        high=1000.0,
    ),
    Param(
        "pad_rate",
        50.0,
        "Rate [Hz] of the pads (BarrettHand feedback: 50)",
        read_only=True,
        low=1.0,
        high=500.0,
    ),
    Param(
        "rdt_rate",
        1000.0,
        "Rate [Hz] of each Net F/T box's RDT stream",
        read_only=True,
        low=1.0,
        high=7000.0,
    ),
    Param(
        "counts_per_force",
        1e6,
        "Net F/T calibration [counts/N]",
        read_only=True,
        low=1.0,
        high=1e9,
    ),
    Param(
        "counts_per_torque",
        1e6,
        "Net F/T calibration [counts/(N m)]",
        read_only=True,
        low=1.0,
        high=1e9,
    ),
    Param(
        "rdt_hosts",
        ["127.0.0.2", "127.0.0.3", "127.0.0.4"],
        "Addresses of the Net F/T boxes, fingers 1-3",
        read_only=True,
    ),
    Param(
        "box_calibration_factors",
        [1.0, 1.0, 1.0],
        "Per box, a factor on counts_per_force and counts_per_torque: "
        "boxes calibrated differently, as three real ones are",
        read_only=True,
    ),
    Param(
        "netft_http_port",
        0,
        "TCP port each box serves its /netftapi2.xml on (0: none; a real box: 80)",
        read_only=True,
        low=0,
        high=65535,
    ),
    Param(
        "rdt_port",
        49152,
        "UDP port of every Net F/T box (RDT: 49152)",
        read_only=True,
        low=1,
        high=65535,
    ),
    Param(
        "unmeasured_interfaces",
        [""],
        "Interfaces the trajectory controller's joint states publish as NaN, "
        "as joint_state_broadcaster does for a joint without them: arm_effort, "
        "hand_velocity",
        read_only=True,
    ),
    Param(
        "tip_zero_offset",
        [0.0] * 6,
        "Every Net F/T box's unloaded reading [N, N m] (Fx Fy Fz Tx Ty Tz) "
        "until bridge/bias removes it",
        read_only=True,
    ),
    Param(
        "controller_name",
        "arm_controller",
        "Name of the emulated trajectory controller",
        read_only=True,
    ),
    Param(
        "arm_interface",
        "both",
        "The arm's driver interface: the trajectory controller, Barrett's "
        f"wam_node, or both (one of {', '.join(ARM_INTERFACES)})",
        read_only=True,
    ),
    *(Param(name, f.default, f.description, low=f.lo, high=f.hi) for name, f in FAULTS.items()),
)


class FakeHwNode(Node):
    """The emulated drivers (see the module doc)."""

    def __init__(self) -> None:
        super().__init__(NODE_NAME)
        declare(self, PARAMETERS)
        p = lambda name: self.get_parameter(name).value
        self.robot = EmulatedRobot(p("object_name"), p("seed"), p("sensor_noise"))
        group = ReentrantCallbackGroup()
        self.events_pub = self.create_publisher(DiagnosticStatus, "/fake_hw/events", 100)
        self._goal_done: dict[int, threading.Event] = {}
        self._goal_ids: dict[bytes, int] = {}
        self._map_lock = threading.RLock()
        self._accepted = 0  # trajectory goals accepted so far
        self._accept_order: dict[bytes, int] = {}  # goal id → its acceptance number
        self.robot.add_listener(self._on_event)
        self.joint_pub = self.create_publisher(JointState, "/joint_states", 10)
        self.arm_interface = p("arm_interface")
        if self.arm_interface not in ARM_INTERFACES:
            raise ValueError(f"arm_interface must be one of {ARM_INTERFACES}")
        self._js_msg = JointState(name=list(self._joint_names()))
        self.unmeasured = set(p("unmeasured_interfaces")) - {""}
        if not self.unmeasured <= {"arm_effort", "hand_velocity"}:
            raise ValueError(f"unmeasured_interfaces: unknown {self.unmeasured}")
        self.tactile_pub = self.create_publisher(TactilePressureArray, "/bhand/tactile_states", 10)
        self.pads_pub = self.create_publisher(ContactPads, "/bhand/contact_pads", 10)
        self._tactile_rng = np.random.default_rng(p("seed") + 100)  # where a contact presses
        action = f"/{p('controller_name')}/follow_joint_trajectory"
        if self.arm_interface != "wam_node":
            self._action = ActionServer(
                self,
                FollowJointTrajectory,
                action,
                execute_callback=self._execute,
                goal_callback=self._on_goal,
                handle_accepted_callback=self._on_accepted,
                cancel_callback=self._on_cancel,
                callback_group=group,
                result_timeout=RESULT_TIMEOUT_S,
            )
        self._wam = None
        if self.arm_interface != "follow_joint_trajectory":
            self._wam = WamNodeInterface(self, self.robot, group)
        srv = lambda kind, name, cb: self.create_service(kind, name, cb, callback_group=group)
        srv(FingerPosition, "/bhand/moveToFingerPositions", self.on_finger_positions)
        srv(SpreadPosition, "/bhand/moveToSpreadPosition", self.on_spread_position)
        srv(FingerVelocity, "/bhand/moveToFingerVelocities", self.on_finger_velocities)
        srv(GraspPosition, "/bhand/moveToGraspPosition", self.on_grasp_position)
        srv(Trigger, "/bhand/openGrasp", self.on_open_grasp)
        srv(Trigger, "/bhand/closeGrasp", self.on_close_grasp)
        srv(Trigger, "/bhand/idle", self.on_idle)
        self.eval = EvalServices(
            self,
            world=lambda: self.robot.world,
            exclusive=self.robot.exclusive,
            reset_world=self.robot.reset,
            group=group,
            names=EvalNames(
                reset="/rrg/reset_sim",
                judge="/rrg/eval/judge_grasp",
                object_pose="/rrg/eval/object_pose",
                outcome="/rrg/eval/grasp_outcome",
                observation="/rrg/observation",
            ),
        )
        factors = list(p("box_calibration_factors"))
        if len(factors) != len(p("rdt_hosts")) or min(factors) <= 0.0:
            raise ValueError("box_calibration_factors: one positive factor per box")
        http_port = p("netft_http_port") or None
        noise = p("sensor_noise")
        self.boxes: list[FakeNetFtBox] = []
        try:
            for i, host in enumerate(p("rdt_hosts")):
                self.boxes.append(
                    FakeNetFtBox(
                        host,
                        lambda i=i: self.robot.tip_load(i),
                        Calibration(
                            p("counts_per_force") * factors[i], p("counts_per_torque") * factors[i]
                        ),
                        rate_hz=p("rdt_rate"),
                        port=p("rdt_port"),
                        noise_n=SENSING.nano17_force_noise * noise,
                        noise_nm=PHYSICS.nano17_torque_noise * noise,
                        seed=p("seed") + 1 + i,
                        zero_offset=p("tip_zero_offset"),
                        http_port=http_port,
                    )
                )
        except OSError:
            self._close_boxes()
            raise
        self._crossing: tuple[float, list[bool]] | None = None
        self._apply({name: p(name) for name in FAULTS}, startup=True)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.create_timer(CROSSING_POLL_PERIOD, self._poll_crossings, callback_group=group)
        self.robot.start()
        self._overruns = 0  # dropped periods at the last report
        self.diagnostics = NodeDiagnostics(self, self.health)
        self._stop = threading.Event()
        self._publisher = threading.Thread(
            target=self._publish_loop, name="fake_hw_pub", daemon=True
        )
        self._publisher.start()
        arm = {"follow_joint_trajectory": action, "wam_node": "/wam/*"}
        self.get_logger().info(
            f"emulated drivers ready: {self.robot.world.obj.name}, "
            f"{arm.get(self.arm_interface, f'{action} and /wam/*')}, /bhand/*, "
            f"Net F/T boxes at {', '.join(b.host for b in self.boxes)}:{p('rdt_port')}"
        )

    # ------------------------------------------------------------------ faults
    def _on_set_parameters(self, params: list[Parameter]) -> SetParametersResult:
        values = {}
        for prm in params:
            if prm.name not in FAULTS:
                continue  # read-only ones are refused by their descriptors
            f, v = FAULTS[prm.name], prm.value
            kind = type(f.default)
            if kind is float and type(v) is int:
                v = float(v)
            if type(v) is not kind or (
                f.lo is not None and not (np.isfinite(v) and f.lo <= v <= f.hi)
            ):
                return SetParametersResult(
                    successful=False,
                    reason=f"{prm.name}: {v!r} is not a {kind.__name__} in [{f.lo}, {f.hi}]",
                )
            values[prm.name] = v
        self._apply(values)
        return SetParametersResult(successful=True)

    def _apply(self, values: dict, startup: bool = False) -> None:
        """Put validated fault/bench parameter values into effect."""
        for name, v in values.items():
            if name == "fault.silent_box":
                for i, box in enumerate(self.boxes):
                    box.silence(v in (i, ALL_BOXES))
            elif name == "fault.drop_probability":
                for box in self.boxes:
                    box.drop_probability(v)
            elif name == "fault.packet_delay":
                for box in self.boxes:
                    box.delay(v)
            elif name == "fault.status_word":
                for box in self.boxes:
                    box.status_word(v)
            elif name == "fault.wrong_length":
                for box in self.boxes:
                    box.wrong_length(v)
            elif name == "fault.joint_limit":
                self.robot.set_joint_limit_fault(v)
            elif name == "fault.stuck_finger":
                self.robot.set_stuck_finger(None if v < 0 else v)
            elif name == "fault.zero_drift":
                base = np.asarray(self.get_parameter("tip_zero_offset").value, dtype=float)
                for box in self.boxes:
                    box.zero_offset = base + np.array([v, 0.0, 0.0, 0.0, 0.0, 0.0])
            elif name in ("fault.ignore_cancel", "fault.silent_tactile"):
                pass  # read where they act: the cancel callback, the publishing loop
            elif name == "fault.extra_force":
                self.robot.set_extra_force(v)
            elif name == "fault.palm_push":
                self.robot.set_palm_push(v)
            elif name == "bench.crossing_threshold":
                self._crossing = None
                if v > 0.0:
                    for box in self.boxes:
                        box.arm_crossing(v)
                    self._crossing = (v, [False] * len(self.boxes))
            if v != FAULTS[name].default:
                self.get_logger().warning(f"{name} = {v}")
            elif not startup:
                self.get_logger().info(f"{name} = {v} (off)")

    def _poll_crossings(self) -> None:
        crossing = self._crossing
        if crossing is None:
            return
        threshold, reported = crossing
        for i, box in enumerate(self.boxes):
            t = box.first_crossing(threshold)
            if t is not None and not reported[i]:
                reported[i] = True
                self._publish_event(
                    Event("first_crossing", t, {"box": i, "host": box.host, "threshold": threshold})
                )

    def health(self) -> Health:
        """For /diagnostics: what is emulated, and the stepping thread's real-time statistics;
        WARN when it dropped periods since the last report (it fell behind real time)."""
        t = self.robot.timing
        dropped, self._overruns = t.overruns - self._overruns, t.overruns
        health = Health(
            message="emulated drivers running",
            values={
                "emulated": "yes: MuJoCo behind the driver interfaces, no hardware",
                "object": self.robot.world.obj.name,
                "arm interface": self.arm_interface,
                "steps": str(t.steps),
                "dropped periods": str(t.overruns),
                "late steps": str(t.late_steps),
                "max lateness [ms]": f"{t.max_lateness_s * 1e3:.2f}",
            },
        )
        if dropped:
            health.escalate(
                WARN, f"behind real time: {dropped} periods dropped since the last report"
            )
        return health

    # ------------------------------------------------------------------ events and state
    def _on_event(self, event: Event) -> None:
        if event.name == "goal_finished":
            with self._map_lock:
                done = self._goal_done.get(event.details["goal_id"])
            if done is not None:
                done.set()
        self._publish_event(event)

    def _publish_event(self, event: Event) -> None:
        values = [KeyValue(key="time", value=f"{event.time_s:.9f}")]
        values += [KeyValue(key=k, value=str(v)) for k, v in event.details.items()]
        self.events_pub.publish(
            DiagnosticStatus(
                level=DiagnosticStatus.OK,
                name=event.name,
                message=", ".join(f"{k}={v}" for k, v in event.details.items()),
                hardware_id=NODE_NAME,
                values=values,
            )
        )
        if event.name == "cancel_received":
            self.get_logger().info(
                "cancel received: " + ", ".join(f"{k}={v}" for k, v in event.details.items())
            )

    def _publish_loop(self) -> None:
        """Joint states at joint_state_rate, pads and the true object pose at pad_rate (a thread
        of its own: an executor timer at 500 Hz costs far more)."""
        js_period = 1.0 / self.get_parameter("joint_state_rate").value
        pad_period = 1.0 / self.get_parameter("pad_rate").value
        next_js = next_pad = time.monotonic()
        # at the control rate every period's state goes out, as a controller's broadcaster
        # publishes each update's; below it, the newest
        every_period = js_period <= PHYSICS.timestep * 1.001
        self.robot.record_periods = every_period
        while not self._stop.is_set():
            now = time.monotonic()
            wake = min(next_js, next_pad)
            if now < wake:
                time.sleep(wake - now)
                continue
            try:
                pads_due = now >= next_pad
                s = self.robot.snapshot(pads=pads_due)
                stamp = self._stamp(s)
                if now >= next_js:
                    for state in self.robot.period_states() if every_period else [s]:
                        self.joint_pub.publish(self._joint_state(state, self._stamp(state)))
                    next_js = max(next_js + js_period, now - js_period)
                if pads_due:
                    if not self.get_parameter("fault.silent_tactile").value:
                        self.tactile_pub.publish(self._tactile(s.pads))
                        pads = ContactPads(
                            in_contact=[bool(f) for f in s.pads > SENSING.pad_force_threshold],
                            force=s.pads.tolist(),
                        )
                        pads.header.stamp, pads.header.frame_id = stamp, HAND_FRAME
                        self.pads_pub.publish(pads)
                    self.eval.publish_truth(stamp, self.robot.object_pose())
                    next_pad = max(next_pad + pad_period, now - pad_period)
            except Exception as exc:
                if self._stop.is_set() or not self.context.ok():  # shutting down
                    return
                self.get_logger().error(f"state publishing failed: {type(exc).__name__}: {exc}")
                time.sleep(0.1)

    def _tactile(self, pads: np.ndarray) -> TactilePressureArray:
        """Barrett's tactile message carrying the pads' forces (7,) [N] on the pucks' cells."""
        levels = [0] * CELLS  # the node's display levels: not emulated
        return TactilePressureArray(
            tactile_pressures=[
                TactilePressure(pressure=cells.tolist(), normalized_pressure=levels)
                for cells in pucks_from_pads(pads, self._tactile_rng)
            ]
        )

    def _joint_names(self) -> tuple[str, ...]:
        """The /joint_states names: the trajectory controller's arm joints (effort: the
        motors' torque), wam_node's (effort: commanded torque), or both, then the hand's."""
        arm = {
            "follow_joint_trajectory": ARM_JOINTS,
            "wam_node": WAM_NODE_ARM_JOINTS,
            "both": ARM_JOINTS + WAM_NODE_ARM_JOINTS,
        }[self.arm_interface]
        return arm + JOINT_NAMES[len(ARM_JOINTS) :]

    def _stamp(self, s):
        """The ROS time of a state's control period (builtin_interfaces/Time), as a controller
        stamps what it read."""
        age_ns = int((time.monotonic() - s.stepped_s) * 1e9)
        return (self.get_clock().now() - Duration(nanoseconds=age_ns)).to_msg()

    def _joint_state(self, s, stamp) -> JointState:
        """The JointState of a snapshot, in one reused message (publish serializes it at once;
        array.array fields skip the per-element checks). wam_node's alone has no velocities and
        zero hand efforts, as wam_node's (wam_publishers.h)."""
        doubles = lambda *parts: array.array("d", np.concatenate(parts).tobytes())
        msg = self._js_msg
        msg.header.stamp = stamp
        hand_q = (s.spread, s.proximal, s.distal)
        hand_v = (s.spread_velocity, s.proximal_velocity, s.distal_velocity)
        arm_effort = s.arm_effort
        if "hand_velocity" in self.unmeasured:
            hand_v = (np.full(8, np.nan),)
        if "arm_effort" in self.unmeasured:
            arm_effort = np.full(7, np.nan)
        if self.arm_interface == "follow_joint_trajectory":
            msg.position = doubles(s.arm_q, *hand_q)
            msg.velocity = doubles(s.arm_qd, *hand_v)
            msg.effort = doubles(arm_effort, UNMEASURED_EFFORT)
        elif self.arm_interface == "wam_node":
            msg.position = doubles(s.arm_q, *hand_q)
            msg.velocity = array.array("d")
            msg.effort = doubles(s.arm_torque, WAM_NODE_HAND_EFFORT)
        else:
            msg.position = doubles(s.arm_q, s.arm_q, *hand_q)
            msg.velocity = doubles(s.arm_qd, s.arm_qd, *hand_v)
            msg.effort = doubles(arm_effort, s.arm_torque, UNMEASURED_EFFORT)
        return msg

    # ------------------------------------------------------------------ trajectory controller
    def _on_goal(self, goal: FollowJointTrajectory.Goal) -> GoalResponse:
        try:
            validate_trajectory(goal, self.robot.snapshot(pads=False).arm_q)
        except ValueError as exc:
            self.get_logger().error(f"follow_joint_trajectory goal rejected: {exc}")
            return GoalResponse.REJECT
        return GoalResponse.ACCEPT

    def _on_accepted(self, handle: ServerGoalHandle) -> None:
        """Number the goals in the order they are accepted: the newest one runs (JTC preempts
        by arrival, whatever order the executor runs the execute callbacks in)."""
        with self._map_lock:
            self._accepted += 1
            self._accept_order[bytes(handle.goal_id.uuid)] = self._accepted
        handle.execute()

    def _on_cancel(self, handle: ServerGoalHandle) -> CancelResponse:
        with self._map_lock:
            goal_id = self._goal_ids.get(bytes(handle.goal_id.uuid))
        if self.get_parameter("fault.ignore_cancel").value:
            self._publish_event(Event("cancel_ignored", time.monotonic(), {"goal_id": goal_id}))
        elif goal_id is not None:
            self.robot.cancel(goal_id)
        return CancelResponse.ACCEPT

    def _execute(self, handle: ServerGoalHandle) -> FollowJointTrajectory.Result:
        R = FollowJointTrajectory.Result
        result = R(error_code=R.SUCCESSFUL)
        key = bytes(handle.goal_id.uuid)
        try:
            q, t = validate_trajectory(handle.request, self.robot.snapshot(pads=False).arm_q)
        except ValueError as exc:  # the arm moved since the goal was accepted
            result.error_code, result.error_string = R.INVALID_GOAL, str(exc)
            handle.abort()
            return result
        if handle.is_cancel_requested:
            handle.canceled()
            return result
        done = threading.Event()
        with self._map_lock:
            if self._accept_order.pop(key, self._accepted) < self._accepted:
                # a newer goal was accepted before this one started: it is preempted at once
                result.error_string = PREEMPTED_MESSAGE
                handle._update_state(GoalEvent.CANCEL_GOAL)
                handle.canceled()
                return result
            goal_id = self.robot.follow(q, t)
            self._goal_ids[key] = goal_id
            self._goal_done[goal_id] = done
            if self.robot.goal_status(goal_id).state is not GoalState.ACTIVE:
                done.set()
        try:
            while not done.wait(FEEDBACK_PERIOD):
                if handle.is_cancel_requested:
                    # the server marks a goal canceling after the cancel callback returns: a
                    # goal still active then had its cancel arrive before it started running
                    running = self.robot.goal_status(goal_id).state is GoalState.ACTIVE
                    if running and not self.get_parameter("fault.ignore_cancel").value:
                        self.robot.cancel(goal_id)
                    continue
                self._feedback(handle, goal_id)
            status = self.robot.goal_status(goal_id)
        finally:
            with self._map_lock:
                self._goal_ids.pop(key, None)
                self._goal_done.pop(goal_id, None)
        result.error_string = status.message
        if status.state is GoalState.SUCCEEDED:
            handle.succeed()
        elif status.state is GoalState.CANCELED:
            deadline = time.monotonic() + CANCEL_STATE_WAIT
            while not handle.is_cancel_requested and time.monotonic() < deadline:
                time.sleep(0.001)  # the server marks it canceling after our cancel callback
            handle.canceled()
        elif status.state is GoalState.PREEMPTED:
            if not handle.is_cancel_requested:  # JTC cancels a preempted goal
                handle._update_state(GoalEvent.CANCEL_GOAL)
            handle.canceled()
        else:
            result.error_code = R.INVALID_GOAL
            handle.abort()
        return result

    def _feedback(self, handle: ServerGoalHandle, goal_id: int) -> None:
        status = self.robot.goal_status(goal_id)
        s = self.robot.snapshot(pads=False)
        fb = FollowJointTrajectory.Feedback(joint_names=list(ARM_JOINTS))
        fb.header.stamp = self.get_clock().now().to_msg()
        fb.desired = JointTrajectoryPoint(positions=status.desired.tolist())
        fb.actual = JointTrajectoryPoint(positions=s.arm_q.tolist(), velocities=s.arm_qd.tolist())
        fb.error = JointTrajectoryPoint(positions=(status.desired - s.arm_q).tolist())
        handle.publish_feedback(fb)

    # ------------------------------------------------------------------ BarrettHand services
    def _hand(self, what: str, command, *args) -> bool:
        try:
            command(*args)
        except ValueError as exc:
            self.get_logger().warning(f"{what} refused: {exc}")
            return False
        return True

    @staticmethod
    def _three(values) -> np.ndarray:
        v = np.asarray(values, dtype=float)
        if v.shape != (3,):
            raise ValueError(f"need 3 values, got {len(v)}")
        return v

    @keep_serving
    def on_finger_positions(self, req, resp):
        resp.response = self._hand(
            "moveToFingerPositions",
            lambda: self.robot.move_fingers(self._three(req.position)),
        )
        return resp

    @keep_serving
    def on_spread_position(self, req, resp):
        resp.response = self._hand("moveToSpreadPosition", self.robot.move_spread, req.position)
        return resp

    @keep_serving
    def on_finger_velocities(self, req, resp):
        resp.response = self._hand(
            "moveToFingerVelocities",
            lambda: self.robot.finger_velocities(self._three(req.velocity)),
        )
        return resp

    @keep_serving
    def on_grasp_position(self, req, resp):
        resp.response = self._hand("moveToGraspPosition", self.robot.move_fingers, req.position)
        return resp

    @keep_serving
    def on_open_grasp(self, req: Trigger.Request, resp: Trigger.Response) -> Trigger.Response:
        self.robot.open_grasp()
        resp.success, resp.message = True, "opening"
        return resp

    @keep_serving
    def on_close_grasp(self, req: Trigger.Request, resp: Trigger.Response) -> Trigger.Response:
        self.robot.close_grasp()
        resp.success, resp.message = True, f"closing to {HAND.proximal_range[1]} rad"
        return resp

    @keep_serving
    def on_idle(self, req: Trigger.Request, resp: Trigger.Response) -> Trigger.Response:
        self.robot.idle()
        resp.success, resp.message = True, "idle: motions stopped, fingers braked"
        return resp

    # ------------------------------------------------------------------ shutdown
    def _close_boxes(self) -> None:
        for box in self.boxes:
            box.close()

    def destroy_node(self) -> None:
        if getattr(self, "_wam", None) is not None:
            self._wam.close()
        if hasattr(self, "_stop"):
            self._stop.set()
            self._publisher.join(timeout=1.0)
        if hasattr(self, "robot"):
            self.robot.stop()
            t = self.robot.timing
            logging.getLogger(NODE_NAME).info(  # the context may be shut down: no rosout
                f"real time: {t.steps} steps, {t.overruns} dropped periods, "
                f"{t.late_steps} late steps, max lateness {1e3 * t.max_lateness_s:.2f} ms"
            )
        if hasattr(self, "boxes"):
            self._close_boxes()
        destroy_action_endpoints(self)
        super().destroy_node()


# ---------------------------------------------------------------------- wam_node's arm interface
class WamNodeInterface:
    """Barrett's own ROS 2 wam_node (barrett-ros2-pkg; its wam_node/src at e9056c2 of the copy
    github.com/gaolongsen/WAM-ROS2) on the emulated arm: ``/wam/RTJointPositionCMD``
    (wam_msgs/RTJointPositions) streams the servo targets and its silence for 0.5 s holds the
    arm; ``/wam/holdJointPosition`` (std_srvs/SetBool: true holds where the arm is, false idles,
    emulated as a hold); ``/wam/moveToJointPosition`` (wam_srvs/JointMove: a trapezoidal move,
    answered once it has ended, as libbarrett's blocking moveTo); ``/wam/idle`` (std_srvs/Trigger,
    emulated as a hold, and logged: the real arm would go limp). The behaviour is
    EmulatedRobot's (rt_joint_positions, hold_joint_position, move_to_joint_position)."""

    def __init__(self, node: Node, robot: EmulatedRobot, group):
        self.node, self.robot = node, robot
        srv = lambda kind, name, cb: node.create_service(kind, name, cb, callback_group=group)
        srv(SetBool, "/wam/holdJointPosition", self.on_hold)
        srv(JointMove, "/wam/moveToJointPosition", self.on_move)
        srv(Trigger, "/wam/idle", self.on_idle)
        # The 500 Hz stream on a node of its own, spun by a single-threaded executor (as the
        # bridge's I/O: rclpy's multi-threaded executor does not keep up with 500 Hz).
        self.io = Node(f"{NODE_NAME}_wam_io", context=node.context)
        self.io.create_subscription(
            RTJointPositions, "/wam/RTJointPositionCMD", self.on_rt_joint_positions, 100
        )
        self._executor = SingleThreadedExecutor(context=node.context)
        self._executor.add_node(self.io)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._spin, name="fake_hw_wam_io", daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        while not self._stop.is_set() and self.node.context.ok():
            try:
                self._executor.spin_once(timeout_sec=0.05)
            except (ExternalShutdownException, KeyboardInterrupt):
                break
            except Exception as exc:
                if self._stop.is_set() or not self.node.context.ok():
                    break
                self.node.get_logger().error(f"wam_node stream: {type(exc).__name__}: {exc}")

    def on_rt_joint_positions(self, msg: RTJointPositions) -> None:
        stamp = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
        try:
            self.robot.rt_joint_positions(msg.joint_states, stamp)
        except ValueError as exc:
            self.node.get_logger().error(
                f"Invalid Joint Position Command received: {exc}", throttle_duration_sec=1.0
            )

    @keep_serving
    def on_hold(self, req: SetBool.Request, resp: SetBool.Response) -> SetBool.Response:
        self.robot.hold_joint_position(req.data)
        if req.data:
            resp.message = "Holding WAM Joint Positions"
        else:
            resp.message = "idle: emulated as a hold (the real arm floats in gravity compensation)"
            self.node.get_logger().warning(f"/wam/holdJointPosition false: {resp.message}")
        resp.success = True
        return resp

    @keep_serving
    def on_move(self, req: JointMove.Request, resp: JointMove.Response) -> JointMove.Response:
        try:
            goal = self.robot.move_to_joint_position(req.joint_state.position)
        except ValueError as exc:
            self.node.get_logger().error(f"/wam/moveToJointPosition refused: {exc}")
            resp.response = False
            return resp
        while self.robot.goal_status(goal).state is GoalState.ACTIVE:
            time.sleep(FEEDBACK_PERIOD)
        resp.response = True
        return resp

    @keep_serving
    def on_idle(self, req: Trigger.Request, resp: Trigger.Response) -> Trigger.Response:
        self.robot.hold_joint_position(False)
        self.node.get_logger().error(
            "/wam/idle called: the real arm would go limp; emulated as a hold"
        )
        resp.success, resp.message = True, "idle (emulated as a hold)"
        return resp

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=1.0)
        self._executor.shutdown(timeout_sec=1.0)
        self.io.destroy_node()


def main(argv: list[str] | None = None) -> int:
    return run_node(FakeHwNode, multi_threaded=True, argv=argv)


if __name__ == "__main__":
    sys.exit(main())
