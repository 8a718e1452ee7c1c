"""A node's health on ``/diagnostics`` (diagnostic_msgs/DiagnosticArray) once a second, as ROS
drivers publish theirs with diagnostic_updater (not installed: the venv's ROS comes from pip,
which has diagnostic_msgs but not diagnostic_updater; this is the small part of it RRG needs).
Foxglove's Diagnostics panel and rqt_robot_monitor (through a stock diagnostic_aggregator) show
them without any RRG code.

A node makes one ``NodeDiagnostics`` with a check, a callable that returns its ``Health`` now
(level, message, key-values whose keys carry their units). A timer in a callback group of its
own publishes it under the name ``"<node name>: <aspect>"`` (diagnostic_updater's convention)
with the node's hardware_id; ``force_update`` (diagnostic_updater's name) publishes it at once,
after an event worth seeing (an update, an execution, a grasp's end), so a short run's bag holds
it too. A check that raises is reported as ERROR, and the node goes on.
``Health.peers`` adds the PeerWatches (rrg_common.ros.liveliness) a node depends on: a peer
not up raises the level.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.node import Node

from rrg_common.ros.liveliness import PeerWatch

TOPIC = "/diagnostics"
#: Period [s] of the reports (diagnostic_updater's default period).
PERIOD_S = 1.0
#: The levels, as ints (diagnostic_msgs/DiagnosticStatus holds each as one byte).
OK, WARN, ERROR, STALE = (
    lv[0]
    for lv in (
        DiagnosticStatus.OK,
        DiagnosticStatus.WARN,
        DiagnosticStatus.ERROR,
        DiagnosticStatus.STALE,
    )
)


@dataclass
class Health:
    """What a node reports: a level (OK … STALE), a one-line message and key-values."""

    level: int = OK
    message: str = "ready"
    values: dict[str, str] = field(default_factory=dict)

    def escalate(self, level: int, message: str) -> None:
        """A problem of ``level``: the level rises to it (never falls), and the message says
        it, the worst first (the OK message, which describes the OK state, goes)."""
        if level <= OK:
            return
        if self.level == OK:
            self.level, self.message = level, message
        elif level > self.level:
            self.level, self.message = level, f"{message}; {self.message}"
        else:
            self.message = f"{self.message}; {message}"

    def peers(self, watches: Iterable[PeerWatch], lost_level: int = WARN) -> Health:
        """Each peer's state in the values ("peer <name>": up, lost or not seen yet, and how
        often it went away), and ``lost_level`` for one that is not up (WARN while it has not
        come up yet)."""
        for watch in watches:
            if watch.alive:
                state = "up"
            elif watch.losses:
                state = "lost"
                self.escalate(lost_level, f"{watch.name} lost")
            else:
                state = "not seen yet"
                self.escalate(WARN, f"waiting for the {watch.name}")
            self.values[f"peer {watch.name}"] = state
            self.values[f"peer {watch.name} losses"] = str(watch.losses)
        return self


def milliseconds(seconds: float | None) -> str:
    """A duration [s] as the value of a "[ms]" key ("none" when there is none yet)."""
    return "none" if seconds is None else f"{seconds * 1e3:.1f}"


class NodeDiagnostics:
    """Publishes ``check()`` on /diagnostics every PERIOD_S, as the status ``"<node name>:
    <aspect>"`` of ``hardware_id``."""

    def __init__(
        self,
        node: Node,
        check: Callable[[], Health],
        aspect: str = "status",
        hardware_id: str = "",
        period_s: float = PERIOD_S,
    ):
        self.node, self.check = node, check
        self.name = f"{node.get_name()}: {aspect}"
        self.hardware_id = hardware_id or node.get_name()
        self.publisher = node.create_publisher(DiagnosticArray, TOPIC, 10)
        self.timer = node.create_timer(
            period_s, self.publish, callback_group=MutuallyExclusiveCallbackGroup()
        )

    def status(self) -> DiagnosticStatus:
        """The node's status now (ERROR with the exception when the check fails)."""
        try:
            health = self.check()
        except Exception as exc:  # report it, keep the node up
            self.node.get_logger().error(
                f"diagnostics check failed: {type(exc).__name__}: {exc}",
                throttle_duration_sec=60.0,
            )
            health = Health(ERROR, f"the health check failed: {type(exc).__name__}: {exc}")
        return DiagnosticStatus(
            level=bytes([health.level]),
            name=self.name,
            message=health.message,
            hardware_id=self.hardware_id,
            values=[KeyValue(key=k, value=str(v)) for k, v in health.values.items()],
        )

    def force_update(self) -> None:
        """Publish the status now (thread-safe), besides the timer's. It never raises: the
        event's own work goes on (a shutdown may have invalidated the publisher)."""
        try:
            self.publish()
        except Exception as exc:
            if self.node.context.ok():
                self.node.get_logger().error(
                    f"diagnostics not published: {type(exc).__name__}: {exc}",
                    throttle_duration_sec=60.0,
                )

    def publish(self) -> None:
        array = DiagnosticArray(status=[self.status()])
        array.header.stamp = self.node.get_clock().now().to_msg()
        self.publisher.publish(array)
