"""QoS profiles, and how long action servers keep results, shared by RRG's nodes."""

from __future__ import annotations

from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

#: A latched topic (the belief's markers): a late subscriber (the planner, the bag recorder,
#: RViz) gets the last message.
LATCHED = QoSProfile(
    depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL, reliability=ReliabilityPolicy.RELIABLE
)

#: Messages of a latched stream its publisher keeps for late subscribers. Discovery of a
#: restarted node takes up to seconds under load (1.3 s measured on two busy cores), during
#: which it may publish more than one message.
STREAM_HISTORY = 10

#: A latched stream (the executor's observations and retreats, the estimator's beliefs): a
#: restarted estimator receives the events it missed (it skips what it has applied), and a
#: subscriber that matches a restarted publisher late (the bag recorder) still receives every
#: message it published since, not only the last.
STREAM = QoSProfile(
    depth=STREAM_HISTORY,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
    reliability=ReliabilityPolicy.RELIABLE,
)

#: How long an action server keeps a finished goal (its request and result) for clients that ask
#: for the result late [s]. rclpy's default, 900 s, kept every guarded move's trajectory for a
#: quarter of an hour: about 117 kB per 200-point goal (measured on a bare GuardedMove server).
#: RRG's clients ask for the result as soon as the goal is accepted.
RESULT_TIMEOUT_S = 30
