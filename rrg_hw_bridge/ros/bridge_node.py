r"""The hardware bridge node (design §7): RRG's arm/hand interface on the real drivers.

    python -m rrg_hw_bridge.ros.bridge_node [--ros-args -p dry_run:=true -p limits_file:=arm.yaml]

Upward it serves what the simulator node serves, under /rrg: ``guarded_move``
(rrg_msgs/GuardedMove), ``hand_command`` (rrg_msgs/HandCommand), ``joint_states``,
``fingertip{1,2,3}/wrench`` and ``contact_pads``, so the executor, estimator and planner run
unchanged. Downward it drives a FollowJointTrajectory arm controller (or, with ``arm_backend``
``wam_node``, Barrett's wam_node through its real-time joint stream), Barrett's BarrettHand
services and three Net F/T boxes over RDT (or WrenchStamped topics), all named by parameters.

Every command passes the safety layer (rrg_hw_bridge.safety): joint position, velocity and
acceleration limits and the workspace box before anything is sent; while a move runs, the
force/torque ceiling, the data watchdog (joint states and wrenches older than
``watchdog_timeout``, Net F/T sequence gaps and status errors) and the latched E-stop
(``/rrg/estop``, std_msgs/Bool; ``bridge/reset_estop`` clears it) cancel the controller's goal,
which holds the arm. A guarded move also stops on the first pad, fingertip or joint-effort
crossing. Every refusal and stop is logged and published on ``bridge/safety``
(diagnostic_msgs/DiagnosticStatus); every validated plan on ``bridge/plan``
(trajectory_msgs/JointTrajectory). ``dry_run`` validates and publishes, and commands nothing.

The node wires topics, services and the action to the ROS-free core: the safety state
(rrg_hw_bridge.bridge_core), the guarded moves (arm_motion) and the hand commands
(hand_control).
"""

from __future__ import annotations

import sys
import threading
import time

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import WrenchStamped
from rcl_interfaces.msg import SetParametersResult
from rclpy.action import GoalResponse
from rclpy.action.server import ServerGoalHandle
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool
from std_srvs.srv import Trigger
from trajectory_msgs.msg import JointTrajectory
from wam_msgs.msg import TactilePressureArray

from rrg_common.ros.arm_hand_interface import (
    StatePublishers,
    check_hand_command,
    goal_via_points,
    serve_arm_hand_interface,
)
from rrg_common.ros.msg_conversions import (
    ARM_JOINT_NAMES,
    PROXIMAL_JOINT_NAMES,
    SPREAD_JOINT_NAME,
    tip_contacts_to_msg,
    vector_to_msg,
)
from rrg_common.ros.node_main import destroy_action_endpoints, keep_serving, run_node
from rrg_common.ros.parameters import declare
from rrg_msgs.action import GuardedMove
from rrg_msgs.msg import ContactPads
from rrg_msgs.srv import HandCommand

from ..arm_motion import ArmMotion, MoveRequest
from ..bridge_core import ARM_ON_START_DELAY_S, BridgeCore, HandStopped
from ..bridge_core import JointState as DriverJointState
from ..config import BRIDGE
from ..contact_guard import DERIVED_PADS_UNSENSED, StopSensing
from ..driver_api import DriverError, Latched
from ..hand_control import HandControl, HandMode
from ..safety import EStop, SafetyCode
from ..tactile import TACTILE_PADS_UNSENSED, TactileError, pads_from_pucks
from .bridge_parameters import PARAMETERS, bridge_options
from .drivers import create_drivers

NODE_NAME = "hw_bridge"
NAMESPACE = "rrg"
H = HandCommand.Response
#: QoS of the E-stop's second subscription: a publisher that keeps its last message
#: (transient local) hands an E-stop engaged before the bridge started to the bridge as it
#: joins. A volatile publisher (``ros2 topic pub`` by default) reaches the first, volatile one.
ESTOP_LATCHED_QOS = QoSProfile(
    depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL
)
#: Upward hand joint names (the simulator's): both spread joints, proximal, distal.
HAND_JOINT_NAMES = (
    SPREAD_JOINT_NAME,
    "bh_f2_spread",
    *PROXIMAL_JOINT_NAMES,
    *(f"bh_f{i}_dist" for i in (1, 2, 3)),
)


class BridgeNode(Node):
    """The arm/hand interface on real drivers, behind a safety layer."""

    def __init__(self) -> None:
        super().__init__(NODE_NAME, namespace=NAMESPACE)
        declare(self, PARAMETERS)
        p = lambda name: self.get_parameter(name).value
        self.core = BridgeCore(bridge_options(p), self.get_logger(), self.report)
        self.core.speed_scale = float(p("speed_scale"))
        self.speed_scale_cap = self.core.speed_scale  # run-time changes may only lower it
        self.add_on_set_parameters_callback(self.on_set_parameters)
        self.arm_motion = ArmMotion(self.core, self.publish_plan)
        self.hand_control = HandControl(self.core, self.ros_time)
        group = ReentrantCallbackGroup()
        # The drivers' streams (joint states at 500 Hz, pads, the E-stop) and the periodic work
        # run on a second node spun by its own single-threaded executor: rclpy's
        # MultiThreadedExecutor cannot keep up with 500 Hz (28 Hz at 84 % of a core, measured),
        # its single-threaded one can (500 Hz at 13 %).
        self.io = Node(f"{NODE_NAME}_io", namespace=NAMESPACE, context=self.context)
        self._io_executor = SingleThreadedExecutor(context=self.context)
        self._io_executor.add_node(self.io)
        self._closing = threading.Event()
        self.core.attach(*create_drivers(self, self.io, p, self.core, group))
        self._subscribe_pads(p)
        self.io.create_subscription(JointState, p("driver_joint_states"), self.on_driver_joints, 50)
        self.io.create_subscription(Bool, p("estop_topic"), self.on_estop, 10)
        self.io.create_subscription(Bool, p("estop_topic"), self.on_estop, ESTOP_LATCHED_QOS)
        self._serve(p, group)
        self._io_thread = threading.Thread(target=self._spin_io, name="bridge-io", daemon=True)
        self._io_thread.start()
        self.core.sensors.start()
        self._log_start(p)

    def _subscribe_pads(self, p) -> None:
        """The pads' source: derived from the fingertips, Barrett's tactile pucks, or a
        ContactPads topic."""
        pad_source = p("pad_source")
        if pad_source == "derived":
            self.get_logger().warning(
                "pad_source 'derived': the hand has no pad feedback; the distal pads read the "
                f"fingertip forces and {', '.join(DERIVED_PADS_UNSENSED)} never fire (the "
                "estimator and the planner leave them out: unsensed_sensors, set by rrg-launch)"
            )
        elif pad_source == "tactile":
            self.get_logger().info(
                f"pads from Barrett's tactile pucks on {p('tactile_topic')}: "
                f"{', '.join(TACTILE_PADS_UNSENSED)} have none and never fire"
            )
            self.io.create_subscription(
                TactilePressureArray, p("tactile_topic"), self.on_tactile, 10
            )
        else:
            self.get_logger().info(f"pads from rrg_msgs/ContactPads on {p('pads_topic')}")
            self.io.create_subscription(ContactPads, p("pads_topic"), self.on_driver_pads, 10)

    def _serve(self, p, group) -> None:
        """RRG's side: the arm/hand interface, the bridge's services, state and status."""
        self.state_pubs = StatePublishers.create(self, frames=bool(p("publish_frames")))
        self.plan_pub = self.create_publisher(JointTrajectory, "bridge/plan", 10)
        self.safety_pub = self.create_publisher(DiagnosticStatus, "bridge/safety", 10)
        #: every status and safety event also goes on /diagnostics, as ROS drivers publish
        #: theirs (rqt_robot_monitor, Foxglove)
        self.diagnostics_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        serve_arm_hand_interface(
            self, self.execute_guarded_move, self.on_move_goal, self.on_hand_command, group
        )
        self.create_service(
            Trigger, "bridge/reset_estop", self.on_reset_estop, callback_group=group
        )
        self.create_service(Trigger, "bridge/bias", self.on_bias, callback_group=group)
        self.io.create_timer(BRIDGE.watchdog_period, self.core.on_watchdog)
        self.io.create_timer(1.0 / p("state_rate"), self.publish_state)
        self.status_pub = self.create_publisher(DiagnosticStatus, "bridge/status", 10)
        self.io.create_timer(1.0, self.publish_status)

    def _log_start(self, p) -> None:
        core = self.core
        self.get_logger().info(
            f"bridge up{' (DRY RUN: nothing will be commanded)' if core.options.dry_run else ''}"
            f": arm {core.arm_text}, hand {p('hand_service_prefix')}/*, fingertips "
            f"{core.sensors.describe()}, limits {core.limits.name}, speed scale "
            f"{core.speed_scale}, watchdog {core.options.watchdog_timeout * 1e3:.0f} ms"
        )
        self.get_logger().warning(
            f"E-stop latched, {core.estop.reason} (ros2 service call "
            f"/{NAMESPACE}/bridge/reset_estop std_srvs/srv/Trigger); nothing moves until then"
            + (
                f"; arm_on_start arms it in {ARM_ON_START_DELAY_S:.0f} s unless an E-stop comes"
                if core.arm_on_start_pending and core.estop.reason == EStop.NOT_ARMED
                else ""
            )
        )

    def on_set_parameters(self, params) -> SetParametersResult:
        """Run-time changes: ``speed_scale`` may be lowered, never raised above its start
        value (the descriptors refuse every read-only parameter)."""
        for prm in params:
            if prm.name != "speed_scale":
                continue
            value = float(prm.value)
            if not 0.0 < value <= self.speed_scale_cap:
                return SetParametersResult(
                    successful=False,
                    reason=f"speed_scale may only be lowered: {value} is not in "
                    f"(0, {self.speed_scale_cap}] (its start value)",
                )
            self.core.speed_scale = value
            self.get_logger().warning(
                f"speed_scale set to {value} (at most {self.speed_scale_cap})"
            )
        return SetParametersResult(successful=True)

    # ------------------------------------------------------------------ safety reports
    def report(self, code: int, check: str, message: str, refused: bool) -> None:
        """Log a refusal or a safety stop and publish it on bridge/safety."""
        what = "refused" if refused else "stopped"
        self.get_logger().error(f"{what} [{check}, code {code}]: {message}")
        status = DiagnosticStatus(
            level=DiagnosticStatus.ERROR,
            name=f"{NODE_NAME}/{check}",
            message=f"{what}: {message}",
            hardware_id="wam",
            values=[KeyValue(key="code", value=str(code)), KeyValue(key="what", value=what)],
        )
        self.safety_pub.publish(status)
        self.publish_diagnostics(status)

    def publish_diagnostics(self, status: DiagnosticStatus) -> None:
        """One status on /diagnostics (diagnostic_msgs/DiagnosticArray)."""
        array = DiagnosticArray(status=[status])
        array.header.stamp = self.get_clock().now().to_msg()
        self.diagnostics_pub.publish(array)

    # ------------------------------------------------------------------ driver callbacks
    def on_driver_joints(self, msg: JointState) -> None:
        # when the driver measured it, on its clock (arrival when it does not stamp)
        stamp = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec or self.ros_time()
        self.core.on_joint_state(
            DriverJointState(
                tuple(msg.name),
                np.asarray(msg.position, dtype=float),
                np.asarray(msg.velocity, dtype=float),
                np.asarray(msg.effort, dtype=float),
                stamp,
            )
        )

    def on_tactile(self, msg: TactilePressureArray) -> None:
        """Barrett's tactile pucks → the pads (rrg_hw_bridge.tactile); a malformed message is
        a sensor fault."""
        try:
            pads = pads_from_pucks([puck.pressure for puck in msg.tactile_pressures])
        except TactileError as exc:
            topic = self.get_parameter("tactile_topic").value
            self.core.sensor_fault(f"tactile pucks on {topic}: {exc}")
            return
        self.core.on_pads(pads)

    def on_driver_pads(self, msg: ContactPads) -> None:
        self.core.on_pads(np.asarray(msg.force, dtype=float))

    def on_estop(self, msg: Bool) -> None:
        self.core.on_estop(bool(msg.data))

    # ------------------------------------------------------------------ upward state
    def joint_state(self) -> JointState:
        m = self.core.measured()
        msg = JointState(
            name=[*ARM_JOINT_NAMES, *HAND_JOINT_NAMES],
            position=np.r_[m.arm_q, m.hand_q].tolist(),
            velocity=np.r_[m.arm_v, m.hand_v].tolist(),
        )
        msg.header.stamp = self.get_clock().now().to_msg()
        return msg

    def publish_state(self) -> None:
        if not np.isfinite(self.core.measured().arm_q).all():
            return
        hand = self.core.hand
        js = self.joint_state()
        self.state_pubs.publish_joints(js)
        tips = hand.tips()
        for i, pub in enumerate(self.state_pubs.wrenches):
            w = WrenchStamped()
            w.header.stamp, w.header.frame_id = js.header.stamp, f"bh_f{i + 1}_tip"
            w.wrench.force, w.wrench.torque = vector_to_msg(tips[i, :3]), vector_to_msg(tips[i, 3:])
            pub.publish(w)
        msg = ContactPads(
            in_contact=[bool(f) for f in hand.fired()[:7]], force=hand.pads().tolist()
        )
        msg.header.stamp, msg.header.frame_id = js.header.stamp, "bh_palm"
        self.state_pubs.pads.publish(msg)

    def publish_status(self) -> None:
        """Once a second on bridge/status: the drivers' stream rates and the safety state; a
        silent Net F/T box is asked to stream again."""
        core = self.core
        revived = core.sensors.revive(BRIDGE.rdt_revive_after)
        if revived:
            self.get_logger().warning(
                f"no data from {', '.join(revived)}: asked again to stream",
                throttle_duration_sec=10.0,
            )
        values = core.status_values(time.monotonic())
        refusal = core.gate()
        status = DiagnosticStatus(
            level=DiagnosticStatus.OK if refusal is None else DiagnosticStatus.WARN,
            name=f"{NODE_NAME}/status",
            message="ready" if refusal is None else refusal.message,
            hardware_id="wam",
            values=[KeyValue(key=k, value=v) for k, v in values.items()],
        )
        self.status_pub.publish(status)
        self.publish_diagnostics(status)

    def ros_time(self) -> float:
        """The node's clock now [s] (the time drivers stamp their messages with)."""
        return self.get_clock().now().nanoseconds * 1e-9

    def fill_sensing(self, answer, joint_state_field: str, stop: StopSensing | None = None) -> None:
        """The hand's sensors, fingertip contacts and joint state (into ``joint_state_field``)
        of a result or a response; with ``stop``, also what fired while a guarded move
        stopped (HandState.reading)."""
        hand = self.core.hand
        reading = hand.reading(stop)
        answer.sensors = [bool(f) for f in reading.fired]
        answer.tip_contacts = tip_contacts_to_msg(
            reading.tip_points, reading.tip_normals, hand.tips(stop)
        )
        setattr(answer, joint_state_field, self.joint_state())

    # ------------------------------------------------------------------ guarded move
    def on_move_goal(self, goal: GuardedMove.Goal) -> GoalResponse:
        if self.arm_motion.busy.locked():
            self.get_logger().warning("guarded_move goal rejected: a move is running")
            return GoalResponse.REJECT
        return GoalResponse.ACCEPT

    def publish_plan(self, q: np.ndarray, t: np.ndarray) -> None:
        goal = self.core.arm.goal(q[1:], t[1:], BRIDGE.goal_time_tolerance)
        self.plan_pub.publish(goal.trajectory)

    def execute_guarded_move(self, handle: ServerGoalHandle) -> GuardedMove.Result:
        goal, result = handle.request, GuardedMove.Result()
        request = MoveRequest(
            lambda q0: goal_via_points(goal, q0),
            goal.stop_on_contact,
            goal.tip_force_threshold,
            goal.pad_force_threshold,
        )
        outcome = self.arm_motion.execute(
            request, lambda: handle.is_cancel_requested, self.context.ok
        )
        result.error_code, result.error_msg = int(outcome.code), outcome.message
        if outcome.ran:
            result.path_fraction = outcome.path_fraction
            self.fill_sensing(result, "final_joint_state", outcome.stop_sensing)
            result.stopped_on_contact = outcome.stopped_on_contact
            result.unconfirmed_stops = outcome.unconfirmed_stops
        {"succeeded": handle.succeed, "canceled": handle.canceled}.get(
            outcome.status, handle.abort
        )()
        return result

    # ------------------------------------------------------------------ hand
    @keep_serving
    def on_hand_command(
        self, req: HandCommand.Request, resp: HandCommand.Response
    ) -> HandCommand.Response:
        if check_hand_command(req, resp):
            refusal = self.core.gate()
            if refusal is not None:
                resp.error_code, resp.error_msg = H.REFUSED, refusal.message
                self.report(refusal.code, refusal.check, f"hand command: {refusal.message}", True)
            elif self.core.options.dry_run:
                resp.error_code, resp.error_msg = H.REFUSED, "dry run: the hand is not commanded"
        if resp.error_code != H.NONE:
            self.get_logger().warning(f"hand_command refused: {resp.error_msg}")
            return resp
        proximal = np.asarray(req.proximal, dtype=float)
        try:
            touched = self.hand_control.run(HandMode(req.mode), req.spread, proximal)
            if touched is not None:
                resp.touched = [bool(f) for f in touched]
        except HandStopped as exc:  # the answer still says where the hand stopped
            resp.error_code, resp.error_msg = H.STOPPED, str(exc)
        except Latched as exc:
            resp.error_code, resp.error_msg = H.REFUSED, str(exc)
            self.report(SafetyCode.ESTOP, "estop", f"hand command: {exc}", True)
            return resp
        except DriverError as exc:
            resp.error_code, resp.error_msg = H.DRIVER_FAILED, str(exc)
            self.get_logger().error(f"hand_command failed: {exc}")
            return resp
        except TimeoutError as exc:
            resp.error_code, resp.error_msg = H.TIMEOUT, str(exc)
            return resp
        self.fill_sensing(resp, "joint_state")
        return resp

    # ------------------------------------------------------------------ services
    @keep_serving
    def on_reset_estop(self, req: Trigger.Request, resp: Trigger.Response) -> Trigger.Response:
        resp.success, resp.message = self.core.estop.reset()
        # one severity per call site: rclpy raises "Logger severity cannot be changed between
        # calls" when one line logs at two
        if resp.success:
            self.get_logger().info(f"E-stop reset: {resp.message}")
        else:
            self.get_logger().warning(f"E-stop reset: {resp.message}")
        return resp

    @keep_serving
    def on_bias(self, req: Trigger.Request, resp: Trigger.Response) -> Trigger.Response:
        resp.success, resp.message = self.core.bias()
        self.get_logger().info(f"bias: {resp.message}")
        return resp

    def _spin_io(self) -> None:
        """Spin the I/O node until shutdown. A callback that fails is logged and the spinning
        goes on (the watchdog and the E-stop run here); during shutdown its publishers' context
        is gone (RCLError), which ends the loop quietly."""
        while not self._closing.is_set() and self.context.ok():
            try:
                self._io_executor.spin_once(timeout_sec=0.05)
            except (ExternalShutdownException, KeyboardInterrupt):
                break
            except Exception as exc:
                if self._closing.is_set() or not self.context.ok():
                    break
                self.get_logger().error(f"I/O callback failed: {type(exc).__name__}: {exc}")

    def destroy_node(self) -> None:
        self._closing.set()
        self._io_thread.join(timeout=1.0)
        self.core.sensors.stop()
        self._io_executor.shutdown(timeout_sec=1.0)
        self.io.destroy_node()
        destroy_action_endpoints(self)
        super().destroy_node()


def main(argv: list[str] | None = None) -> int:
    return run_node(BridgeNode, multi_threaded=True, argv=argv)


if __name__ == "__main__":
    sys.exit(main())
