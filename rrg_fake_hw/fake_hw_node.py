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

The node wires parameters, topics and the drivers' interfaces to the ROS-free core: the
emulated robot (emulated_robot), the Net F/T boxes, the joint state layout and the faults
(fake_hw_core) and the trajectory goals (trajectory_goals); the interfaces are in ``ros/``
(trajectory_controller, barrett_interfaces) and the parameters in ros/fake_hw_parameters.
"""

from __future__ import annotations

import logging
import sys
import threading
import time

import numpy as np
from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
from rcl_interfaces.msg import SetParametersResult
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState
from wam_msgs.msg import TactilePressureArray

from rrg_common.ros.diagnostics import WARN, Health, NodeDiagnostics
from rrg_common.ros.node_main import destroy_action_endpoints, run_node
from rrg_common.ros.parameters import declare
from rrg_models.config import PHYSICS, SENSING
from rrg_msgs.msg import ContactPads
from rrg_sim.ros.eval_services import EvalNames, EvalServices

from .emulated_robot import EmulatedRobot, Event, Snapshot
from .fake_hw_core import (
    FAULTS,
    NODE_NAME,
    FaultInjector,
    JointStateLayout,
    checked_fault,
    open_boxes,
)
from .ros.barrett_interfaces import BHandServices, WamNodeInterface, tactile_message
from .ros.fake_hw_parameters import PARAMETERS
from .ros.trajectory_controller import TrajectoryController
from .trajectory_goals import TrajectoryGoals

HAND_FRAME = "bhand_palm_link"
#: Period [s] of the check for first force crossings of the armed boxes (chosen: the crossing
#: instant is recorded by the box itself; this only delays the event message).
CROSSING_POLL_PERIOD = 0.02


class FakeHwNode(Node):
    """The emulated drivers (see the module doc)."""

    def __init__(self) -> None:
        super().__init__(NODE_NAME)
        declare(self, PARAMETERS)
        p = lambda name: self.get_parameter(name).value
        self.robot = EmulatedRobot(p("object_name"), p("seed"), p("sensor_noise"))
        group = ReentrantCallbackGroup()
        self.events_pub = self.create_publisher(DiagnosticStatus, "/fake_hw/events", 100)
        self.goals = TrajectoryGoals(self.robot)
        self.robot.add_listener(self._on_event)
        self.joint_pub = self.create_publisher(JointState, "/joint_states", 10)
        self.layout = JointStateLayout(p("arm_interface"), p("unmeasured_interfaces"))
        self.arm_interface = self.layout.arm_interface
        self._js_msg = JointState(name=list(self.layout.names()))
        self.tactile_pub = self.create_publisher(TactilePressureArray, "/bhand/tactile_states", 10)
        self.pads_pub = self.create_publisher(ContactPads, "/bhand/contact_pads", 10)
        self._tactile_rng = np.random.default_rng(p("seed") + 100)  # where a contact presses
        action = self._serve_drivers(p, group)
        self.eval = self._serve_eval(group)
        self.boxes = open_boxes(
            self.robot.tip_load,
            p("rdt_hosts"),
            p("counts_per_force"),
            p("counts_per_torque"),
            p("box_calibration_factors"),
            rate_hz=p("rdt_rate"),
            port=p("rdt_port"),
            sensor_noise=p("sensor_noise"),
            seed=p("seed"),
            zero_offset=p("tip_zero_offset"),
            http_port=p("netft_http_port") or None,
        )
        self.faults = FaultInjector(self.robot, self.boxes, p("tip_zero_offset"))
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

    def _serve_drivers(self, p, group) -> str:
        """The arm's interfaces (the trajectory controller's, wam_node's or both) and the hand's
        services; returns the trajectory controller's action name."""
        action = f"/{p('controller_name')}/follow_joint_trajectory"
        if self.arm_interface != "wam_node":
            self._controller = TrajectoryController(
                self, self.robot, self.goals, self._publish_event, action, group
            )
        self._wam = None
        if self.arm_interface != "follow_joint_trajectory":
            self._wam = WamNodeInterface(self, self.robot, group)
        self._hand = BHandServices(self, self.robot, group)
        return action

    def _serve_eval(self, group) -> EvalServices:
        """The simulation-only services and the true object pose, as the simulator node's."""
        return EvalServices(
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

    # ------------------------------------------------------------------ faults
    def _on_set_parameters(self, params: list[Parameter]) -> SetParametersResult:
        values = {}
        for prm in params:
            if prm.name not in FAULTS:
                continue  # read-only ones are refused by their descriptors
            try:
                values[prm.name] = checked_fault(prm.name, prm.value)
            except ValueError as exc:
                return SetParametersResult(successful=False, reason=str(exc))
        self._apply(values)
        return SetParametersResult(successful=True)

    def _apply(self, values: dict, startup: bool = False) -> None:
        """Put validated fault/bench parameter values into effect, and log them."""
        for name, v in values.items():
            self.faults.apply(name, v)
            if v != FAULTS[name].default:
                self.get_logger().warning(f"{name} = {v}")
            elif not startup:
                self.get_logger().info(f"{name} = {v} (off)")

    def _poll_crossings(self) -> None:
        for event in self.faults.new_crossings():
            self._publish_event(event)

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
        self.goals.on_event(event)
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
                    self._publish_pads(s, stamp)
                    next_pad = max(next_pad + pad_period, now - pad_period)
            except Exception as exc:
                if self._stop.is_set() or not self.context.ok():  # shutting down
                    return
                self.get_logger().error(f"state publishing failed: {type(exc).__name__}: {exc}")
                time.sleep(0.1)

    def _publish_pads(self, s: Snapshot, stamp) -> None:
        """The pads as Barrett's tactile pucks and as ContactPads (unless fault.silent_tactile),
        and the true object pose."""
        if not self.get_parameter("fault.silent_tactile").value:
            self.tactile_pub.publish(tactile_message(s.pads, self._tactile_rng))
            pads = ContactPads(
                in_contact=[bool(f) for f in s.pads > SENSING.pad_force_threshold],
                force=s.pads.tolist(),
            )
            pads.header.stamp, pads.header.frame_id = stamp, HAND_FRAME
            self.pads_pub.publish(pads)
        self.eval.publish_truth(stamp, self.robot.object_pose())

    def _stamp(self, s: Snapshot):
        """The ROS time of a state's control period (builtin_interfaces/Time), as a controller
        stamps what it read."""
        age_ns = int((time.monotonic() - s.stepped_s) * 1e9)
        return (self.get_clock().now() - Duration(nanoseconds=age_ns)).to_msg()

    def _joint_state(self, s: Snapshot, stamp) -> JointState:
        """The JointState of a snapshot, in one reused message (publish serializes it at once;
        array.array fields skip the per-element checks)."""
        msg = self._js_msg
        msg.header.stamp = stamp
        msg.position, msg.velocity, msg.effort = self.layout.arrays(s)
        return msg

    # ------------------------------------------------------------------ shutdown
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
            for box in self.boxes:
                box.close()
        destroy_action_endpoints(self)
        super().destroy_node()


def main(argv: list[str] | None = None) -> int:
    return run_node(FakeHwNode, multi_threaded=True, argv=argv)


if __name__ == "__main__":
    sys.exit(main())
