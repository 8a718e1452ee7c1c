"""Telling that a peer node died, from DDS liveliness (the role bond plays for nav2's lifecycle
manager).

A node that others depend on ``announce``s itself: it publishes one latched message on
``/rrg/alive/<name>`` (std_msgs/Header: the stamp is when this instance started, frame_id its
name) from a publisher with AUTOMATIC liveliness and a lease of ALIVE_LEASE_S. DDS asserts that
liveliness for as long as the process runs, so a process that is killed, even by SIGKILL,
loses it one lease later. A ``PeerWatch`` subscribes to the same topic with a liveliness
event callback: ``alive`` says whether the peer is up now and ``losses`` counts how often it
went away. Waiting for an answer from a dead server would otherwise last its whole timeout:
the graph still lists a killed process's endpoints for many seconds (measured: a SIGKILLed
publisher was still counted 4 s later, while its liveliness was lost after 0.75 s).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

from rclpy.callback_groups import CallbackGroup
from rclpy.duration import Duration
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, LivelinessPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import Header

#: Liveliness lease [s] of an announced node: a dead peer is noticed about this long after it
#: died (0.74 s measured for a SIGKILL on the 2-core machine under load). Chosen: shorter than
#: any wait it guards, and long enough that a loaded machine does not miss an assertion (Fast
#: DDS's own threads assert it, not Python's). Both sides use it: Fast DDS reports a loss only
#: after the subscriber's requested lease, which must be at least the publisher's (measured:
#: with 10 s requested, a SIGKILLed publisher was still alive 4 s later).
ALIVE_LEASE_S = 1.0

ALIVE_QOS = QoSProfile(
    depth=1,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
    reliability=ReliabilityPolicy.RELIABLE,
    liveliness=LivelinessPolicy.AUTOMATIC,
    liveliness_lease_duration=Duration(seconds=ALIVE_LEASE_S),
)


def alive_topic(name: str) -> str:
    """The topic a node called ``name`` announces itself on."""
    return f"/rrg/alive/{name}"


def announce(node: Node, name: str) -> None:
    """Publish that ``name`` (this node) is up, for as long as its process lives (the node
    keeps the publisher)."""
    pub = node.create_publisher(Header, alive_topic(name), ALIVE_QOS)
    pub.publish(Header(stamp=node.get_clock().now().to_msg(), frame_id=name))


class PeerLost(RuntimeError):
    """A peer node went away while it was being waited for."""


class PeerWatch:
    """Whether the announced node ``name`` is up, from its liveliness (thread-safe)."""

    def __init__(
        self,
        node: Node,
        name: str,
        callback_group: CallbackGroup | None = None,
        on_change: Callable[[bool], None] | None = None,
    ):
        self.name = name
        self.on_change = on_change
        self._cv = threading.Condition()
        self._alive = False
        self.losses = 0  # times the peer went away
        self.started: Header | None = None  # the current instance's announcement
        node.create_subscription(
            Header,
            alive_topic(name),
            self._on_announcement,
            ALIVE_QOS,
            callback_group=callback_group,
            event_callbacks=SubscriptionEventCallbacks(liveliness=self._on_liveliness),
        )

    def _on_announcement(self, msg: Header) -> None:
        with self._cv:
            self.started = msg

    def _on_liveliness(self, event) -> None:
        alive = event.alive_count > 0
        with self._cv:
            changed = alive != self._alive
            if self._alive and not alive:
                self.losses += 1
            self._alive = alive
            self._cv.notify_all()
        if changed and self.on_change is not None:
            self.on_change(alive)

    @property
    def alive(self) -> bool:
        return self._alive

    def lost_since(self, losses: int) -> bool:
        """Whether the peer went away after ``losses`` was read from ``self.losses``, or is
        down now."""
        return self.losses > losses or not self._alive

    def wait_alive(self, timeout_s: float, interrupted: Callable[[], bool] | None = None) -> bool:
        """Wait until the peer is up; False on timeout or interruption."""
        deadline = time.monotonic() + timeout_s
        with self._cv:
            while not self._alive:
                if (interrupted is not None and interrupted()) or time.monotonic() > deadline:
                    return False
                self._cv.wait(0.05)
        return True
