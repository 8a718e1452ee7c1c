"""QoS profiles shared by RRG's nodes."""

from __future__ import annotations

from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

#: A latched topic (the belief, its markers): a late subscriber (the planner, the bag recorder,
#: RViz) gets the last message.
LATCHED = QoSProfile(
    depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL, reliability=ReliabilityPolicy.RELIABLE
)

#: The executor's events (observations, retreats): latched, so that a restarted estimator
#: receives the last of each and can apply the one it missed (it skips what it has applied).
EVENTS = QoSProfile(
    depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL, reliability=ReliabilityPolicy.RELIABLE
)
