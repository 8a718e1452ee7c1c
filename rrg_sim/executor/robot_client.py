"""The executor core's ``Robot`` (rrg_sim.executor.wrt_executor) over ROS: action and service
clients of the arm/hand interface node (the simulator, or the hardware bridge), for use inside
a callback of a MultiThreadedExecutor (the clients must be in a reentrant callback group).

Joint angles come from ``/rrg/joint_states`` and from the results of the commands themselves,
whichever is newer; the sensor reading is the one the last command returned (at a guarded
move's stop, after closing the hand).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

import numpy as np
from builtin_interfaces.msg import Duration
from rclpy.node import Node
from sensor_msgs.msg import JointState
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from rrg_common.ros.arm_hand_interface import INTERFACE_PEER
from rrg_common.ros.futures import ThreadSafeActionClient, WaitInterrupted, WaitTimeout, wait_for
from rrg_common.ros.liveliness import PeerLost, PeerWatch
from rrg_common.ros.msg_conversions import (
    ARM_JOINT_NAMES,
    PROXIMAL_JOINT_NAMES,
    SPREAD_JOINT_NAME,
    stamp_to_ns,
    tip_contacts_from_msg,
)
from rrg_models import wam
from rrg_models.config import HAND, N_SENSORS
from rrg_models.hand_sensing import Reading
from rrg_msgs.action import GuardedMove
from rrg_msgs.srv import HandCommand
from rrg_sim.executor.robot_errors import (
    ForceCeilingStop,
    HandStopped,
    MotionCanceled,
    MotionFailed,
    RobotFault,
    StaleDataStop,
)

#: An opening of the hand that the safety layer stopped midway is sent again, at most
#: OPEN_RETRIES times, each after OPEN_RETRY_PAUSE_S [s] (chosen): an opening finger that
#: strikes the object spikes its fingertip load for a few samples (15 N and 0.24 N m for
#: ~30 ms, an emulated drill grasp), each stop leaves the fingers further open, and the way out
#: of the contact is to open (one opening was stopped twice, by fingers 1 and 2 in turn, on
#: the tactile pucks). The bridge gates and guards every try like the first: an E-stop or a
#: stale stream refuses it, and the last stop is the caller's.
OPEN_RETRIES = 3
OPEN_RETRY_PAUSE_S = 0.5


def duration(seconds: float) -> Duration:
    sec = int(np.floor(seconds))
    return Duration(sec=sec, nanosec=int(round((seconds - sec) * 1e9)) % 1_000_000_000)


class RosRobot:
    """Robot interface over ``guarded_move``, ``hand_command`` and ``joint_states`` (relative
    names: the node's namespace applies). ``interrupted`` is polled while waiting."""

    def __init__(self, node: Node, callback_group, timeout_s: float):
        self.node = node
        self.timeout_s = timeout_s
        self.move_client = ThreadSafeActionClient(
            node, GuardedMove, "guarded_move", callback_group=callback_group
        )
        self.hand_client = node.create_client(
            HandCommand, "hand_command", callback_group=callback_group
        )
        node.create_subscription(
            JointState, "joint_states", self.on_joint_state, 10, callback_group=callback_group
        )
        #: the interface's liveliness: a wait for it ends with RobotFault as soon as it dies
        self.interface = PeerWatch(node, INTERFACE_PEER, callback_group, self._on_interface)
        self.interrupted: Callable[[], bool] = lambda: False
        #: lone pad trips the interface did not confirm, summed over its guarded moves
        self.unconfirmed_stops = 0
        self._lock = threading.Lock()
        self._joints: dict[str, float] = {}
        self._stamp = -1
        self._reading = Reading(
            np.zeros(N_SENSORS, bool), np.full((3, 3), np.nan), np.full((3, 3), np.nan)
        )

    # ------------------------------------------------------------------ state
    def _on_interface(self, alive: bool) -> None:
        if alive:
            self.node.get_logger().info("the arm/hand interface is up")
        else:
            self.node.get_logger().error(
                "robot fault: the arm/hand interface went away; nothing moves until it is back"
            )

    def on_joint_state(self, msg: JointState) -> None:
        with self._lock:
            if stamp_to_ns(msg.header.stamp) >= self._stamp:
                self._stamp = stamp_to_ns(msg.header.stamp)
                self._joints.update(zip(msg.name, msg.position))

    def ready(self) -> bool:
        """Whether the joint states of every joint the executor needs have arrived."""
        names = (*ARM_JOINT_NAMES, SPREAD_JOINT_NAME, *PROXIMAL_JOINT_NAMES)
        return (
            self.interface.alive
            and all(n in self._joints for n in names)
            and self.move_client.server_is_ready()
            and self.hand_client.service_is_ready()
        )

    def synced_since(self, since_ns: int) -> bool:
        """Whether a joint state stamped at or after ``since_ns`` (ROS time) has arrived: the
        state is fresh even if the robot was moved meanwhile by someone else (a reset)."""
        return self._stamp >= since_ns

    def arm_q(self) -> np.ndarray:
        return np.array([self._joints[n] for n in ARM_JOINT_NAMES])

    def hand_angles(self) -> tuple[float, np.ndarray]:
        return float(self._joints[SPREAD_JOINT_NAME]), np.array(
            [self._joints[n] for n in PROXIMAL_JOINT_NAMES]
        )

    def hand_pose(self) -> np.ndarray:
        return wam.fk(self.arm_q())

    def reading(self) -> Reading:
        return self._reading

    def _sensed(self, joint_state: JointState, sensors, tip_contacts) -> None:
        self.on_joint_state(joint_state)
        points, normals = tip_contacts_from_msg(tip_contacts)
        self._reading = Reading(np.asarray(sensors, dtype=bool), points, normals)

    def _wait(self, future, what: str):
        try:
            return wait_for(future, self.timeout_s, self.interrupted, self.interface)
        except WaitTimeout as exc:
            raise MotionFailed(f"{what}: {exc}") from exc
        except PeerLost as exc:
            raise RobotFault(f"{what}: the arm/hand interface went away") from exc

    # ------------------------------------------------------------------ commands
    def follow(self, q: np.ndarray, t: np.ndarray, guard: bool) -> float | None:
        traj = JointTrajectory(
            joint_names=list(ARM_JOINT_NAMES),
            points=[
                JointTrajectoryPoint(positions=qk.tolist(), time_from_start=duration(tk))
                for qk, tk in zip(q, t)
            ],
        )
        handle = self._wait(
            self.move_client.send_goal_async(
                GuardedMove.Goal(trajectory=traj, stop_on_contact=guard)
            ),
            "guarded_move",
        )
        if not handle.accepted:
            raise MotionFailed("guarded_move rejected the goal")
        try:
            answer = self._wait(handle.get_result_async(), "guarded_move")
        except WaitInterrupted as exc:
            wait_for(handle.cancel_goal_async(), 10.0)
            raise MotionCanceled("guarded move canceled") from exc
        res = answer.result
        R = GuardedMove.Result
        if guard and res.error_code == R.FORCE_LIMIT and res.stopped_on_contact:
            # the safety layer held the arm at a contact whose first samples spiked over the
            # force ceiling (an impact): the guarded move still stopped where it touched
            self.node.get_logger().warning(
                f"guarded move stopped by the force ceiling ({res.error_msg}): taken as its "
                "stop on contact"
            )
        elif res.error_code == R.FORCE_LIMIT:
            raise ForceCeilingStop(f"guarded_move failed ({res.error_code}): {res.error_msg}")
        elif res.error_code == R.STALE_DATA:
            raise StaleDataStop(f"guarded_move failed ({res.error_code}): {res.error_msg}")
        elif res.error_code != R.NONE:
            raise MotionFailed(f"guarded_move failed ({res.error_code}): {res.error_msg}")
        self._sensed(res.final_joint_state, res.sensors, res.tip_contacts)
        self.unconfirmed_stops += int(res.unconfirmed_stops)
        return res.path_fraction * (len(q) - 1) if res.stopped_on_contact else None

    def _hand(self, mode: int, spread: float, proximal) -> HandCommand.Response:
        req = HandCommand.Request(
            mode=mode,
            spread=float(np.clip(spread, *HAND.spread_range)),
            proximal=np.clip(np.broadcast_to(proximal, 3), *HAND.proximal_range),
        )
        try:
            resp = self._wait(self.hand_client.call_async(req), "hand_command")
        except WaitInterrupted as exc:
            raise MotionCanceled("hand command interrupted") from exc
        if resp.error_code != HandCommand.Response.NONE:
            error = HandStopped if resp.error_code == HandCommand.Response.STOPPED else MotionFailed
            raise error(f"hand_command failed ({resp.error_code}): {resp.error_msg}")
        self._sensed(resp.joint_state, resp.sensors, resp.tip_contacts)
        return resp

    def move_hand(self, spread: float, proximal) -> None:
        """Move the hand to its targets; an opening (no proximal target beyond where its finger
        is) that the safety layer stopped midway is tried again (OPEN_RETRIES)."""
        # a finger pushed just past its open stop (a reading of -1 mrad) still opens to it
        at = np.maximum(self.hand_angles()[1], HAND.proximal_range[0])
        targets = np.clip(np.broadcast_to(proximal, 3), *HAND.proximal_range)
        opening = bool(np.all(targets <= at + 1e-3))
        for attempt in range(OPEN_RETRIES + 1):
            try:
                self._hand(HandCommand.Request.MODE_POSITION, spread, proximal)
                return
            except HandStopped as exc:
                if not opening or attempt == OPEN_RETRIES:
                    raise
                self.node.get_logger().warning(
                    f"the hand's opening was stopped ({exc}): opening again in "
                    f"{OPEN_RETRY_PAUSE_S} s (try {attempt + 2} of {OPEN_RETRIES + 1})"
                )
                time.sleep(OPEN_RETRY_PAUSE_S)

    def close_hand(self, guarded: bool = False) -> np.ndarray:
        mode = HandCommand.Request.MODE_CLOSE_GUARDED if guarded else HandCommand.Request.MODE_CLOSE
        return np.asarray(self._hand(mode, self.hand_angles()[0], 0.0).touched, dtype=bool)
