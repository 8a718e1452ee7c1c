"""The executor node (design §7): executes a WRT at an estimate e on the arm/hand interface and
publishes what it observed.

    python -m rrg_sim.executor.executor_node

Serves ``/rrg/execute_wrt`` (rrg_msgs/ExecuteWrt): τ(e), a continuous IK path, timed joint
via-points sent as guarded moves to ``/rrg/guarded_move``, closing through
``/rrg/hand_command``, and the observation (published on ``/rrg/observation`` and returned). The
hand is left where the WRT stopped (a goal grasp closed on the object, so that it can be judged
or lifted): ``/rrg/retreat`` (rrg_msgs/Retreat), or the next execution, retreats from it. Every
retreat is published on ``/rrg/retreated`` (rrg_msgs/Retreated), so the estimator applies its
transition. Both topics are latched streams (qos.STREAM): a restarted estimator receives the
latest of each. The sequence is the ROS-free ``rrg_sim.executor.wrt_executor.WrtExecutor`` (the
physics world runs the same one in-process); this node drives it through ``RosRobot``, so it
runs unchanged against a hardware bridge. Its health (the interface, the last execution) goes
on ``/diagnostics`` once a second (``executor: status``).

It lives in rrg_sim because everything it needs is there (the object catalogue with the
WRTs, the WAM's IK, the path planning), and it is robot-side software: it never reads a belief.
"""

from __future__ import annotations

import sys
import threading
import time

import numpy as np
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.action.server import ServerGoalHandle
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.node import Node
from std_msgs.msg import Header

from rrg_common.ros.diagnostics import ERROR, WARN, Health, NodeDiagnostics
from rrg_common.ros.liveliness import announce
from rrg_common.ros.msg_conversions import WORLD_FRAME, observation_to_msg, planar_from_msg
from rrg_common.ros.node_main import destroy_action_endpoints, keep_serving, run_node
from rrg_common.ros.parameters import Param, declare
from rrg_common.ros.qos import RESULT_TIMEOUT_S, STREAM
from rrg_models.objects import get_object, object_names, unknown_object_message
from rrg_models.trajectory import InfeasiblePath
from rrg_msgs.action import ExecuteWrt
from rrg_msgs.msg import Observation as ObservationMsg
from rrg_msgs.msg import Retreated
from rrg_msgs.srv import Retreat
from rrg_sim.config import WORLD_PROFILES, world_profile
from rrg_sim.executor.robot_client import RosRobot
from rrg_sim.executor.robot_errors import (
    ExecutionStopped,
    MotionCanceled,
    MotionFailed,
    RobotFault,
)
from rrg_sim.executor.wrt_executor import WrtExecutor

NODE_NAME = "executor"
NAMESPACE = "rrg"
R = ExecuteWrt.Result


#: The node's parameters (rrg_common.ros.parameters).
PARAMETERS: tuple[Param, ...] = (
    Param(
        "motion_timeout",
        300.0,
        "Longest wait [s] for one guarded move or hand command",
        read_only=True,
        low=1.0,
        high=3600.0,
    ),
    Param(
        "ready_timeout",
        30.0,
        "Longest wait [s] for the arm/hand interface when a goal arrives",
        low=0.1,
        high=600.0,
    ),
    Param(
        "world_profile",
        "nominal",
        (
            "World profile the robot is taken to be in "
            f"(rrg_sim.config.world_profile: {', '.join(WORLD_PROFILES)}, …): where its "
            "calibration or the table's height is uncertain, a goal grasp and its probe "
            "begin with the object's table touch (rrg_sim.table_touch)"
        ),
        read_only=True,
    ),
)


class ExecutorNode(Node):
    """ExecuteWrt and retreat over the arm/hand interface."""

    def __init__(self) -> None:
        super().__init__(NODE_NAME, namespace=NAMESPACE)
        declare(self, PARAMETERS)
        self.touch_table = world_profile(self.get_parameter("world_profile").value).uncertain_height
        group = ReentrantCallbackGroup()
        self.robot = RosRobot(self, group, self.get_parameter("motion_timeout").value)
        self.core = WrtExecutor(self.robot)
        self._busy = threading.Lock()
        self.obs_pub = self.create_publisher(ObservationMsg, "observation", STREAM)
        self.retreated_pub = self.create_publisher(Retreated, "retreated", STREAM)
        self._last_observation: ObservationMsg | None = None  # of the WRT a retreat would leave
        #: for /diagnostics: the goal running, and the last execution's (goal, result, duration
        #: [s])
        self._running = ""
        self._last_execution: tuple[str, str, float] | None = None
        self._executions = 0
        ActionServer(
            self,
            ExecuteWrt,
            "execute_wrt",
            execute_callback=self.execute_wrt,
            goal_callback=self.on_goal,
            cancel_callback=lambda _: CancelResponse.ACCEPT,
            callback_group=group,
            result_timeout=RESULT_TIMEOUT_S,
        )
        self.create_service(Retreat, "retreat", self.on_retreat, callback_group=group)
        announce(self, NODE_NAME)
        self.diagnostics = NodeDiagnostics(self, self.health)
        self.get_logger().info("executor ready")

    def destroy_node(self) -> None:
        destroy_action_endpoints(self)
        super().destroy_node()

    def health(self) -> Health:
        """For /diagnostics: whether the arm/hand interface is ready (WARN until it is, ERROR
        once it is lost: a robot fault), the WRT running, the last execution's result and
        duration, and the lone pad trips the interface did not confirm."""
        ready = self.robot.ready()
        health = Health() if ready else Health(WARN, "the arm/hand interface is not ready")
        health.values["arm/hand interface ready"] = str(ready)
        health.values["executing"] = self._running or "nothing"
        goal, result, seconds = self._last_execution or ("none", "none", None)
        health.values["last execution"] = goal
        health.values["last execution result"] = result
        health.values["last execution duration [s]"] = (
            "none" if seconds is None else f"{seconds:.2f}"
        )
        health.values["executions"] = str(self._executions)
        health.values["unconfirmed stops"] = str(self.robot.unconfirmed_stops)
        return health.peers([self.robot.interface], lost_level=ERROR)

    def on_goal(self, goal: ExecuteWrt.Goal) -> GoalResponse:
        if self._busy.locked():
            self.get_logger().warning(f"execute_wrt {goal.wrt_name} rejected: busy")
            return GoalResponse.REJECT
        return GoalResponse.ACCEPT

    def wait_ready(self) -> bool:
        """Wait until the arm/hand interface is up and its joint states are fresh (stamped after
        this call: the robot may have been moved meanwhile, e.g. by a simulator reset)."""
        pause = threading.Event()
        now = self.get_clock().now().nanoseconds
        deadline = now + self.get_parameter("ready_timeout").value * 1e9
        while not (self.robot.ready() and self.robot.synced_since(now)):
            if self.get_clock().now().nanoseconds > deadline or not self.context.ok():
                return False
            pause.wait(0.005)
        return True

    def execute_wrt(self, handle: ServerGoalHandle) -> ExecuteWrt.Result:
        goal, result = handle.request, ExecuteWrt.Result()
        t0, self._running = time.monotonic(), f"{goal.object_name}/{goal.wrt_name}"
        e = planar_from_msg(goal.estimate)
        if goal.object_name not in object_names():
            result.error_code, result.error_msg = (
                R.UNKNOWN_OBJECT,
                unknown_object_message(goal.object_name),
            )
        elif goal.wrt_name not in [w.name for w in get_object(goal.object_name).wrts()]:
            result.error_code = R.UNKNOWN_WRT
            result.error_msg = f"{goal.object_name} has no WRT {goal.wrt_name!r}"
        elif not np.all(np.isfinite(e)):
            result.error_code, result.error_msg = R.INFEASIBLE, f"non-finite estimate {e.tolist()}"
        elif not self.wait_ready():
            result.error_code, result.error_msg = (
                R.MOTION_FAILED,
                "the arm/hand interface is not available",
            )
        else:
            with self._busy:
                self.run(handle, get_object(goal.object_name).wrt(goal.wrt_name), e, result)
        if result.error_code == R.NONE:
            handle.succeed()
        elif result.error_code == R.CANCELED and handle.is_cancel_requested:
            handle.canceled()
        else:
            handle.abort()
            self.get_logger().error(
                f"execute_wrt {goal.object_name}/{goal.wrt_name} failed: {result.error_msg}"
            )
        outcome = "ok" if result.error_code == R.NONE else f"error {result.error_code}"
        self._last_execution = (
            self._running,
            outcome + (f": {result.error_msg}" if result.error_msg else ""),
            time.monotonic() - t0,
        )
        self._running, self._executions = "", self._executions + 1
        self.diagnostics.force_update()
        return result

    def run(self, handle: ServerGoalHandle, wrt, e: np.ndarray, result: ExecuteWrt.Result) -> None:
        def progress(phase: str, fraction: float) -> None:
            handle.publish_feedback(ExecuteWrt.Feedback(phase=phase, progress=fraction))

        self.robot.interrupted = lambda: handle.is_cancel_requested or not self.context.ok()
        try:
            if self.core.last is not None:  # the previous WRT's retreat, announced like any other
                self.retreat(progress)
            touch = get_object(handle.request.object_name).table_touch if self.touch_table else None
            obs = self.core.execute(wrt, e, progress, touch=touch)
            msg = observation_to_msg(
                obs, handle.request.object_name, wrt.name, e, self.get_clock().now().to_msg()
            )
            self._last_observation = msg
            self.obs_pub.publish(msg)
            result.observation = msg
            self.get_logger().info(
                f"{wrt.name} at {np.round(e, 3).tolist()}: contact={obs.contact}, "
                f"progress {obs.progress:.3f} m, sensors {np.flatnonzero(obs.sensors).tolist()}"
            )
        except InfeasiblePath as exc:
            result.error_code, result.error_msg = (
                R.INFEASIBLE,
                f"no IK path for {wrt.name} at {e.tolist()}: {exc}",
            )
        except MotionCanceled as exc:
            result.error_code, result.error_msg = R.CANCELED, str(exc)
        except RobotFault as exc:
            result.error_code, result.error_msg = R.ROBOT_FAULT, str(exc)
        except ExecutionStopped as exc:
            result.error_code, result.error_msg = R.SAFETY_STOP, str(exc)
        except MotionFailed as exc:
            result.error_code, result.error_msg = R.MOTION_FAILED, str(exc)
        except Exception as exc:
            result.error_code, result.error_msg = R.UNKNOWN, f"{type(exc).__name__}: {exc}"
        finally:
            self.robot.interrupted = lambda: not self.context.ok()

    def retreat(self, progress=None) -> Header:
        """Retreat from the last WRT and publish it on /rrg/retreated; returns its header."""
        self.core.retreat(progress)
        obs, self._last_observation = self._last_observation, None
        header = Header(stamp=self.get_clock().now().to_msg(), frame_id=WORLD_FRAME)
        event = Retreated(header=header)
        if obs is not None:
            event.observation_stamp, event.object_name, event.wrt_name = (
                obs.header.stamp,
                obs.object_name,
                obs.wrt_name,
            )
        self.retreated_pub.publish(event)
        return header

    @keep_serving
    def on_retreat(self, req: Retreat.Request, resp: Retreat.Response) -> Retreat.Response:
        if not self.wait_ready():
            resp.error_code, resp.error_msg = (
                Retreat.Response.UNAVAILABLE,
                "the arm/hand interface is not available",
            )
            return resp
        with self._busy:
            try:
                resp.header = self.retreat()
            except RobotFault as exc:
                resp.error_code, resp.error_msg = Retreat.Response.ROBOT_FAULT, str(exc)
            except (MotionFailed, MotionCanceled, InfeasiblePath) as exc:
                resp.error_code, resp.error_msg = (
                    Retreat.Response.MOTION_FAILED,
                    f"retreat failed: {exc}",
                )
        if resp.error_code != Retreat.Response.NONE:
            self.get_logger().error(resp.error_msg)
        return resp


def main(argv: list[str] | None = None) -> int:
    return run_node(ExecutorNode, multi_threaded=True, argv=argv)


if __name__ == "__main__":
    sys.exit(main())
