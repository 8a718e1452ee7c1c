"""Barrett's wam_node interfaces on the emulated robot: the arm's (WamNodeInterface: the
real-time joint position stream, holdJointPosition, moveToJointPosition, idle) and the
BarrettHand's services (BHandServices), whose moves start and whose calls return at once, as
wam_node's do, and the tactile message of Barrett's BarrettHand node (tactile_message). The
behaviour is EmulatedRobot's."""

from __future__ import annotations

import threading
import time

import numpy as np
from bhand_srvs.srv import FingerPosition, FingerVelocity, GraspPosition, SpreadPosition
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from std_srvs.srv import SetBool, Trigger
from wam_msgs.msg import RTJointPositions, TactilePressure, TactilePressureArray
from wam_srvs.srv import JointMove

from rrg_common.ros.node_main import keep_serving
from rrg_hw_bridge.tactile import CELLS, pucks_from_pads
from rrg_models.config import HAND

from ..emulated_robot import EmulatedRobot, GoalState
from ..fake_hw_core import NODE_NAME
from ..trajectory_goals import FEEDBACK_PERIOD


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

    def get_logger(self):
        """The node's logger (keep_serving logs a failed callback through it)."""
        return self.node.get_logger()

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


class BHandServices:
    """Barrett's BarrettHand services (wam_node) on the emulated hand: ``/bhand/moveTo*``
    (bhand_srvs) and ``/bhand/openGrasp``, ``/bhand/closeGrasp``, ``/bhand/idle``
    (std_srvs/Trigger)."""

    def __init__(self, node: Node, robot: EmulatedRobot, group):
        self.node, self.robot = node, robot
        srv = lambda kind, name, cb: node.create_service(kind, name, cb, callback_group=group)
        srv(FingerPosition, "/bhand/moveToFingerPositions", self.on_finger_positions)
        srv(SpreadPosition, "/bhand/moveToSpreadPosition", self.on_spread_position)
        srv(FingerVelocity, "/bhand/moveToFingerVelocities", self.on_finger_velocities)
        srv(GraspPosition, "/bhand/moveToGraspPosition", self.on_grasp_position)
        srv(Trigger, "/bhand/openGrasp", self.on_open_grasp)
        srv(Trigger, "/bhand/closeGrasp", self.on_close_grasp)
        srv(Trigger, "/bhand/idle", self.on_idle)

    def get_logger(self):
        """The node's logger (keep_serving logs a failed callback's exception on it)."""
        return self.node.get_logger()

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


def tactile_message(pads: np.ndarray, rng: np.random.Generator) -> TactilePressureArray:
    """Barrett's tactile message carrying the pads' forces (7,) [N] on the pucks' cells
    (rrg_hw_bridge.tactile; ``rng`` picks where a contact presses)."""
    levels = [0] * CELLS  # the node's display levels: not emulated
    return TactilePressureArray(
        tactile_pressures=[
            TactilePressure(pressure=cells.tolist(), normalized_pressure=levels)
            for cells in pucks_from_pads(pads, rng)
        ]
    )
