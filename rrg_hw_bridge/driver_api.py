"""What the bridge's core asks of the drivers below it (ROS-free): the arm, the hand and the
fingertip sensors as protocols, and the errors a driver raises. ``rrg_hw_bridge.ros.drivers``
implements them on the real drivers' ROS interfaces and on RDT over UDP."""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol

import numpy as np


class DriverError(RuntimeError):
    """A driver refused a request or did not answer in time."""


class Latched(DriverError):
    """The E-stop was latched, so the command was not sent."""


#: Runs a motion command only while the E-stop is released, so that no latch lands between
#: the check and the send: gate(command) → (ran, command's value)
#: (rrg_hw_bridge.safety.EStop.run_if_released).
Gate = Callable[[Callable[[], object]], tuple[bool, object]]


def open_gate(command: Callable[[], object]) -> tuple[bool, object]:
    """The gate of a driver without an E-stop: always runs the command."""
    return True, command()


class ResultFuture(Protocol):
    """The answer of a sent arm goal (an rclpy Future or the wam_node stream's)."""

    def done(self) -> bool: ...

    def result(self): ...


class GoalHandle(Protocol):
    """A sent arm goal: cancel it (the controller holds the arm), or wait for its answer."""

    def cancel_goal_async(self): ...

    def get_result_async(self) -> ResultFuture: ...


class ArmDriver(Protocol):
    """The arm's driver: a FollowJointTrajectory controller or Barrett's wam_node."""

    def ready(self) -> bool:
        """Whether the driver can take a goal now."""

    def goal(self, q: np.ndarray, t: np.ndarray, goal_time_tolerance: float):
        """The driver's goal for via-points q (K,7) [rad] at times t (K,) [s]."""

    def send(self, goal) -> GoalHandle:
        """Send a goal through the E-stop's gate (Latched, or DriverError when refused)."""

    def hold(self, q: np.ndarray, hold_time: float) -> None:
        """Hold the arm at q (7,) [rad]."""


class HandDriver(Protocol):
    """Barrett's BarrettHand services."""

    def move_spread(self, spread: float) -> None: ...

    def move_fingers(self, proximal: np.ndarray) -> None: ...

    def finger_velocities(self, velocity: np.ndarray, wait: bool = True) -> None: ...

    def stop(self, spread: float) -> None:
        """Stop every hand motor at once, holding the spread [rad]."""


class FingertipSensors(Protocol):
    """The three fingertip force/torque sensors (Net F/T boxes over RDT, or wrench topics)."""

    #: whether bias() makes the boxes tare their own records (RDT), so that the bridge tares
    #: on records that follow it
    biased_by_box: bool

    def start(self) -> None: ...

    def stop(self) -> None: ...

    def bias(self) -> None: ...

    def reset_latch(self, finger: int) -> None: ...

    def revive(self, silent_s: float) -> list[str]: ...

    def describe(self) -> str: ...

    def status(self) -> dict[str, str]: ...

    def unread(self) -> dict[str, str]: ...
