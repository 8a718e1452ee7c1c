"""The arm/hand interface (design §7) as the simulator node and the hardware bridge both serve
it: its state publishers, its servers, and the reading of a GuardedMove goal into joint
via-points, so that both accept the same goals."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from geometry_msgs.msg import WrenchStamped
from rclpy.action import ActionServer, CancelResponse
from rclpy.node import Node
from rclpy.publisher import Publisher
from sensor_msgs.msg import JointState

from rrg_common.ros.frames import RobotFramesPublisher
from rrg_common.ros.liveliness import announce
from rrg_common.ros.msg_conversions import ARM_JOINT_NAMES
from rrg_common.ros.qos import RESULT_TIMEOUT_S
from rrg_models import wam
from rrg_models.config import HAND
from rrg_models.description.urdf_robot import robot_urdf
from rrg_models.trajectory import GOAL_START_TOLERANCE, DensePath, GoalError, sample_times
from rrg_msgs.action import GuardedMove
from rrg_msgs.msg import ContactPads
from rrg_msgs.srv import HandCommand

#: The name the arm/hand interface (the simulator, or the bridge) announces itself under.
INTERFACE_PEER = "arm_hand_interface"


def goal_via_points(goal: GuardedMove.Goal, q0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(q (M,7) [rad], t (M,) [s]) of a goal in ARM_JOINT_NAMES order, the arm's configuration
    q0 prepended at t = 0; without timing (all times zero), the executor's default timing
    (trajectory.sample_times). Joint limits are the caller's to check. Raises GoalError."""
    R = GuardedMove.Result
    traj = goal.trajectory
    if sorted(traj.joint_names) != sorted(ARM_JOINT_NAMES) or len(traj.joint_names) != 7:
        raise GoalError(
            f"joint_names must be the 7 arm joints {list(ARM_JOINT_NAMES)}, got "
            f"{list(traj.joint_names)}",
            R.INVALID_TRAJECTORY,
        )
    if not traj.points:
        raise GoalError("the trajectory has no points", R.INVALID_TRAJECTORY)
    if any(len(p.positions) != 7 for p in traj.points):
        raise GoalError("every point needs 7 positions", R.INVALID_TRAJECTORY)
    order = [list(traj.joint_names).index(n) for n in ARM_JOINT_NAMES]
    q = np.array([np.asarray(p.positions)[order] for p in traj.points])
    t = np.array([p.time_from_start.sec + 1e-9 * p.time_from_start.nanosec for p in traj.points])
    if not np.all(np.isfinite(q)):
        raise GoalError("non-finite positions", R.INVALID_TRAJECTORY)
    if np.any(np.diff(t) < 0.0):
        raise GoalError("time_from_start must not decrease", R.INVALID_TRAJECTORY)
    q = np.vstack([q0, q])
    if not np.any(t > 0.0):  # no timing: the executor's default speeds
        return q, sample_times(DensePath(wam.fk(q), q, np.zeros(len(q), int)))
    if t[0] == 0.0 and np.abs(q[1] - q0).max() > GOAL_START_TOLERANCE:
        raise GoalError(
            "the first point is away from the arm's configuration at time 0",
            R.INVALID_TRAJECTORY,
        )
    return q, np.r_[0.0, t]


def check_hand_command(req: HandCommand.Request, resp: HandCommand.Response) -> bool:
    """Whether a hand command is valid; if not, its error code and message are set on resp."""
    Q, R = HandCommand.Request, HandCommand.Response
    proximal = np.asarray(req.proximal, dtype=float)
    lo, hi = HAND.proximal_range
    if req.mode not in (Q.MODE_POSITION, Q.MODE_OPEN, Q.MODE_CLOSE, Q.MODE_CLOSE_GUARDED):
        resp.error_code, resp.error_msg = R.INVALID_MODE, f"unknown mode {req.mode}"
    elif not HAND.spread_range[0] <= req.spread <= HAND.spread_range[1]:
        resp.error_code = R.OUT_OF_RANGE
        resp.error_msg = f"spread {req.spread} outside {HAND.spread_range} rad"
    elif req.mode == Q.MODE_POSITION and not np.all((proximal >= lo) & (proximal <= hi)):
        resp.error_code = R.OUT_OF_RANGE
        resp.error_msg = f"proximal {proximal.tolist()} outside {(lo, hi)} rad"
    return resp.error_code == R.NONE


@dataclass
class StatePublishers:
    """The interface's state topics: ``joint_states``, ``fingertip{1,2,3}/wrench`` (each Nano17 in
    its own frame) and ``contact_pads`` (relative names: the node's namespace applies), and the
    robot's description and frames (rrg_common.ros.frames: ``/robot_description``, ``/tf_static``,
    and ``/tf`` from each joint state)."""

    joints: Publisher
    wrenches: list[Publisher]
    pads: Publisher
    frames: RobotFramesPublisher | None

    @classmethod
    def create(cls, node: Node, frames: bool = True) -> StatePublishers:
        """frames: also the robot's description and frames (False: none)."""
        return cls(
            node.create_publisher(JointState, "joint_states", 10),
            [node.create_publisher(WrenchStamped, f"fingertip{i}/wrench", 10) for i in (1, 2, 3)],
            node.create_publisher(ContactPads, "contact_pads", 10),
            RobotFramesPublisher(node, robot_urdf()) if frames else None,
        )

    def publish_joints(self, joint_state: JointState) -> None:
        """The joint states, and the robot's frames at them."""
        self.joints.publish(joint_state)
        if self.frames is not None:
            self.frames.publish(joint_state)


def serve_arm_hand_interface(
    node: Node,
    execute_guarded_move: Callable,
    accept_move: Callable,
    hand_command: Callable,
    group,
) -> ActionServer:
    """The ``guarded_move`` action (goals filtered by ``accept_move``, cancellable) and the
    ``hand_command`` service, announced as the peer INTERFACE_PEER (rrg_common.ros.liveliness), so
    that the executor notices at once when the interface dies."""
    node.create_service(HandCommand, "hand_command", hand_command, callback_group=group)
    announce(node, INTERFACE_PEER)
    return ActionServer(
        node,
        GuardedMove,
        "guarded_move",
        execute_callback=execute_guarded_move,
        goal_callback=accept_move,
        cancel_callback=lambda _: CancelResponse.ACCEPT,
        callback_group=group,
        result_timeout=RESULT_TIMEOUT_S,
    )
