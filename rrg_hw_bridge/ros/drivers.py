"""Clients of the real drivers below the bridge, one class per backend: the arm's
FollowJointTrajectory controller, Barrett's BarrettHand services, and the fingertip sensors
(the built-in Net F/T RDT client, or WrenchStamped topics of an existing driver).

Every class is used from inside callbacks of a MultiThreadedExecutor (reentrant callback
group) and never blocks longer than its timeout.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from bhand_srvs.srv import FingerPosition, FingerVelocity, SpreadPosition
from builtin_interfaces.msg import Duration
from control_msgs.action import FollowJointTrajectory
from geometry_msgs.msg import WrenchStamped
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from std_srvs.srv import Trigger
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from rrg_sim.ros_common.futures import ThreadSafeActionClient, WaitTimeout, wait_for

from ..rdt import Calibration, RdtClient, RdtSample

#: Longest wait [s] for a driver's answer to one request (a goal, a cancel, a service call).
DRIVER_TIMEOUT = 2.0


class DriverError(RuntimeError):
    """A driver refused a request or did not answer in time."""


def duration(seconds: float) -> Duration:
    sec = int(np.floor(seconds))
    return Duration(sec=sec, nanosec=int(round((seconds - sec) * 1e9)) % 1_000_000_000)


class TrajectoryArm:
    """The arm through ``control_msgs/action/FollowJointTrajectory`` (any ros2_control arm)."""

    def __init__(self, node: Node, action_name: str, joint_names: tuple[str, ...], group):
        self.joint_names = joint_names
        self.client = ThreadSafeActionClient(
            node, FollowJointTrajectory, action_name, callback_group=group
        )
        self.action_name = action_name

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
        """Send a goal; returns its ClientGoalHandle once accepted (DriverError otherwise)."""
        try:
            handle = wait_for(self.client.send_goal_async(goal), DRIVER_TIMEOUT)
        except WaitTimeout as exc:
            raise DriverError(f"{self.action_name}: no answer to the goal") from exc
        if not handle.accepted:
            raise DriverError(f"{self.action_name} rejected the goal")
        return handle


class BarrettHandServices:
    """The BarrettHand through Barrett's ROS 2 services (barrett-ros2-pkg's wam_node)."""

    def __init__(self, node: Node, prefix: str, group):
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

    def _call(self, client, request, wait: bool = True):
        future = client.call_async(request)
        if not wait:
            return future
        try:
            response = wait_for(future, DRIVER_TIMEOUT)
        except WaitTimeout as exc:
            raise DriverError(f"{client.srv_name}: no answer") from exc
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
        """Command proximal velocities (3,) [rad/s]; 0 stops (and holds) that finger."""
        self._call(
            self.finger_velocity,
            FingerVelocity.Request(velocity=np.asarray(velocity, dtype=float).tolist()),
            wait=wait,
        )

    def idle(self) -> None:
        self._call(self.idle_client, Trigger.Request(), wait=False)


class RdtSensors:
    """Three Net F/T boxes (one Nano17 each) through the built-in RDT client."""

    def __init__(
        self,
        hosts: list[str],
        port: int,
        calibration: Calibration,
        on_wrench: Callable[[int, np.ndarray, float], None],
        on_fault: Callable[[int, str, str], None],
    ):
        self.clients = []
        for i, host in enumerate(hosts):

            def sample(s: RdtSample, i=i) -> None:
                if not s.status:  # a record with a status error is reported by on_fault
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

    def stop(self) -> None:
        for c in self.clients:
            c.stop()

    def describe(self) -> str:
        return ", ".join(f"{c.name}@{c.host}" for c in self.clients)

    def status(self) -> dict[str, str]:
        """Each box's receive rate [Hz], lost records, status and length errors, and age [s]."""
        out = {}
        for c in self.clients:
            h = c.health()
            out[c.name] = (
                f"{h.rate_hz:.0f} Hz, {h.lost} lost, {h.status_errors} status errors, "
                f"{h.length_errors} length errors, age {h.age_s:.3f} s"
            )
        return out


class WrenchTopicSensors:
    """Fingertip wrenches from ``geometry_msgs/WrenchStamped`` topics of an existing driver."""

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

    def stop(self) -> None:
        pass

    def describe(self) -> str:
        return ", ".join(self.topics)

    def status(self) -> dict[str, str]:
        return {}
