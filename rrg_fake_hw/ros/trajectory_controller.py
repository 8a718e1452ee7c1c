"""The emulated ros2_control JointTrajectoryController: its FollowJointTrajectory action server
on the emulated arm. Goals are checked (rrg_fake_hw.trajectory_goals.validate_trajectory) as JTC
checks them, a new goal preempts the running one, a cancel holds the arm at once, and feedback
goes out every FEEDBACK_PERIOD."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

from control_msgs.action import FollowJointTrajectory
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.action.server import GoalEvent, ServerGoalHandle
from rclpy.node import Node
from trajectory_msgs.msg import JointTrajectoryPoint

from rrg_common.ros.qos import RESULT_TIMEOUT_S

from ..emulated_robot import PREEMPTED_MESSAGE, EmulatedRobot, Event, GoalState, GoalStatus
from ..fake_hw_core import ARM_JOINTS
from ..trajectory_goals import FEEDBACK_PERIOD, TrajectoryGoals, validate_trajectory

#: Longest wait [s] for the action server to mark a canceled goal as canceling.
CANCEL_STATE_WAIT = 1.0


class TrajectoryController:
    """The action ``action`` (control_msgs/FollowJointTrajectory) on ``node``, driving the
    robot through ``goals``; a cancel the ``fault.ignore_cancel`` parameter ignores is
    reported with ``publish_event``."""

    def __init__(
        self,
        node: Node,
        robot: EmulatedRobot,
        goals: TrajectoryGoals,
        publish_event: Callable[[Event], None],
        action: str,
        group,
    ) -> None:
        self.node, self.robot, self.goals = node, robot, goals
        self._publish_event = publish_event
        self.server = ActionServer(
            node,
            FollowJointTrajectory,
            action,
            execute_callback=self._execute,
            goal_callback=self._on_goal,
            handle_accepted_callback=self._on_accepted,
            cancel_callback=self._on_cancel,
            callback_group=group,
            result_timeout=RESULT_TIMEOUT_S,
        )

    def _ignore_cancel(self) -> bool:
        """Whether the fault.ignore_cancel fault is on."""
        return self.node.get_parameter("fault.ignore_cancel").value

    def _on_goal(self, goal: FollowJointTrajectory.Goal) -> GoalResponse:
        try:
            validate_trajectory(goal.trajectory, self.robot.snapshot(pads=False).arm_q)
        except ValueError as exc:
            self.node.get_logger().error(f"follow_joint_trajectory goal rejected: {exc}")
            return GoalResponse.REJECT
        return GoalResponse.ACCEPT

    def _on_accepted(self, handle: ServerGoalHandle) -> None:
        """Number the goals in the order they are accepted (TrajectoryGoals.accept)."""
        self.goals.accept(bytes(handle.goal_id.uuid))
        handle.execute()

    def _on_cancel(self, handle: ServerGoalHandle) -> CancelResponse:
        goal_id = self.goals.robot_goal(bytes(handle.goal_id.uuid))
        if self._ignore_cancel():
            self._publish_event(Event("cancel_ignored", time.monotonic(), {"goal_id": goal_id}))
        elif goal_id is not None:
            self.robot.cancel(goal_id)
        return CancelResponse.ACCEPT

    def _execute(self, handle: ServerGoalHandle) -> FollowJointTrajectory.Result:
        R = FollowJointTrajectory.Result
        result = R(error_code=R.SUCCESSFUL)
        key = bytes(handle.goal_id.uuid)
        try:
            q, t = validate_trajectory(
                handle.request.trajectory, self.robot.snapshot(pads=False).arm_q
            )
        except ValueError as exc:  # the arm moved since the goal was accepted
            result.error_code, result.error_string = R.INVALID_GOAL, str(exc)
            handle.abort()
            return result
        if handle.is_cancel_requested:
            handle.canceled()
            return result
        started = self.goals.start(key, q, t)
        if started is None:  # a newer goal was accepted before this one started
            result.error_string = PREEMPTED_MESSAGE
            handle._update_state(GoalEvent.CANCEL_GOAL)
            handle.canceled()
            return result
        goal_id, done = started
        try:
            status = self._track(handle, goal_id, done)
        finally:
            self.goals.forget(key, goal_id)
        result.error_string = status.message
        self._conclude(handle, status, result)
        return result

    def _track(self, handle: ServerGoalHandle, goal_id: int, done: threading.Event) -> GoalStatus:
        """Publish feedback until the robot goal finishes, canceling it once a cancel is
        requested; its final status."""
        while not done.wait(FEEDBACK_PERIOD):
            if handle.is_cancel_requested:
                # the server marks a goal canceling after the cancel callback returns: a
                # goal still active then had its cancel arrive before it started running
                running = self.robot.goal_status(goal_id).state is GoalState.ACTIVE
                if running and not self._ignore_cancel():
                    self.robot.cancel(goal_id)
                continue
            self._feedback(handle, goal_id)
        return self.robot.goal_status(goal_id)

    def _conclude(
        self, handle: ServerGoalHandle, status: GoalStatus, result: FollowJointTrajectory.Result
    ) -> None:
        """End the goal's handle as the robot goal ended (JTC's outcomes)."""
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
            result.error_code = FollowJointTrajectory.Result.INVALID_GOAL
            handle.abort()

    def _feedback(self, handle: ServerGoalHandle, goal_id: int) -> None:
        status = self.robot.goal_status(goal_id)
        s = self.robot.snapshot(pads=False)
        fb = FollowJointTrajectory.Feedback(joint_names=list(ARM_JOINTS))
        fb.header.stamp = self.node.get_clock().now().to_msg()
        fb.desired = JointTrajectoryPoint(positions=status.desired.tolist())
        fb.actual = JointTrajectoryPoint(positions=s.arm_q.tolist(), velocities=s.arm_qd.tolist())
        fb.error = JointTrajectoryPoint(positions=(status.desired - s.arm_q).tolist())
        handle.publish_feedback(fb)
